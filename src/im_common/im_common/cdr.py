"""
Exact-length CDR (XCDR1, little endian) encoding and decoding of ROS 2 messages.

Why not only ``rclpy.serialization.serialize_message``? Two measured reasons (see
``docs/recording.md``):

* it costs ≈ 4.5 µs per ``Vector3Stamped`` here, most of the recorder's budget;
* the buffer it returns carries trailing bytes past the end of the CDR payload (and uninitialised
  padding), which strict readers such as ``rosbags`` reject ("CDR message size mismatch").

So the bag writer encodes the stack's three message types with ``struct`` (fast paths), and any
other type with a generic codec compiled from the message class's introspection data
(``SLOT_TYPES``). Alignment follows classic CDR: a primitive of size n is aligned to n bytes
(n ≤ 8) relative to the start of the payload, i.e. after the 4-byte encapsulation header; the
elements of an empty sequence are not aligned. Padding bytes are written as zeros.
"""
from __future__ import annotations

import importlib
import struct
from typing import Any, Callable, Dict, Tuple

import numpy as np

try:    # the fast paths' message classes (module level: no deferral)
    from geometry_msgs.msg import Vector3Stamped
    from rosgraph_msgs.msg import Clock
    from sensor_msgs.msg import JointState
except ImportError:  # pragma: no cover - message packages are exec_depends
    Vector3Stamped = Clock = JointState = None

ENCAPSULATION = b'\x00\x01\x00\x00'   # CDR_LE, no options
#: nanoseconds per second: builtin_interfaces/Time splits a stamp into sec and nanosec by it
#: (:mod:`im_common.conversions` re-exports it: stamps are that module's subject)
NS_PER_S = 1_000_000_000

_BASIC = {
    'boolean': ('?', 1), 'octet': ('B', 1), 'char': ('B', 1), 'uint8': ('B', 1), 'int8': ('b', 1),
    'int16': ('h', 2), 'uint16': ('H', 2), 'int32': ('i', 4), 'uint32': ('I', 4),
    'int64': ('q', 8), 'uint64': ('Q', 8), 'float': ('f', 4), 'double': ('d', 8),
}
_U32 = struct.Struct('<I')


class CdrError(ValueError):
    """A payload does not decode as the announced type."""


def message_class(type_name: str):
    """Return the rclpy message class of ``pkg/msg/Type`` (or ``pkg/Type``)."""
    parts = type_name.split('/')
    if len(parts) == 2:
        parts = [parts[0], 'msg', parts[1]]
    if len(parts) != 3 or not all(parts):
        raise ValueError(f'not a ROS 2 message type name: {type_name!r}')
    try:
        mod = importlib.import_module(f'{parts[0]}.{parts[1]}')
        return getattr(mod, parts[2])
    except (ImportError, AttributeError):
        raise ValueError(f'message type {type_name!r} is not installed') from None


def _pad(pos: int, align: int) -> int:
    return (-pos) % align


# ------------------------------------------------------------------------------------------
# Generic codec, compiled from rosidl introspection
# ------------------------------------------------------------------------------------------
def _field_codec(slot) -> Tuple[Callable, Callable]:
    """
    (encode(value, out: bytearray), decode(buf, pos) -> (value, pos)) for one slot type.

    Positions are offsets into the *whole* buffer; alignment is relative to offset 4.
    """
    kind = type(slot).__name__
    if kind == 'BasicType':
        fmt, size = _BASIC[slot.typename]
        return _basic_codec(fmt, size)
    if kind in ('UnboundedString', 'BoundedString'):
        return _string_codec()
    if kind == 'NamespacedType':
        cls = message_class('/'.join(slot.namespaces + [slot.name]))
        return _message_codec(cls)
    if kind in ('Array', 'UnboundedSequence', 'BoundedSequence'):
        vt = slot.value_type
        fixed = kind == 'Array'
        count = slot.size if fixed else None
        if type(vt).__name__ == 'BasicType' and vt.typename in _BASIC:
            fmt, size = _BASIC[vt.typename]
            return _basic_sequence_codec(fixed, count, fmt, size)
        return _sequence_codec(fixed, count, *_field_codec(vt))
    raise NotImplementedError(f'CDR codec: unsupported field type {kind}')


def _basic_codec(fmt: str, size: int) -> Tuple[Callable, Callable]:
    """Return the codec of one primitive of struct format ``fmt``, ``size`` bytes."""
    st = struct.Struct('<' + fmt)

    def enc(v, out, st=st, size=size):
        out += bytes(_pad(len(out) - 4, size))
        out += st.pack(v)

    def dec(buf, pos, st=st, size=size):
        pos += _pad(pos - 4, size)
        return st.unpack_from(buf, pos)[0], pos + size
    return enc, dec


