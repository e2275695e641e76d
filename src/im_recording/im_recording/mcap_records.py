"""
The MCAP records of a recording: opcodes, their encoding and the one parser of their bodies.

The writer (:mod:`im_recording.writer`) encodes records with :func:`record` and the string, bytes
and map helpers; the reader (:mod:`im_recording.reader`) and ``recover``
(:mod:`im_recording.recover`) decode them with the parsers here, each of which consumes exactly
a record's body or raises :class:`Damage` naming what does not validate.
"""
from __future__ import annotations

import struct
from typing import Dict, Mapping, Optional, Tuple
import zlib

import lz4.frame
import zstandard

MAGIC = b'\x89MCAP0\r\n'

OP_HEADER, OP_FOOTER, OP_SCHEMA, OP_CHANNEL, OP_MESSAGE, OP_CHUNK = 1, 2, 3, 4, 5, 6
OP_MESSAGE_INDEX, OP_CHUNK_INDEX, OP_STATISTICS, OP_METADATA = 7, 8, 11, 12
OP_METADATA_INDEX, OP_SUMMARY_OFFSET, OP_DATA_END = 13, 14, 15
OP_ATTACHMENT, OP_ATTACHMENT_INDEX = 9, 10

MSG_HDR = struct.Struct('<BQHIQQ')     # opcode, record length, channel, sequence, log, publish
MSG_FIXED = 2 + 4 + 8 + 8
REC = struct.Struct('<BQ')
U16, U32, U64 = struct.Struct('<H'), struct.Struct('<I'), struct.Struct('<Q')
QQ = struct.Struct('<QQ')


def string(text: str) -> bytes:
    """Return ``text`` UTF-8 encoded after its uint32 length: an MCAP String."""
    b = text.encode('utf-8')
    return U32.pack(len(b)) + b


def blob(data: bytes) -> bytes:
    """Return ``data`` as MCAP bytes (uint32 length)."""
    return U32.pack(len(data)) + data


def string_map(d: Mapping[str, str]) -> bytes:
    """Return ``d`` as an MCAP map of strings, sorted by key."""
    body = b''.join(string(str(k)) + string(str(v)) for k, v in sorted(d.items()))
    return U32.pack(len(body)) + body


def record(op: int, body: bytes) -> bytes:
    """Return one record: opcode, uint64 length, body."""
    return REC.pack(op, len(body)) + body


#: a chunk larger than this (uncompressed) is taken for damage; the writer's are <= ~4 MiB
MAX_CHUNK = 1 << 30
#: the chunk compressions a recording's chunks may have
COMPRESSIONS = ('', 'zstd', 'lz4')
CHUNK_HEAD = struct.Struct('<QQQI')


class Damage(ValueError):
    """A record that does not validate (the message says why)."""


# ------------------------------------------------------------------------------------------
# Record bodies: each parser consumes exactly the body or raises Damage
# ------------------------------------------------------------------------------------------
def need(b, p: int, n: int) -> None:
    """Raise Damage unless ``n`` bytes follow offset ``p`` of ``b``."""
    if p + n > len(b):
        raise Damage('a field runs past the end of its record')


def read_string(b, p: int) -> Tuple[str, int]:
    """Return (the String at ``p``, the offset after it)."""
    need(b, p, 4)
    (n,) = U32.unpack_from(b, p)
    need(b, p + 4, n)
    try:
        return bytes(b[p + 4:p + 4 + n]).decode('utf-8'), p + 4 + n
    except UnicodeDecodeError:
        raise Damage('a string field is not UTF-8') from None


def skip_bytes(b, p: int) -> int:
    """Return the offset after the Bytes field at ``p``."""
    need(b, p, 4)
    (n,) = U32.unpack_from(b, p)
    need(b, p + 4, n)
    return p + 4 + n


def read_string_map(b, p: int) -> Tuple[Dict[str, str], int]:
    """Return (the map of Strings at ``p``, the offset after it)."""
    need(b, p, 4)
    (n,) = U32.unpack_from(b, p)
    end = p + 4 + n
    need(b, p + 4, n)
    p += 4
    out = {}
    while p < end:
        k, p = read_string(b, p)
        out[k], p = read_string(b, p)
    if p != end:
        raise Damage('a map field does not end where its length says')
    return out, p


def exact(b, p: int) -> None:
    """Raise Damage unless the fields end exactly at the end of ``b``."""
    if p != len(b):
        raise Damage(f'{len(b) - p} bytes left over after the last field')


def parse_schema(b) -> Tuple[int, str, str]:
    """(id, name, encoding) of a Schema record's body."""
    need(b, 0, 2)
    (sid,) = U16.unpack_from(b, 0)
    name, p = read_string(b, 2)
    enc, p = read_string(b, p)
    exact(b, skip_bytes(b, p))
    if sid == 0 or not name:
        raise Damage('schema id 0 or an empty schema name')
    return sid, name, enc


def parse_channel(b) -> Tuple[int, int, str, str, Dict[str, str]]:
    """(id, schema id, topic, message encoding, metadata) of a Channel record's body."""
    need(b, 0, 4)
    cid, sid = struct.unpack_from('<HH', b, 0)
    topic, p = read_string(b, 4)
    enc, p = read_string(b, p)
    meta, p = read_string_map(b, p)
    exact(b, p)
    if not topic:
        raise Damage('a channel with an empty topic name')
    return cid, sid, topic, enc, meta


