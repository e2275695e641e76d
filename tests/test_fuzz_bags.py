"""
Property-based fuzzing of the four readers of a recording: replay, report, ``--rerun``, recover.

One small valid bag (a synthetic run in ten chunks, with a ``run`` record and the observer's
parameters) is made once, then damaged the ways a disk, a kill or a copy damage files: truncated,
bits flipped, a byte range or a whole chunk zeroed, a record duplicated, two records swapped,
garbage with or without the MCAP magic, an empty file. Every reader either succeeds and what it
says is true of the bytes it had (counted by the ``mcap`` library's own reader, not ours), or
refuses with one line naming the file, exit code 1 or 2, no traceback, and leaves the existing
output it was given (``--force``) as it was.

``recover`` never claims a message its output does not hold, counts the topics it saved messages
on, and never says "nothing lost" when a message of the undamaged bag is missing from its output.

Cases: the 'ci' hypothesis profile of tests/conftest.py runs 100 seeded ones per kind of damage
(every reader on each); ``make fuzz`` ('fuzz' profile) 1,000 fresh ones per kind, and 25 per
installed executable.
"""
from collections import Counter
import contextlib
import io
import os
import re
import subprocess

from hypothesis import given, settings, strategies as st
from im_recording import recover as rec
from im_recording.bag import BagError, BagWriter, check_data_crc
from im_recording.mcap_records import MAGIC, REC
from im_recording.replay import main as replay_main, Player
from im_recording.report import main as report_main
from im_recording.synth import make_synthetic_bag
import pytest

KINDS = ('truncate', 'bit_flip', 'zero_range', 'zero_chunk', 'duplicate_record',
         'reorder_records', 'garbage', 'combined')
SENTINEL = b'an earlier output, not to be overwritten by a refusal\n'
RUN_YAML = 'task: speed\nstrategy: min_energy\nT_s: 0.001\nduration: 0.03\n'
OBSERVER = {'R_s': '0.687', 'R_r': '0.842', 'k_e_injection': '0.0'}
# the 'ci' profile: 100 seeded cases per kind, each through all four readers (~30 s on 2 cores)
_FUZZ = settings.get_current_profile_name() == 'fuzz'
_CASES = settings(deadline=None, max_examples=settings().max_examples if _FUZZ
                  else min(settings().max_examples, 100))


# ------------------------------------------------------------------------------------------
# The bag, its records, and an independent reader
# ------------------------------------------------------------------------------------------
def independent(path) -> Counter:
    """(topic, log time, bytes) of every message, read by the mcap library with CRC checks."""
    from mcap.reader import make_reader
    with open(path, 'rb') as f:
        reader = make_reader(f, validate_crcs=True)
        return Counter((ch.topic, m.log_time, bytes(m.data))
                       for _s, ch, m in reader.iter_messages())


def records_named(path) -> dict:
    """Return the Metadata records of ``path`` by name, as the mcap library reads them."""
    from mcap.reader import make_reader
    with open(path, 'rb') as f:
        return {m.name: dict(m.metadata) for m in make_reader(f).iter_metadata()}


def records(data: bytes):
    """(start, end, opcode) of every whole record between the leading and the trailing magic."""
    out, pos, stop = [], 8, len(data) - 8
    while pos + 9 <= stop:
        op, length = REC.unpack_from(data, pos)
        end = pos + 9 + length
        if end > stop:
            break
        out.append((pos, end, op))
        pos = end
    return out


@pytest.fixture(scope='session')
def good(tmp_path_factory):
    """Return the undamaged bag: its bytes, records and messages."""
    path = tmp_path_factory.mktemp('fuzz_bags') / 'good.mcap'
    make_synthetic_bag(path, steps=30, chunk_size=4096,
                       metadata={'run': {'yaml': RUN_YAML}, 'parameters/observer': OBSERVER})
    data = path.read_bytes()
    recs = records(data)
    assert sum(op == 6 for _a, _b, op in recs) >= 8, 'the bag should have several chunks'
    return {'path': path, 'bytes': data, 'records': recs, 'messages': independent(path)}


@st.composite
def mutated(draw, kind: str, g: dict) -> bytes:
    """Return the good bag damaged one way (``kind``), or two ways in turn ('combined')."""
    if kind == 'combined':
        first, then = draw(st.lists(st.sampled_from(KINDS[:-2]), min_size=2, max_size=2))
        return damage(draw, then, damage(draw, first, g['bytes']))
    return damage(draw, kind, g['bytes'])


