"""Salvage a recording cut short by a hard kill (no summary, no footer, maybe a torn chunk).

``ros2 run im_bringup recover bags/broken.mcap [-o fixed.mcap] [--force]``

Reads the file record by record from the start, keeps every Schema, Channel and Metadata record
and every message of every complete chunk (and loose Message records), stops at the first torn or
corrupt record, and rewrites all of it through :class:`~im_bringup.bag.BagWriter` into a valid,
indexed file (default ``<name>.recovered.mcap``). Prints how many messages were saved and where
reading stopped. Exit code 2 if nothing could be read at all.
"""
from __future__ import annotations

import argparse
import struct
import sys
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Dict, List, Optional, Tuple

from .bag import (MAGIC, OP_CHANNEL, OP_CHUNK, OP_DATA_END, OP_FOOTER, OP_MESSAGE, OP_METADATA,
                  OP_SCHEMA, BagError, BagWriter, _decompress)

_REC = struct.Struct('<BQ')
_U16, _U32, _U64 = struct.Struct('<H'), struct.Struct('<I'), struct.Struct('<Q')


@dataclass
class Salvage:
    schemas: Dict[int, Tuple[str, str, bytes]] = field(default_factory=dict)
    channels: Dict[int, Tuple[str, int, str, Dict[str, str]]] = field(default_factory=dict)
    metadata: List[Tuple[str, Dict[str, str]]] = field(default_factory=list)
    messages: List[Tuple[int, int, bytes]] = field(default_factory=list)   # (cid, log_time, data)
    stopped_at: int = 0
    reason: str = 'end of data section'
    complete: bool = False


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


def scan(path) -> Salvage:
    """Read every intact record of a (possibly truncated) MCAP file."""
    p = Path(path)
    if not p.exists():
        raise BagError(p, 'no such file')
    data = p.read_bytes()
    if data[:8] != MAGIC:
        raise BagError(p, 'not an MCAP file (bad magic bytes at the start)')
    s = Salvage()
    pos = 8
    try:
        for op, rpos, body in _records(data, 8, len(data)):
            s.stopped_at = rpos
            if op in (OP_DATA_END, OP_FOOTER):
                s.complete = True
                s.reason = 'file is complete (data end found)'
                break
            if op == OP_CHUNK:
                b = _Buf(body)
                b.u64()
                b.u64()
                usize = b.u64()
                crc = b.u32()
                comp = b.s()
                clen = b.u64()
                raw = body[b.p:b.p + clen]
                if len(raw) != clen:
                    raise ValueError('torn chunk')
                inner = _decompress(comp, raw, usize)
                if len(inner) != usize or (crc and zlib.crc32(inner) != crc):
                    raise ValueError('chunk fails its size/CRC check')
                staged = Salvage(s.schemas, s.channels)
                for iop, _, ibody in _records(inner, 0, len(inner)):
                    _take(staged, iop, ibody, True)
                s.messages.extend(staged.messages)
            else:
                _take(s, op, body, False)
            pos = rpos + 9 + len(body)
            s.stopped_at = pos
    except Exception as exc:  # a torn or corrupt record ends the salvage
        s.reason = f'stopped at byte {s.stopped_at} of {len(data)}: {exc}'
    return s


def recover(path, out: Optional[str] = None, force: bool = False) -> dict:
    """Rewrite the readable prefix of ``path`` into ``out``; returns counts and paths."""
    s = scan(path)
    if not s.channels:
        raise BagError(path, f'nothing to recover (no channel readable; {s.reason})')
    out = out or str(Path(path).with_suffix('')) + '.recovered.mcap'
    if Path(out).resolve() == Path(path).resolve():
        raise BagError(out, 'refusing to overwrite the damaged input; choose another -o')
    with BagWriter(out, force=force) as w:
        for name, md in s.metadata:
            if name != 'rosbag2':
                w.add_metadata(name, md)
        w.add_metadata('recovered_from', {'path': str(path), 'reason': s.reason})
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
    return {'input': str(path), 'output': out, 'messages': n, 'topics': len(topics),
            'complete': s.complete, 'reason': s.reason,
            'last_stamp_ns': max((m[1] for m in s.messages), default=None)}


def main(argv=None) -> int:
    from rclpy.utilities import remove_ros_args
    args = remove_ros_args(args=list(sys.argv if argv is None else ['recover'] + list(argv)))[1:]
    ap = argparse.ArgumentParser(prog='recover', description='Salvage the readable part of a '
                                 'truncated MCAP recording into a new, valid file.')
    ap.add_argument('bag')
    ap.add_argument('-o', '--out', default=None)
    ap.add_argument('--force', action='store_true', help='overwrite the output file')
    a = ap.parse_args(args)
    try:
        r = recover(a.bag, a.out, a.force)
    except (BagError, FileExistsError, OSError) as exc:
        print(f'recover: error: {exc}', file=sys.stderr)
        return 2
    last = r['last_stamp_ns']
    print(f"recover: saved {r['messages']} messages on {r['topics']} topics "
          f"(up to t = {last * 1e-9 if last is not None else float('nan'):.6f} s) "
          f"into {r['output']}; {r['reason']}")
    return 0


if __name__ == '__main__':
    sys.exit(main())