def parse_metadata(b) -> Tuple[str, Dict[str, str]]:
    """(name, key -> value) of a Metadata record's body."""
    name, p = read_string(b, 0)
    md, p = read_string_map(b, p)
    exact(b, p)
    return name, md


def parse_message_index(b) -> Tuple[int, int, Optional[int], Optional[int]]:
    """(channel, entries, first stamp, last stamp) of a Message Index record."""
    need(b, 0, 6)
    cid, n = struct.unpack_from('<HI', b, 0)
    if n % 16 or 6 + n != len(b):
        raise Damage('message index array length does not match the record')
    if n == 0:
        return cid, 0, None, None
    stamps = [t for t, _ in struct.iter_unpack('<QQ', b[6:])]
    return cid, len(stamps), min(stamps), max(stamps)


def parse_attachment(b) -> None:
    """Validate an Attachment record's body (its CRC too)."""
    need(b, 0, 16)
    _, p = read_string(b, 16)
    _, p = read_string(b, p)
    need(b, p, 8)
    (n,) = U64.unpack_from(b, p)
    p += 8
    need(b, p, n + 4)
    (crc,) = U32.unpack_from(b, p + n)
    exact(b, p + n + 4)
    if crc and zlib.crc32(b[:p + n]) != crc:
        raise Damage('attachment CRC mismatch')


def chunk_header(b) -> Tuple[int, int, int, int, str, int]:
    """
    (start, end, uncompressed size, CRC, compression, offset of the records) of a Chunk body.

    Damage unless its fields are consistent with each other and with the record's length.
    """
    need(b, 0, CHUNK_HEAD.size)
    t0, t1, usize, crc = CHUNK_HEAD.unpack_from(b, 0)
    comp, p = read_string(b, CHUNK_HEAD.size)
    if comp not in COMPRESSIONS:
        raise Damage(f'unknown chunk compression {comp[:20]!r}')
    need(b, p, 8)
    (clen,) = U64.unpack_from(b, p)
    p += 8
    if p + clen != len(b):
        raise Damage('chunk data size does not match the record length')
    if t0 > t1 or usize > MAX_CHUNK or (comp == '' and usize != clen):
        raise Damage('inconsistent chunk header')
    return t0, t1, usize, crc, comp, p


_zstd = None


def inflate(comp: str, raw, usize: int) -> bytes:
    """
    Return a chunk's records decompressed (``comp``: '', 'zstd' or 'lz4'; ``usize`` bytes).

    Damage when the data does not decompress to exactly one frame of at most ``usize`` bytes.
    """
    global _zstd
    if comp == '':
        return bytes(raw)
    try:
        if comp == 'zstd':
            if _zstd is None:
                _zstd = zstandard.ZstdDecompressor()
            declared = zstandard.frame_content_size(raw)
            if declared not in (-1, usize):
                raise Damage('zstd frame size differs from the chunk header')
            return _zstd.decompress(raw, max_output_size=usize)
        d = lz4.frame.LZ4FrameDecompressor()
        out = d.decompress(bytes(raw), max_length=usize + 1)
        if not d.eof:
            raise Damage('lz4 frame does not end where the chunk does')
        return out
    except Damage:
        raise
    except Exception as exc:    # noqa: BLE001 - the libraries raise many kinds on bad input
        raise Damage(f'chunk does not decompress ({type(exc).__name__})') from None


def chunk_records(b):
    """
    Validate a whole Chunk body and everything in it.

    Returns (uncompressed records, messages as [(channel, log time, data start, data end)],
    declarations as [(number of messages before it, opcode, parsed Schema or Channel)]).
    """
    _t0, _t1, usize, crc, comp, p = chunk_header(b)
    inner = inflate(comp, memoryview(b)[p:], usize)
    if len(inner) != usize:
        raise Damage('chunk size differs from its header after decompression')
    if crc and zlib.crc32(inner) != crc:
        raise Damage('chunk CRC mismatch')
    msgs, decls = [], []
    add = msgs.append
    head, rec = MSG_HDR.unpack_from, REC.unpack_from
    pos, last = 0, usize - MSG_HDR.size
    while pos < usize:
        if pos <= last:
            op, length, cid, _seq, t, _pub = head(inner, pos)
        elif pos + 9 <= usize:
            op, length = rec(inner, pos)
        else:
            raise Damage('torn record inside a chunk')
        end = pos + 9 + length
        if end > usize:
            raise Damage('a record inside the chunk runs past its end')
        if op == OP_MESSAGE and length >= MSG_FIXED:
            add((cid, t, pos + 9 + MSG_FIXED, end))
        elif op == OP_SCHEMA:
            decls.append((len(msgs), op, parse_schema(inner[pos + 9:end])))
        elif op == OP_CHANNEL:
            decls.append((len(msgs), op, parse_channel(inner[pos + 9:end])))
        else:
            raise Damage(f'record of opcode {op} inside a chunk')
        pos = end
    return inner, msgs, decls
