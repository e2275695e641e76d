"""
``recover`` (issue 23).

Every record boundary validated, a damaged chunk costs exactly that chunk, the loss is reported
exactly and never called complete, the input is never touched, and an output that cannot be written
leaves nothing behind.
"""
import errno
import os

from im_common import cdr
from im_recording import recover as rec
from im_recording.bag import BagWriter, info, iter_raw, partial_path
import pytest

V3, JS = '/im/measured/current', '/im/measured/shaft'


def _chunks(path):
    from mcap.reader import make_reader
    with open(path, 'rb') as f:
        return sorted(make_reader(f).get_summary().chunk_indexes,
                      key=lambda c: c.chunk_start_offset)


def _all(path):
    return [(tp, t, bytes(d)) for tp, _, t, d in iter_raw(path)]


def _many_chunks(path, steps=1300, chunk=1024, compression='zstd'):
    """
    Return a recording in a few hundred small chunks.

    Every message has its own stamp, so a chunk's messages are exactly those stamped within its
    [start, end].
    """
    with BagWriter(path, chunk_size=chunk, compression=compression,
                   metadata={'scenario': {'task': 'speed'}}) as w:
        for k in range(steps):
            t = 1_000_000 + k * 1000
            w.write_vector3(V3, t, 0.37 * k, -float(k))
            w.write_joint_state(JS, t + 500, ('rotor',), (0.01 * k,), (float(k % 97),))
    return path