def _string_codec() -> Tuple[Callable, Callable]:
    """Return the codec of a string (length with its NUL, UTF-8 bytes, NUL)."""
    def enc(v, out):
        b = v.encode('utf-8')
        out += bytes(_pad(len(out) - 4, 4))
        out += _U32.pack(len(b) + 1)
        out += b
        out += b'\x00'

    def dec(buf, pos):
        pos += _pad(pos - 4, 4)
        (n,) = _U32.unpack_from(buf, pos)
        pos += 4
        if n == 0 or pos + n > len(buf):
            raise CdrError('string runs past the end of the payload')
        return bytes(buf[pos:pos + n - 1]).decode('utf-8'), pos + n
    return enc, dec


def _basic_sequence_codec(fixed: bool, count, fmt: str, size: int) -> Tuple[Callable, Callable]:
    """Return the codec of an array (``fixed``, ``count`` long) or a sequence of primitives."""
    def enc(v, out, fmt=fmt, size=size):
        n = len(v)
        _enc_count(out, n, fixed, count)
        if n:
            out += bytes(_pad(len(out) - 4, size))
            out += struct.pack(f'<{n}{fmt}', *v)

    def dec(buf, pos, fmt=fmt, size=size):
        n, pos = _dec_count(buf, pos, fixed, count)
        if n:
            pos += _pad(pos - 4, size)
            if pos + n * size > len(buf):
                raise CdrError('sequence runs past the end of the payload')
            vals = struct.unpack_from(f'<{n}{fmt}', buf, pos)
            pos += n * size
        else:
            vals = ()
        return list(vals), pos
    return enc, dec


def _enc_count(out: bytearray, n: int, fixed: bool, count) -> None:
    """Write a sequence's length (aligned uint32); check an array's (``fixed``) instead."""
    if not fixed:
        out += bytes(_pad(len(out) - 4, 4))
        out += _U32.pack(n)
    elif n != count:
        raise CdrError(f'array needs {count} elements, got {n}')


def _dec_count(buf, pos: int, fixed: bool, count) -> Tuple[int, int]:
    """Return (elements, position after the length): an array's ``count``, a sequence's read."""
    if fixed:
        return count, pos
    pos += _pad(pos - 4, 4)
    (n,) = _U32.unpack_from(buf, pos)
    return n, pos + 4


def _sequence_codec(fixed: bool, count, e_enc: Callable,
                    e_dec: Callable) -> Tuple[Callable, Callable]:
    """Return the codec of an array (``fixed``, ``count`` long) or a sequence of any element."""
    def enc(v, out):
        _enc_count(out, len(v), fixed, count)
        for item in v:
            e_enc(item, out)

    def dec(buf, pos):
        n, pos = _dec_count(buf, pos, fixed, count)
        if not fixed and n > len(buf):
            raise CdrError('sequence length larger than the payload')
        vals = []
        for _ in range(n):
            x, pos = e_dec(buf, pos)
            vals.append(x)
        return vals, pos
    return enc, dec


_CODECS: Dict[type, Tuple[Callable, Callable]] = {}


def _message_codec(cls):
    codec = _CODECS.get(cls)
    if codec is not None:
        return codec
    names = list(cls.get_fields_and_field_types().keys())
    parts = [(n, *_field_codec(s)) for n, s in zip(names, cls.SLOT_TYPES)]

    def enc(msg, out):
        for name, f_enc, _ in parts:
            f_enc(getattr(msg, name), out)

    def dec(buf, pos):
        d = {}
        for name, _, f_dec in parts:
            d[name], pos = f_dec(buf, pos)
        return d, pos
    _CODECS[cls] = (enc, dec)
    return enc, dec


def decode_generic(cls, data) -> Tuple[dict, int]:
    """Decode to nested dicts; returns (fields, end offset of the CDR payload)."""
    if len(data) < 4 or data[1] != 1:
        raise CdrError('not a little-endian CDR payload (bad encapsulation header)')
    _, dec = _message_codec(cls)
    try:
        return dec(data, 4)
    except struct.error as exc:
        raise CdrError(f'payload too short: {exc}') from None


def payload_length(type_name: str, data) -> int:
    """Exact length of the CDR payload at the start of ``data`` (ignoring trailing bytes)."""
    fast = _LENGTH_FAST.get(type_name)
    if fast is not None:
        n = fast(data)
        if n is not None:
            return n
    return decode_generic(message_class(type_name), data)[1]