def damage(draw, kind: str, data: bytes) -> bytes:
    """Return ``data`` damaged one way; a record-wise way needs records (else: unchanged)."""
    n, recs = len(data), records(data)
    if kind == 'truncate':
        return data[:draw(st.integers(0, max(0, n - 1)))]
    if kind == 'bit_flip':
        out = bytearray(data)
        for pos, bit in draw(st.lists(st.tuples(st.integers(0, n - 1), st.integers(0, 7)),
                                      min_size=1, max_size=4)) if n else ():
            out[pos] ^= 1 << bit
        return bytes(out)
    if kind == 'zero_range':
        a = draw(st.integers(0, max(0, n - 1)))
        b = min(n, a + draw(st.integers(1, 4096)))
        return data[:a] + bytes(b - a) + data[b:]
    if kind == 'zero_chunk':
        chunks = [r for r in recs if r[2] == 6]
        if not chunks:
            return data
        a, b, _ = draw(st.sampled_from(chunks))
        how = draw(st.sampled_from(('record', 'body', 'part')))
        if how == 'body':               # its header kept
            a += 9
        elif how == 'part':             # any stretch inside it
            a = draw(st.integers(a, b - 1))
            b = draw(st.integers(a + 1, b))
        return data[:a] + bytes(b - a) + data[b:]
    if kind == 'duplicate_record':
        if not recs:
            return data
        a, b, _ = draw(st.sampled_from(recs))
        at = draw(st.sampled_from([r[0] for r in recs] + [recs[-1][1]]))
        return data[:at] + data[a:b] + data[at:]
    if kind == 'reorder_records':
        if len(recs) < 2:
            return data
        i = draw(st.integers(0, len(recs) - 2))
        j = draw(st.integers(i + 1, len(recs) - 1))
        (a1, b1, _), (a2, b2, _) = recs[i], recs[j]
        return data[:a1] + data[a2:b2] + data[b1:a2] + data[a1:b1] + data[b2:]
    assert kind == 'garbage'
    body = draw(st.binary(min_size=0, max_size=2048))
    head = MAGIC if draw(st.booleans()) else b''
    tail = MAGIC if draw(st.booleans()) else b''
    return head + body + tail