def _corrupt(data: bytearray, ci, mode: int) -> None:
    """Damage chunk ``ci`` (only its own bytes) in one of four ways."""
    a, n = ci.chunk_start_offset, ci.chunk_length
    if mode == 0:                                   # zero the middle half of the chunk
        data[a + n // 4:a + 3 * n // 4] = bytes(3 * n // 4 - n // 4)
    elif mode == 1:                                 # its record header: opcode and length
        data[a:a + 9] = bytes(9)
    elif mode == 2:                                 # one flipped byte in the compressed data
        data[a + 53 + (ci.message_start_time // 1000 * 7919) % (n - 53)] ^= 0xFF
    else:                                           # the whole chunk record zeroed
        data[a:a + n] = bytes(n)


@pytest.mark.slow
def test_corrupting_each_chunk_in_turn_loses_exactly_that_chunk(tmp_path):
    src = _many_chunks(tmp_path / 'long.mcap')
    ci = _chunks(src)
    assert len(ci) >= 200
    full = _all(src)
    good = bytes(src.read_bytes())
    bad, out = tmp_path / 'bad.mcap', tmp_path / 'out.mcap'
    failures = []
    for i, c in enumerate(ci):
        data = bytearray(good)
        _corrupt(data, c, i % 4)
        bad.write_bytes(bytes(data))
        r = rec.recover(bad, str(out), force=True)
        t0, t1 = c.message_start_time, c.message_end_time
        want = [m for m in full if not t0 <= m[1] <= t1]
        got = _all(out)
        ranges = [(x['t0_ns'], x['t1_ns'], x['messages']) for x in r.get('lost_ranges', ())]
        if got != want or ranges != [(t0, t1, len(full) - len(want))] or r['complete']:
            failures.append((i, i % 4, len(full) - len(got), len(full) - len(want), ranges,
                             (t0, t1)))
    assert not failures, f'{len(failures)} of {len(ci)} chunks: {failures[:5]}'


def _index_holding_a_data_end_pattern(path):
    """
    Build chunks whose Message Index records contain a Data End record's bytes.

    Chunks whose Message Index records contain ``0f 04 00 00 00 00 00 00 00`` (the bytes of a Data
    End record): a message at chunk offset 1039 (0x40f) followed in the index by a stamp that is a
    multiple of 256.
    """
    name = 'r'
    while len(cdr.pack_joint_state(0, 0, (name,), (1.0,), (1.0,))) + 31 < 1039:
        name += 'r'
    assert len(cdr.pack_joint_state(0, 0, (name,), (1.0,), (1.0,))) + 31 == 1039
    with BagWriter(path, chunk_size=4096, compression='none') as w:
        for k in range(600):
            if k % 3 == 0:
                w.flush()                   # every chunk starts with the 1039-byte message
            t = (k + 1) * 1024
            w.write_joint_state(JS, t, (name,), (1.0,), (1.0,))
            w.write_vector3(V3, t + 256, 1.0, 2.0)
            w.write_vector3(V3, t + 512, 3.0, 4.0)
    return path


def test_data_end_bytes_inside_a_message_index_do_not_end_the_recovery(tmp_path, capsys):
    src = _index_holding_a_data_end_pattern(tmp_path / 'mi.mcap')
    ci = _chunks(src)
    full = _all(src)
    data = bytearray(src.read_bytes())
    pattern = bytes((0x0F, 4)) + bytes(7)
    k = len(ci) // 4
    mid = ci[k].chunk_start_offset + ci[k].chunk_length // 2
    data[mid - 2048:mid + 2048] = bytes(4096)                  # 4 KiB zeroed, as in the issue
    assert data.find(pattern, mid + 2048, ci[-1].chunk_start_offset) > 0
    hit = [c for c in ci if c.chunk_start_offset < mid + 2048
           and c.chunk_start_offset + c.chunk_length > mid - 2048]
    t0, t1 = min(c.message_start_time for c in hit), max(c.message_end_time for c in hit)
    bad = tmp_path / 'bad.mcap'
    bad.write_bytes(bytes(data))
    code = rec.main([str(bad), '-o', str(tmp_path / 'fixed.mcap')])
    cap = capsys.readouterr()
    want = [m for m in full if not t0 <= m[1] <= t1]
    got = _all(tmp_path / 'fixed.mcap')
    assert (len(got), got) == (len(want), want)
    assert code == 1
    assert f'{t0 * 1e-9:.9f} .. {t1 * 1e-9:.9f} s' in cap.err
    assert 'complete' not in cap.out and f'{len(full) - len(want)} of {len(full)}' in cap.out


def test_an_intact_file_is_copied_whole_and_called_complete(tmp_path, capsys):
    src = _many_chunks(tmp_path / 'ok.mcap', steps=300)
    assert rec.main([str(src), '-o', str(tmp_path / 'copy.mcap')]) == 0
    out = capsys.readouterr().out
    assert 'nothing lost' in out
    assert _all(tmp_path / 'copy.mcap') == _all(src)


def test_a_torn_tail_reports_its_chunk_header_range(tmp_path, capsys):
    src = _many_chunks(tmp_path / 'cut.mcap', steps=300, chunk=4096)
    ci = _chunks(src)
    last = ci[len(ci) // 2]
    part = partial_path(tmp_path / 'torn.mcap')
    part.write_bytes(src.read_bytes()[:last.chunk_start_offset + last.chunk_length // 2])
    before = part.read_bytes()
    # the interrupted recording itself, recovered under the final name
    assert rec.main([str(part), '-o', str(tmp_path / 'torn.mcap')]) == 1
    cap = capsys.readouterr()
    t0, t1 = last.message_start_time, last.message_end_time
    assert f'{t0 * 1e-9:.9f} .. {t1 * 1e-9:.9f} s' in cap.err and 'torn' in cap.err
    assert _all(tmp_path / 'torn.mcap') == [m for m in _all(src) if m[1] < t0]
    assert part.read_bytes() == before                         # the input is never modified
    assert sorted(p.name for p in tmp_path.iterdir()) == ['cut.mcap', 'torn.mcap',
                                                          'torn.mcap.part']


def test_recover_part_onto_its_final_name_keeps_the_input(tmp_path, capsys):
    src = _many_chunks(tmp_path / 'x.mcap', steps=200)
    part = partial_path(src)
    src.rename(part)                                            # as a killed writer leaves it
    data = part.read_bytes()
    assert rec.main([str(part), '-o', str(src)]) == 0
    assert capsys.readouterr().err == ''
    assert part.read_bytes() == data
    assert info(src).message_count == 400
    assert rec.main([str(src)]) == 0                            # output x.recovered.mcap
    assert info(tmp_path / 'x.recovered.mcap').message_count == 400


def test_a_full_disk_is_one_line_and_leaves_no_part_behind(tmp_path, capsys, monkeypatch):
    src = _many_chunks(tmp_path / 'in.mcap', steps=2000)
    out_dir = tmp_path / 'out'
    out_dir.mkdir()
    real = BagWriter._write
    written = {'n': 0}

    def full_disk(self, data):
        written['n'] += len(data)
        if written['n'] > 20_000:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        real(self, data)

    monkeypatch.setattr(BagWriter, '_write', full_disk)
    out = out_dir / 'fixed.mcap'
    assert rec.main([str(src), '-o', str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count('\n') == 1 and 'Traceback' not in err
    assert str(out) in err and os.strerror(errno.ENOSPC) in err
    assert list(out_dir.iterdir()) == []                        # no 0-byte .part in the way
    monkeypatch.setattr(BagWriter, '_write', real)
    assert rec.main([str(src), '-o', str(out)]) == 0            # the next try just works
    assert info(out).message_count == 4000


def test_nothing_readable_is_one_line_and_writes_nothing(tmp_path, capsys):
    junk = tmp_path / 'junk.mcap'
    junk.write_bytes(b'\x89MCAP0\r\n' + bytes(5000))
    assert rec.main([str(junk), '-o', str(tmp_path / 'o.mcap')]) == 2
    err = capsys.readouterr().err
    assert err.count('\n') == 1 and 'junk.mcap' in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ['junk.mcap']


def test_random_damage_anywhere_keeps_every_untouched_chunk_and_invents_nothing(tmp_path):
    import random
    src = _many_chunks(tmp_path / 'a.mcap', steps=600, chunk=2048)
    ci, full = _chunks(src), _all(src)
    good = src.read_bytes()
    rng = random.Random(7)
    bad, out = tmp_path / 'b.mcap', tmp_path / 'o.mcap'
    for it in range(80):
        data = bytearray(good)
        a, n = rng.randrange(8, len(good)), rng.choice([1, 8, 64, 512, 4096])
        data[a:a + n] = bytes(rng.randrange(256) for _ in data[a:a + n])
        if it % 5 == 0:                                    # and cut short, as after a kill
            data = data[:rng.randrange(a, len(good) + 1)]
        bad.write_bytes(bytes(data))
        try:
            r = rec.recover(bad, str(out), force=True)
        except Exception as exc:                           # only 'nothing to recover' allowed
            assert 'nothing to recover' in str(exc), (it, a, n)
            continue
        got = _all(out)
        hit = [c for c in ci if c.chunk_start_offset < a + n
               and c.chunk_start_offset + c.chunk_length > a
               or c.chunk_start_offset + c.chunk_length > len(data)]
        want = [m for m in full
                if not any(c.message_start_time <= m[1] <= c.message_end_time for c in hit)]
        assert set(got) <= set(full), (it, a, n)            # nothing invented or altered
        if not any('channel record was lost' in x for x in r.get('notes', ())):
            assert set(want) <= set(got), (it, a, n)        # every untouched chunk kept
        if r.get('whole'):                                   # 'nothing lost' only if true
            in_file = [m for m in full if not any(
                c.message_start_time <= m[1] <= c.message_end_time for c in ci
                if c.chunk_start_offset + c.chunk_length > len(data))]
            assert got == in_file, (it, a, n)


def test_a_damaged_message_index_loses_no_message_and_says_so(tmp_path, capsys):
    src = _many_chunks(tmp_path / 'a.mcap', steps=400)
    ci = _chunks(src)
    data = bytearray(src.read_bytes())
    mi = min(ci[10].message_index_offsets.values())
    data[mi + 1:mi + 9] = bytes(8)                      # the first index record's length
    bad = tmp_path / 'bad.mcap'
    bad.write_bytes(bytes(data))
    assert rec.main([str(bad), '-o', str(tmp_path / 'o.mcap')]) == 1    # damage, said
    cap = capsys.readouterr()
    assert _all(tmp_path / 'o.mcap') == _all(src)
    assert 'no messages lost' in cap.err and '0 of 800 messages lost' in cap.out


def test_a_truncated_bag_names_the_missing_tail_and_its_run_record_says_what_was_saved(
        tmp_path, capsys):
    import yaml
    src = tmp_path / 'three.mcap'
    run = {'yaml': yaml.safe_dump({'task': 'speed', 'T_s': 0.001, 'duration': 3.0})}
    with BagWriter(src, chunk_size=4096, metadata={'run': run}) as w:
        for k in range(3001):
            w.write_vector3(V3, k * 1_000_000, float(k), 0.0)
    ci = _chunks(src)
    cut = ci[int(len(ci) * 0.6)]
    bad = tmp_path / 'cut.mcap'
    bad.write_bytes(src.read_bytes()[:cut.chunk_start_offset + cut.chunk_length // 2])
    out = tmp_path / 'saved.mcap'
    assert rec.main([str(bad), '-o', str(out)]) == 1
    err = capsys.readouterr().err
    t0, t1 = cut.message_start_time, cut.message_end_time
    assert f'lost t = {t0 * 1e-9:.9f} .. {t1 * 1e-9:.9f} s' in err              # the torn chunk
    assert f'lost t = {t1 * 1e-9:.9f} .. end of run (3.000000000 s' in err, err  # and the tail
    md = info(out).metadata
    saved_last = max(t for _, _, t, _ in iter_raw(out))
    assert saved_last < t0
    assert yaml.safe_load(md['run']['yaml'])['duration'] == saved_last * 1e-9
    assert md['recovered_from']['run_duration_s'] == '3.0'


def test_a_closed_file_without_its_end_event_is_still_complete_and_an_unclosed_one_is_not(
        tmp_path, capsys):
    src = _many_chunks(tmp_path / 'x.mcap', steps=300)          # no run record, no status
    part = partial_path(tmp_path / 'y.mcap')
    data = src.read_bytes()
    part.write_bytes(data[:_chunks(src)[-1].chunk_start_offset])  # whole chunks, not closed
    assert rec.main([str(part), '-o', str(tmp_path / 'y.mcap')]) == 1
    cap = capsys.readouterr()
    assert 'nothing lost' not in cap.out and 'end of run (unknown)' in cap.err, cap