# ------------------------------------------------------------------------------------------
# Fast paths for the stack's topic types
# ------------------------------------------------------------------------------------------
_V3_EMPTY = struct.Struct('<HHiIIIddd')        # encapsulation, stamp, frame_id '' , x, y, z
V3_EMPTY_SIZE = _V3_EMPTY.size                  # 44
_CLOCK = struct.Struct('<HHiI')
_STAMP = struct.Struct('<iI')
_DDD = struct.Struct('<ddd')


_v3_framed: Dict[str, Tuple[struct.Struct, int, bytes]] = {}


def _v3_struct(frame_id: str):
    """(Struct, string length, frame bytes) of a Vector3Stamped with this frame_id."""
    b = frame_id.encode('utf-8')
    n = len(b) + 1
    pad = _pad(12 + n, 8)            # doubles start 8-aligned in the payload
    entry = (struct.Struct(f'<HHiII{n}s{pad}xddd'), n, b)
    if len(_v3_framed) < 256:
        _v3_framed[frame_id] = entry
    return entry


def pack_vector3_stamped(sec: int, nanosec: int, x: float, y: float, z: float,
                         frame_id: str = '') -> bytes:
    if not frame_id:
        return _V3_EMPTY.pack(256, 0, sec, nanosec, 1, 0, x, y, z)
    e = _v3_framed.get(frame_id) or _v3_struct(frame_id)
    return e[0].pack(256, 0, sec, nanosec, e[1], e[2], x, y, z)


def pack_clock(sec: int, nanosec: int) -> bytes:
    return _CLOCK.pack(256, 0, sec, nanosec)


_names_cache: Dict[tuple, bytes] = {}


def _names_block(names, start: int) -> bytes:
    """Return the encoded ``string[] name`` starting at (aligned) payload offset ``start``."""
    key = (start & 3, tuple(names))
    blk = _names_cache.get(key)
    if blk is None:
        out = bytearray(start & 3)  # dummy prefix so that alignment arithmetic is right
        out += bytes(_pad(len(out), 4))
        out += _U32.pack(len(names))
        for s in names:
            b = s.encode('utf-8')
            out += bytes(_pad(len(out), 4))
            out += _U32.pack(len(b) + 1) + b + b'\x00'
        blk = bytes(out[start & 3:])
        if len(_names_cache) < 1024:
            _names_cache[key] = blk
    return blk


def _pack_doubles(out: bytearray, vals) -> None:
    n = len(vals)
    out += bytes(_pad(len(out) - 4, 4))
    out += _U32.pack(n)
    if n:
        out += bytes(_pad(len(out) - 4, 8))
        out += struct.pack(f'<{n}d', *vals)


def pack_joint_state(sec: int, nanosec: int, names, position=(), velocity=(), effort=(),
                     frame_id: str = '') -> bytes:
    fb = frame_id.encode('utf-8')
    out = bytearray(ENCAPSULATION)
    out += _STAMP.pack(sec, nanosec)
    out += _U32.pack(len(fb) + 1)
    out += fb + b'\x00'
    out += _names_block(names, len(out) - 4)
    _pack_doubles(out, position)
    _pack_doubles(out, velocity)
    _pack_doubles(out, effort)
    return bytes(out)


def joint_state_packer(names, n_position: int, n_velocity: int, n_effort: int,
                       frame_id: str = ''):
    """
    Make a one-call packer of JointStates with fixed names, frame id and sequence lengths.

    ``pack(sec, nanosec, position, velocity, effort) -> bytes`` for JointStates of fixed names,
    frame id and sequence lengths: one ``struct`` call instead of :func:`pack_joint_state`'s
    piecewise build (the graph publishes the plant's shaft and the adapter's estimates every step).
    Its layout is checked against :func:`pack_joint_state` when it is made.
    """
    fb = frame_id.encode('utf-8')
    head = bytearray(ENCAPSULATION + bytes(8))
    head += _U32.pack(len(fb) + 1) + fb + b'\x00'
    head += _names_block(names, len(head) - 4)
    fmt = ['<HHiI', f'{len(head) - 12}s']
    consts = [bytes(head[12:])]
    size = len(head)
    for n in (n_position, n_velocity, n_effort):
        seq = bytearray(_pad(size - 4, 4)) + _U32.pack(n)
        if n:
            seq += bytes(_pad(size + len(seq) - 4, 8))
        fmt += [f'{len(seq)}s', f'{n}d']
        consts.append(bytes(seq))
        size += len(seq) + 8 * n
    st = struct.Struct(''.join(fmt))
    mid, c_pos, c_vel, c_eff = consts
    _pack = st.pack

    def pack(sec: int, nanosec: int, position, velocity=(), effort=()) -> bytes:
        return _pack(256, 0, sec, nanosec, mid, c_pos, *position, c_vel, *velocity, c_eff,
                     *effort)
    sample = (tuple(0.5 + i for i in range(n_position)), tuple(1.5 + i for i in range(n_velocity)),
              tuple(2.5 + i for i in range(n_effort)))
    if pack(7, 9, *sample) != pack_joint_state(7, 9, names, *sample, frame_id=frame_id):
        raise AssertionError('joint_state_packer: layout differs from pack_joint_state')
    return pack