# ------------------------------------------------------------------------------------------
# The properties, one per reader
# ------------------------------------------------------------------------------------------
def call(main, argv):
    """Run a console entry point in-process: (exit code, stdout, stderr)."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main(argv)
    return code, out.getvalue(), err.getvalue()


def assert_refusal(code, err, bag, why=''):
    """One line naming the file, exit code 1 or 2, no traceback."""
    lines = err.splitlines()
    assert code in (1, 2), f'exit code {code}: {err!r} {why}'
    assert len(lines) == 1, f'{len(lines)} lines on stderr: {err!r} {why}'
    assert str(bag) in lines[0], f'the line does not name {bag}: {err!r} {why}'
    assert 'Traceback' not in err


def sentinel(path):
    path.write_bytes(SENTINEL)
    return path


def check_report(bag, work):
    out = work / 'rep'
    out.mkdir(exist_ok=True)
    md, js = sentinel(out / 'report.md'), sentinel(out / 'report.json')
    code, _o, err = call(report_main, [str(bag), '--out', str(out), '--no-plots', '--force'])
    if code == 0:
        import json
        counts = json.loads(js.read_text())['runs'][0]['message_counts']
        held = Counter(t for t, _l, _d in independent(bag).elements())
        assert counts == dict(held), 'report counts messages the file does not hold'
    else:
        assert_refusal(code, err, bag, 'report')
        assert md.read_bytes() == SENTINEL and js.read_bytes() == SENTINEL
    return code


def check_replay(bag, work):
    out = sentinel(work / 'reest.mcap')
    code, stdout, err = call(replay_main, [str(bag), '--reestimate', '--out', str(out),
                                           '--force'])
    if code == 0:
        said = int(re.search(r'; (\d+) messages written', stdout).group(1))
        assert sum(independent(out).values()) == said
        # the observer it ran is the one the bag recorded, not a damaged copy of its record
        assert records_named(out)['parameters/observer'] == OBSERVER
    else:
        assert_refusal(code, err, bag, 'replay --reestimate')
        assert out.read_bytes() == SENTINEL
    # playing: the Player on a node that counts what it publishes
    try:
        n = Player(_Node(), str(bag), lockstep=True, clock=False).play()
    except BagError as exc:
        assert str(bag) in str(exc) and '\n' not in str(exc).strip()
    else:
        assert n == sum(independent(bag).values()), 'replay published what the file lacks'
    return code


class _Pub:

    def publish(self, data):
        pass

    def get_subscription_count(self):
        return 0


class _Node:

    def create_publisher(self, *_args):
        return _Pub()


def check_rerun(bag, work):
    from im_bringup.scenario import main as scenario_main
    out = sentinel(work / 'params.yaml')
    code, _o, err = call(scenario_main, ['--rerun', str(bag), '--write-params', str(out),
                                         '--force'])
    if code == 0:
        # what it re-ran is the run the bag recorded, not a damaged copy of it
        assert records_named(bag)['run'] == {'yaml': RUN_YAML}
        assert out.read_bytes() != SENTINEL
    else:
        assert_refusal(code, err, bag, '--rerun')
        assert out.read_bytes() == SENTINEL
    return code


_SAVED = re.compile(r'^recover: saved (\d+) messages on (\d+) topics .* into (.+?); (.*)$', re.M)


def check_recover(bag, work, original: Counter):
    out = sentinel(work / 'fixed.mcap')
    code, stdout, err = call(rec.main, [str(bag), '-o', str(out), '--force'])
    assert 'Traceback' not in err
    if code == 2:
        assert_refusal(code, err, bag, 'recover')
        assert out.read_bytes() == SENTINEL
        return code
    assert code in (0, 1), f'exit code {code}'
    assert all(line.startswith('recover: ') for line in err.splitlines()), err
    m = _SAVED.search(stdout)
    assert m, stdout
    held = independent(out)
    topics = {t for t, _l, _d in held}
    assert int(m.group(1)) == sum(held.values()), 'recover claims messages it does not hold'
    assert int(m.group(2)) == len(topics), 'recover counts topics it saved nothing on'
    missing = sum((original - held).values())
    if missing:
        assert code == 1 and 'nothing lost' not in m.group(4), \
            f'{missing} messages lost but: {m.group(4)}'
    said = re.search(r', (\d+)(?: of \d+)? messages lost', m.group(4))
    if said:    # a number of messages lost is never below what the output lacks
        assert int(said.group(1)) >= missing, f'{missing} messages lost but: {m.group(4)}'
    if code == 0:
        assert not err.strip() and 'nothing lost' in m.group(4)
    return code


def check_all(data: bytes, g: dict, work):
    bag = work / 'bag.mcap'
    bag.write_bytes(data)
    return (check_recover(bag, work, g['messages']), check_report(bag, work),
            check_replay(bag, work), check_rerun(bag, work))


@pytest.fixture(scope='module')
def work(tmp_path_factory):
    return tmp_path_factory.mktemp('fuzz_work')


@pytest.mark.slow
@pytest.mark.parametrize('kind', KINDS)
@_CASES
@given(data=st.data())
def test_every_reader_succeeds_truthfully_or_refuses_in_one_line(kind, good, work, data):
    check_all(data.draw(mutated(kind, good)), good, work)


def test_the_undamaged_bag_passes_every_reader(good, work):
    code, stdout, _e = call(rec.main, [str(good['path']), '-o', str(work / 'whole.mcap'),
                                       '--force'])
    assert code == 0 and 'nothing lost' in stdout
    assert check_all(good['bytes'], good, work) == (0, 0, 0, 0)


def test_an_empty_file_is_refused_by_every_reader(good, work):
    assert check_all(b'', good, work) == (2, 2, 2, 2)


# ------------------------------------------------------------------------------------------
# The installed executables, on a sample
# ------------------------------------------------------------------------------------------
def _command(tool, bag, out):
    from test_executables import ros2_run_path
    if tool == 'scenario':
        return [ros2_run_path('im_bringup', 'scenario'), '--rerun', str(bag), '--write-params',
                str(out), '--force']
    exe = ros2_run_path('im_recording', tool)
    return {'recover': [exe, str(bag), '-o', str(out), '--force'],
            'report': [exe, str(bag), '--out', str(out), '--force'],
            'replay': [exe, str(bag), '--lockstep', '--wait-subscribers', '0']}[tool]


@pytest.mark.processes
@pytest.mark.parametrize('tool', ['recover', 'report', 'replay', 'scenario'])
@settings(deadline=None, max_examples=25 if _FUZZ else 3)
@given(kind=st.sampled_from(KINDS + ('empty',)), data=st.data())
def test_the_installed_executables_on_a_sample(tool, good, work, kind, data):
    """Exit code 0, or 1/2 with one line naming the file; never a traceback; no output lost."""
    raw = b'' if kind == 'empty' else data.draw(mutated(kind, good))
    bag = work / 'sample.mcap'
    bag.write_bytes(raw)
    out = work / ('sample_rep' if tool == 'report' else 'sample_out')
    if tool == 'report':
        out.mkdir(exist_ok=True)
        kept = sentinel(out / 'report.md')
    else:
        kept = sentinel(out)
    proc = subprocess.run(_command(tool, bag, out), capture_output=True, text=True,
                          timeout=120, env=dict(os.environ, PYTHONWARNINGS='ignore'))
    assert 'Traceback' not in proc.stderr, proc.stderr
    if proc.returncode == 0 or (tool == 'recover' and proc.returncode == 1):
        return
    assert_refusal(proc.returncode, proc.stderr, bag, f'{tool} ({kind})')
    assert kept.read_bytes() == SENTINEL


# ------------------------------------------------------------------------------------------
# Defects the fuzzing found, each pinned
# ------------------------------------------------------------------------------------------
def test_recover_counts_the_topics_it_saved_messages_on_not_its_channels(good, tmp_path):
    """A file with channels that carry nothing: 'on N topics' counts the topics with messages."""
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore
    src, out = tmp_path / 'some_empty.mcap', tmp_path / 'fixed.mcap'
    with BagWriter(src) as w:
        for k in range(4):
            w.add_topic(f'/empty/{k}', 'geometry_msgs/msg/Vector3Stamped')
        for k in range(18):
            w.add_topic(f'/busy/{k}', 'geometry_msgs/msg/Vector3Stamped')
            w.write_vector3(f'/busy/{k}', 1000 * (k + 1), 1.0, 2.0)
    code, stdout, _e = call(rec.main, [str(src), '-o', str(out)])
    assert code == 0
    with AnyReader([out], default_typestore=get_typestore(Stores.ROS2_JAZZY)) as ar:
        held = {conn.topic for conn, _t, _raw in ar.messages()}
        assert len(ar.topics) == 22         # the empty channels are copied, as declared
    assert len(held) == 18
    assert ' saved 18 messages on 18 topics ' in stdout
    # and a file whose every chunk is lost saves messages on no topic at all
    data = good['bytes']
    for a, b, op in good['records']:
        if op == 6:
            data = data[:a] + bytes(b - a) + data[b:]
    bag = tmp_path / 'no_chunks.mcap'
    bag.write_bytes(data)
    code, stdout, _e = call(rec.main, [str(bag), '-o', str(out), '--force'])
    assert code == 1 and ' saved 0 messages on 0 topics ' in stdout


def test_a_file_too_short_for_a_footer_is_one_line_naming_it(good, tmp_path):
    """Magic, then magic: 16 bytes. It was 'report: error: [Errno 22] Invalid argument'."""
    for data in (MAGIC + MAGIC, MAGIC + bytes(20) + MAGIC):
        work = tmp_path / str(len(data))
        work.mkdir()
        bag = work / 'short.mcap'
        bag.write_bytes(data)
        assert check_all(data, good, work) == (2, 2, 2, 2)
        for main in (report_main, replay_main):
            code, _o, err = call(main, [str(bag)])
            assert_refusal(code, err, bag)
            assert 'truncated: no MCAP footer' in err
        with pytest.raises(BagError, match='truncated'):
            check_data_crc(bag)


def _patched(good, old: bytes, new: bytes) -> bytes:
    data = good['bytes']
    assert data.count(old) == 1 and len(old) == len(new)
    return data.replace(old, new)


def test_rerun_refuses_a_run_record_the_data_crc_does_not_vouch_for(good, tmp_path, capsys):
    """A flipped bit in the run record re-ran another run (duration 1.03 s for 0.03 s)."""
    from im_bringup.scenario import main as scenario_main
    bag = tmp_path / 'flipped.mcap'
    bag.write_bytes(_patched(good, b'duration: 0.03', b'duration: 1.03'))
    out = sentinel(tmp_path / 'params.yaml')
    code, _o, err = call(scenario_main, ['--rerun', str(bag), '--write-params', str(out),
                                         '--force'])
    assert_refusal(code, err, bag)
    assert 'data section CRC mismatch' in err and out.read_bytes() == SENTINEL
    # a run record that is not YAML, or not a mapping, was a traceback (yaml's ScannerError)
    for text, why in (('task: [speed\n', 'is not valid YAML (line 2, column 1)'),
                      ('- 1\n', 'not a mapping')):
        bag = tmp_path / 'odd.mcap'
        make_synthetic_bag(bag, steps=2, metadata={'run': {'yaml': text}}, force=True)
        code, _o, err = call(scenario_main, ['--rerun', str(bag), '--write-params', str(out),
                                             '--force'])
        assert_refusal(code, err, bag)
        assert why in err and out.read_bytes() == SENTINEL


def test_reestimate_refuses_observer_parameters_the_data_crc_does_not_vouch_for(good, tmp_path):
    """A flipped bit in parameters/observer re-ran the observer with R_r = 9.842 Ω."""
    bag = tmp_path / 'flipped.mcap'
    bag.write_bytes(_patched(good, b'0.842', b'9.842'))
    out = sentinel(tmp_path / 'reest.mcap')
    code, _o, err = call(replay_main, [str(bag), '--reestimate', '--out', str(out), '--force'])
    assert_refusal(code, err, bag)
    assert 'data section CRC mismatch' in err and out.read_bytes() == SENTINEL


def test_replay_that_meets_a_damaged_chunk_while_playing_says_it_in_one_line(good, tmp_path):
    """It printed 'replay: 0 messages published from BAG' before the error line: two lines."""
    a, b, _op = next(r for r in good['records'] if r[2] == 6)
    data = bytearray(good['bytes'])
    data[b - 20] ^= 0xFF           # inside the first chunk's compressed records
    bag = tmp_path / 'bad_chunk.mcap'
    bag.write_bytes(bytes(data))
    code, _o, err = call(replay_main, [str(bag), '--lockstep', '--wait-subscribers', '0'])
    assert_refusal(code, err, bag)
    assert f'corrupt chunk at byte {a}' in err and '(after 0 messages published)' in err


def test_recover_never_calls_a_file_whole_when_it_did_not_copy_its_messages(tmp_path):
    """
    Messages read intact but not copied are a loss: exit 1, counted, each reason on one line.

    A channel in another encoding made recover say 'nothing lost', exit 0, with 2 of 3 messages
    left out; a bit flip in a channel's QoS metadata printed yaml's five-line error as a note.
    """
    from mcap.writer import Writer
    src, out = tmp_path / 'mixed.mcap', tmp_path / 'fixed.mcap'
    with open(src, 'wb') as f:
        w = Writer(f)
        w.start(profile='ros2', library='test')
        sid = w.register_schema('geometry_msgs/msg/Vector3Stamped', 'ros2msg', b'')
        js = w.register_channel('/as_json', 'json', 0)
        qos = w.register_channel('/bad_qos', 'cdr', sid,
                                 {'offered_qos_profiles': '- depth: 10\n  nsec: 8: 5\n'})
        ok = w.register_channel('/ok', 'cdr', sid)
        w.add_message(js, 1000, b'{}', 1000)
        w.add_message(qos, 1500, bytes(60), 1500)
        w.add_message(ok, 2000, bytes(60), 2000)
        w.finish()
    code, stdout, err = call(rec.main, [str(src), '-o', str(out)])
    assert code == 1, stdout
    assert 'nothing lost' not in stdout and ', 2 of 3 messages lost' in stdout
    assert ' saved 1 messages on 1 topics ' in stdout
    lines = err.splitlines()
    assert len(lines) == 2 and all(line.startswith('recover: 1 message(s) not copied (/')
                                   for line in lines), err
    assert "/as_json: message encoding 'json', not cdr" in err
    assert '/bad_qos: offered_qos_profiles is not valid YAML (line 2, column 10)' in err
    assert sum(independent(out).values()) == 1


def test_recover_keeps_the_summarys_channel_over_an_altered_one(good, tmp_path):
    """One zeroed byte in a channel's topic name put 31 messages under a NUL-mangled name."""
    data = good['bytes']
    at = data.index(b'/im/measured/shaft') + 1          # the data section's Channel record
    bag, out = tmp_path / 'renamed.mcap', tmp_path / 'fixed.mcap'
    bag.write_bytes(data[:at] + b'\x00' + data[at + 1:])
    r = rec.recover(bag, str(out))
    assert not r['whole'] and r['messages_lost'] == 0
    assert "channel 3 (/im/measured/shaft): the data section's record differs from the " \
           "summary's, which was kept" in r['notes']
    assert independent(out) == good['messages']


def test_recover_counts_a_lost_tail_as_at_least(good, tmp_path):
    """A damaged chunk, then the file cut: 'N messages lost' counted the chunk's, not the tail."""
    chunks = [r for r in good['records'] if r[2] == 6]
    (a, b, _), cut = chunks[0], chunks[3][0]
    data = good['bytes']
    bag, out = tmp_path / 'cut.mcap', tmp_path / 'fixed.mcap'
    bag.write_bytes(data[:a + 9] + bytes(b - a - 9) + data[b:cut])
    r = rec.recover(bag, str(out))
    held = sum(independent(out).values())
    missing = sum(good['messages'].values()) - held
    assert r['messages_lost'] is None and 0 < r['messages_lost_at_least'] < missing
    assert f", at least {r['messages_lost_at_least']} messages lost, and the tail" in r['reason']
