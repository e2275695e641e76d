"""Salvage a recording cut short by a hard kill (no summary, no footer, maybe a torn chunk).

``ros2 run im_bringup recover bags/broken.mcap [-o fixed.mcap] [--force]``

Reads the file record by record from the start, keeps every Schema, Channel and Metadata record
and every message of every intact chunk (CRC verified) and loose Message records. A damaged
chunk is skipped: reading resumes at the next chunk that passes its CRC, and the byte and time
ranges lost are printed (one line each) and stored in the ``recovered_from`` metadata. Everything
is rewritten through :class:`~im_bringup.bag.BagWriter` into a valid, indexed file (default
``<name>.recovered.mcap``; never the input, an existing file only with ``--force``). A writer
that was killed leaves its data in ``<name>.mcap.part``: ``recover <name>.mcap`` reads that.
Exit code 2 if nothing could be read at all.
"""
from __future__ import annotations

import argparse
import struct
import sys
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Dict, List, Optional, Tuple

from .bag import (_REC, _U16, _U32, _U64, MAGIC, OP_CHANNEL, OP_CHUNK, OP_DATA_END, OP_FOOTER,
                  OP_MESSAGE, OP_METADATA, OP_SCHEMA, BagError, BagWriter, _decompress,
                  check_output, partial_path)


@dataclass
class Salvage:
    schemas: Dict[int, Tuple[str, str, bytes]] = field(default_factory=dict)
    channels: Dict[int, Tuple[str, int, str, Dict[str, str]]] = field(default_factory=dict)
    metadata: List[Tuple[str, Dict[str, str]]] = field(default_factory=list)
    messages: List[Tuple[int, int, bytes]] = field(default_factory=list)   # (cid, log_time, data)
    stopped_at: int = 0
    reason: str = 'end of data section'
    complete: bool = False
    # skipped damage: (first byte, next intact byte, start ns, end ns or None, why)
    lost: List[tuple] = field(default_factory=list)


class _Buf:
    def __init__(self, data: bytes, pos: int = 0):
        self.d, self.p = data, pos

    def u16(self):
        (v,) = _U16.unpack_from(self.d, self.p)
        self.p += 2
        return v

    def u32(self):
        (v,) = _U32.unpack_from(self.d, self.p)
        self.p += 4
        return v

    def u64(self):
        (v,) = _U64.unpack_from(self.d, self.p)
        self.p += 8
        return v

    def s(self) -> str:
        n = self.u32()
        v = self.d[self.p:self.p + n]
        if len(v) != n:
            raise ValueError('string past the end of the record')
        self.p += n
        return v.decode('utf-8')

    def b32(self) -> bytes:
        n = self.u32()
        v = self.d[self.p:self.p + n]
        if len(v) != n:
            raise ValueError('bytes past the end of the record')
        self.p += n
        return v

    def smap(self) -> Dict[str, str]:
        n = self.u32()
        end = self.p + n
        out = {}
        while self.p < end:
            k = self.s()
            out[k] = self.s()
        return out


def _records(data: bytes, pos: int, end: int):
    while pos < end:
        if pos + 9 > end:
            raise ValueError('torn record header')
        op, length = _REC.unpack_from(data, pos)
        if pos + 9 + length > end:
            raise ValueError(f'record (opcode {op}) runs past the end of the file')
        yield op, pos, data[pos + 9:pos + 9 + length]
        pos += 9 + length


def _take(s: Salvage, op: int, body: bytes, in_chunk: bool) -> None:
    b = _Buf(body)
    if op == OP_SCHEMA:
        sid = b.u16()
        s.schemas[sid] = (b.s(), b.s(), b.b32())
    elif op == OP_CHANNEL:
        cid = b.u16()
        sid = b.u16()
        s.channels[cid] = (b.s(), sid, b.s(), b.smap())
    elif op == OP_MESSAGE:
        cid = b.u16()
        b.u32()
        log_time = b.u64()
        b.u64()
        s.messages.append((cid, log_time, body[b.p:]))
    elif op == OP_METADATA and not in_chunk:
        name = b.s()
        s.metadata.append((name, b.smap()))