def _enc_v3(m) -> bytes:
    h = m.header
    st = h.stamp
    v = m.vector
    return pack_vector3_stamped(st.sec, st.nanosec, v.x, v.y, v.z, h.frame_id)


def _enc_js(m) -> bytes:
    h = m.header
    st = h.stamp
    return pack_joint_state(st.sec, st.nanosec, m.name, m.position, m.velocity, m.effort,
                            h.frame_id)


def _enc_clock(m) -> bytes:
    c = m.clock
    return _CLOCK.pack(256, 0, c.sec, c.nanosec)


def _len_v3(data):
    if len(data) >= 16:
        (n,) = _U32.unpack_from(data, 12)
        end = 16 + n
        return end + _pad(end - 4, 8) + 24
    return None


def _len_clock(data):
    return 12


_LENGTH_FAST = {
    'sensor_msgs/msg/JointState': lambda d: _len_js(d),
    'geometry_msgs/msg/Vector3Stamped': _len_v3,
    'rosgraph_msgs/msg/Clock': _len_clock,
}

_ENCODERS: Dict[type, Callable[[Any], bytes]] = {}


def _init_fast():
    if Vector3Stamped is None:  # pragma: no cover - message packages are exec_depends
        return
    _ENCODERS[Vector3Stamped] = _enc_v3
    _ENCODERS[JointState] = _enc_js
    _ENCODERS[Clock] = _enc_clock


_init_fast()


def encoder_for(cls) -> Callable[[Any], bytes]:
    """Return a function msg -> exact CDR bytes for messages of class ``cls``."""
    f = _ENCODERS.get(cls)
    if f is None:
        enc, _ = _message_codec(cls)

        def f(msg, enc=enc):
            out = bytearray(ENCAPSULATION)
            enc(msg, out)
            return bytes(out)
        _ENCODERS[cls] = f
    return f


def encode(msg) -> bytes:
    return encoder_for(type(msg))(msg)


def decode_joint_state(data) -> Tuple[int, int, tuple, tuple, tuple, tuple]:
    """(sec, nanosec, names, position, velocity, effort) of a JointState payload."""
    return _parse_joint_state(data)[0]


def _len_js(data):
    return _parse_joint_state(data)[1]


def _parse_joint_state(data):
    """
    Decode a JointState payload in one pass.

    Returns ((sec, nanosec, names, position, velocity, effort), end of the payload, end of the
    frame id, ((offset, count) of position, velocity, effort)).
    """
    try:
        sec, nsec = _STAMP.unpack_from(data, 4)
        (n,) = _U32.unpack_from(data, 12)
        pos = fid_end = 16 + n
        pos += _pad(pos - 4, 4)
        (cnt,) = _U32.unpack_from(data, pos)
        pos += 4
        names = []
        for _ in range(cnt):
            pos += _pad(pos - 4, 4)
            (n,) = _U32.unpack_from(data, pos)
            pos += 4
            names.append(bytes(data[pos:pos + n - 1]).decode('utf-8'))
            pos += n
        seqs, blocks = [], []
        for _ in range(3):
            pos += _pad(pos - 4, 4)
            (cnt,) = _U32.unpack_from(data, pos)
            pos += 4
            if cnt:
                pos += _pad(pos - 4, 8)
                seqs.append(struct.unpack_from(f'<{cnt}d', data, pos))
            else:
                seqs.append(())
            blocks.append((pos, cnt))
            pos += 8 * cnt
    except (struct.error, UnicodeDecodeError) as exc:
        raise CdrError(f'bad JointState payload: {exc}') from None
    if pos > len(data):
        raise CdrError('JointState payload shorter than its sequences')
    return (sec, nsec, tuple(names), seqs[0], seqs[1], seqs[2]), pos, fid_end, tuple(blocks)


def joint_state_layout(data) -> Tuple[int, Tuple[Tuple[int, int], ...], int]:
    """
    Return where a JointState payload keeps its values: (end of the frame id, blocks, length).

    ``blocks`` = ((offset, count) of position, velocity, effort): each block's doubles start at
    ``offset``. Payloads of one length whose bytes between the frame id and the blocks are equal
    have the same names and counts, hence their values at the same offsets (a batch decoder reads
    them in one go: :func:`im_recording.recorded_run.decode_topic`).
    """
    _, end, fid_end, blocks = _parse_joint_state(data)
    return fid_end, blocks, end


def decode_vector3_stamped(data) -> Tuple[int, int, float, float, float]:
    try:
        sec, nsec = _STAMP.unpack_from(data, 4)
        (n,) = _U32.unpack_from(data, 12)
        pos = 16 + n
        pos += _pad(pos - 4, 8)
        x, y, z = _DDD.unpack_from(data, pos)
    except struct.error as exc:
        raise CdrError(f'bad Vector3Stamped payload: {exc}') from None
    return sec, nsec, x, y, z


def header_stamp_ns(data) -> int:
    """Stamp of a message whose first field is a Header or a Time (offset 4): ns."""
    sec, nsec = _STAMP.unpack_from(data, 4)
    return sec * NS_PER_S + nsec


# ------------------------------------------------------------------------------------------
# Batch decoding: many payloads of one layout in one read
# ------------------------------------------------------------------------------------------
def _rows(payloads):
    """Return the payloads as rows of one (n, length) byte array; None if their lengths differ."""
    if not payloads or len(set(map(len, payloads))) != 1:
        return None
    return np.frombuffer(b''.join(payloads), np.uint8).reshape(len(payloads), -1)


def _same_bytes(rows, a: int, b: int) -> bool:
    """Tell whether every row holds the first row's bytes ``a:b``."""
    return bool((rows[:, a:b] == rows[0, a:b]).all())


def _stamps_ns(a):
    return a['sec'].astype(np.int64) * NS_PER_S + a['nsec'].astype(np.int64)


def vector3_stamped_batch(payloads):
    """
    Return (stamps [ns], x, y, z) arrays of ``Vector3Stamped`` payloads of one layout, or None.

    One layout: one length and one frame id length throughout (a graph's tag in the frame id
    changes, its length not), so the doubles sit at the same offsets in each: one ``frombuffer``
    reads them all, the values :func:`decode_vector3_stamped` gives one by one (measured in
    ``benchmarks/bench_bag.py``: ``us_per_msg_decode_v3_batch`` against
    ``us_per_msg_decode_v3_each``). None when the payloads differ in layout (then decode each).
    """
    rows = _rows(payloads)
    if rows is None or rows.shape[1] < V3_EMPTY_SIZE or not _same_bytes(rows, 12, 16):
        return None
    n = rows.shape[1]
    a = rows.view(np.dtype({'names': ['sec', 'nsec', 'x', 'y', 'z'],
                            'formats': ['<i4', '<u4', '<f8', '<f8', '<f8'],
                            'offsets': [4, 8, n - 24, n - 16, n - 8], 'itemsize': n}))[:, 0]
    return _stamps_ns(a), a['x'].copy(), a['y'].copy(), a['z'].copy()


def joint_state_batch(payloads):
    """
    Return (stamps [ns], names, [position, velocity, effort] arrays) of ``JointState`` payloads.

    None unless every payload has the first one's length, frame id length, names and counts
    (:func:`joint_state_layout`; the tag in the frame id may differ): then one ``frombuffer``
    reads them all, the same doubles :func:`decode_joint_state` reads one by one. A sequence
    that is empty is None; the others are (payloads, count) arrays.
    """
    rows = _rows(payloads)
    if rows is None:
        return None
    p0 = payloads[0]
    n = len(p0)
    try:
        fid_end, blocks, end = joint_state_layout(p0)
    except CdrError:
        return None
    if end != n or not _same_bytes(rows, 12, 16):
        return None
    at = fid_end
    for off, cnt in blocks:         # the names and counts between the frame id and the values
        if not _same_bytes(rows, at, off):
            return None
        at = off + 8 * cnt
    names = ['sec', 'nsec'] + [f'q{j}' for j in range(3) if blocks[j][1]]
    formats = ['<i4', '<u4'] + [('<f8', (c,)) for _, c in blocks if c]
    offsets = [4, 8] + [off for off, c in blocks if c]
    a = rows.view(np.dtype({'names': names, 'formats': formats, 'offsets': offsets,
                            'itemsize': n}))[:, 0]
    seqs = [a[f'q{j}'] if blocks[j][1] else None for j in range(3)]
    return _stamps_ns(a), decode_joint_state(p0)[2], seqs