_KNOWN_OPS = frozenset(range(1, 16))      # MCAP opcodes 0x01-0x0F


def _chunk_records(body: bytes):
    """(start, end, records) of a Chunk record body; ValueError if torn or failing its CRC."""
    b = _Buf(body)
    t0 = b.u64()
    t1 = b.u64()
    usize = b.u64()
    crc = b.u32()
    comp = b.s()
    clen = b.u64()
    raw = body[b.p:b.p + clen]
    if len(raw) != clen:
        raise ValueError('torn chunk')
    inner = _decompress(comp, raw, usize)
    if len(inner) != usize:
        raise ValueError('chunk fails its size check')
    if crc and zlib.crc32(inner) != crc:
        raise ValueError('chunk CRC mismatch')
    return t0, t1, list(_records(inner, 0, len(inner)))


def _resync(data: bytes, pos: int) -> Optional[int]:
    """The next offset after ``pos`` where an intact Chunk (CRC verified) or the Data End
    record starts; None if there is none."""
    i = pos
    while True:
        i = data.find(bytes((OP_CHUNK,)), i + 1)
        j = data.find(bytes((OP_DATA_END,)) + _U64.pack(4), pos + 1)
        if i < 0 and j < 0:
            return None
        if j >= 0 and (i < 0 or j < i):
            return j
        if i + 9 > len(data):
            return None
        (length,) = _U64.unpack_from(data, i + 1)
        if length < 40 or i + 9 + length > len(data):
            continue
        try:
            _chunk_records(data[i + 9:i + 9 + length])
        except Exception:       # noqa: BLE001 - not a chunk boundary, keep looking
            continue
        return i


def scan(path) -> Salvage:
    """Read every intact record of a (possibly truncated or damaged) MCAP file.

    A chunk that fails its CRC or does not decompress is skipped and reading resumes at the
    next intact chunk; the skipped byte and time ranges are in :attr:`Salvage.lost`.
    """
    p = Path(path)
    if not p.exists():
        raise BagError(p, 'no such file')
    data = p.read_bytes()
    if data[:8] != MAGIC:
        raise BagError(p, 'not an MCAP file (bad magic bytes at the start)')
    s = Salvage()
    pos, end = 8, len(data)
    while pos < end:
        s.stopped_at = pos
        problem = None
        t_range = (None, None)
        if pos + 9 > end:
            s.reason = f'stopped at byte {pos} of {end}: torn record header'
            break
        op, length = _REC.unpack_from(data, pos)
        if op not in _KNOWN_OPS:
            problem = f'unknown opcode {op}'
        elif pos + 9 + length > end:
            if op == OP_CHUNK or op == OP_MESSAGE:
                s.reason = (f'stopped at byte {pos} of {end}: record (opcode {op}) runs past '
                            'the end of the file')
                if op == OP_CHUNK and length >= 16:
                    t_range = struct.unpack_from('<QQ', data, pos + 9)
                    s.lost.append((pos, end, t_range[0], t_range[1], 'torn at the end'))
                break
            problem = f'record (opcode {op}) runs past the end of the file'
        else:
            body = data[pos + 9:pos + 9 + length]
            if op in (OP_DATA_END, OP_FOOTER):
                s.complete = True
                s.reason = 'file is complete (data end found)'
                break
            try:
                if op == OP_CHUNK:
                    t_range = struct.unpack_from('<QQ', body, 0)
                    _t0, _t1, recs = _chunk_records(body)
                    staged = Salvage(s.schemas, s.channels)
                    for iop, _, ibody in recs:
                        _take(staged, iop, ibody, True)
                    s.messages.extend(staged.messages)
                else:
                    _take(s, op, body, False)
            except Exception as exc:    # noqa: BLE001 - any damage: skip this record
                problem = str(exc) or type(exc).__name__
        if problem is None:
            pos += 9 + length
            continue
        nxt = _resync(data, pos)
        s.lost.append((pos, nxt if nxt is not None else end, t_range[0], t_range[1], problem))
        if nxt is None:
            s.reason = f'stopped at byte {pos} of {end}: {problem}; nothing intact after it'
            break
        pos = nxt
    s.stopped_at = pos
    if s.lost and s.complete:
        s.reason = f'file is complete but {len(s.lost)} damaged range(s) were skipped'
    elif s.lost and not s.reason.startswith('stopped'):
        s.reason = f'{len(s.lost)} damaged range(s) skipped'
    return s


def lost_text(s: Salvage) -> List[str]:
    """One line per skipped range: bytes, and the stamps lost when the chunk header says so."""
    out = []
    for b0, b1, t0, t1, why in s.lost:
        when = (f't = {t0 * 1e-9:.6f} .. {t1 * 1e-9:.6f} s lost' if t0 is not None
                else 'time range unknown')
        out.append(f'skipped bytes {b0}-{b1} ({why}): {when}')
    return out


def source_of(path) -> Path:
    """The file to salvage: ``path``, or the ``<path>.part`` a killed writer left."""
    p = Path(path)
    if not p.exists() and partial_path(p).exists():
        return partial_path(p)
    return p


def recover(path, out: Optional[str] = None, force: bool = False) -> dict:
    """Rewrite the readable records of ``path`` into ``out``; returns counts and paths.

    ``path`` may name a recording whose writer was killed: its data is then in ``<path>.part``
    (see :class:`~im_bringup.bag.BagWriter`), which is read instead.
    """
    src = source_of(path)
    out = out or str(Path(path).with_suffix('')) + '.recovered.mcap'
    check_output(out, [src, path], force, what='recovered file')
    s = scan(src)
    if not s.channels:
        raise BagError(src, f'nothing to recover (no channel readable; {s.reason})')
    with BagWriter(out, force=force) as w:
        for name, md in s.metadata:
            if name not in ('rosbag2', 'recovered_from'):
                w.add_metadata(name, md)
        w.add_metadata('recovered_from', {'path': str(src), 'reason': s.reason,
                                          'lost': '; '.join(lost_text(s))})
        topics = {}
        for cid, (topic, sid, enc, meta) in sorted(s.channels.items()):
            tname = s.schemas.get(sid, ('',))[0]
            if enc != 'cdr' or not tname:
                continue
            w.add_topic(topic, tname, qos=meta.get('offered_qos_profiles'))
            topics[cid] = topic
        n = 0
        for cid, t, data in sorted(s.messages, key=lambda m: m[1]):
            topic = topics.get(cid)
            if topic is not None:
                w.write_serialized(topic, data, t)
                n += 1
    return {'input': str(src), 'output': out, 'messages': n, 'topics': len(topics),
            'complete': s.complete, 'reason': s.reason, 'lost': lost_text(s),
            'last_stamp_ns': max((m[1] for m in s.messages), default=None)}


def main(argv=None) -> int:
    from im_common.cli import parse_args
    ap = argparse.ArgumentParser(prog='recover', description='Salvage the readable part of a '
                                 'truncated MCAP recording into a new, valid file.')
    ap.add_argument('bag')
    ap.add_argument('-o', '--out', default=None)
    ap.add_argument('--force', action='store_true', help='overwrite the output file')
    a = parse_args(ap, argv)
    try:
        r = recover(a.bag, a.out, a.force)
    except (BagError, FileExistsError, OSError) as exc:
        print(f'recover: error: {exc}', file=sys.stderr)
        return 2
    last = r['last_stamp_ns']
    for line in r['lost']:
        print(f'recover: {line}', file=sys.stderr)
    print(f"recover: saved {r['messages']} messages on {r['topics']} topics "
          f"(up to t = {last * 1e-9 if last is not None else float('nan'):.6f} s) "
          f"into {r['output']}; {r['reason']}")
    return 0


if __name__ == '__main__':
    sys.exit(main())
