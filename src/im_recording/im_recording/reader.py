"""
Recordings read back.

What a file holds (:func:`info`), its messages raw (:func:`iter_raw`) or deserialized
(:func:`read_messages`), its data CRC (:func:`check_data_crc`).

Stamps are simulated time whichever log times the file holds (its ``log_time`` record,
:func:`im_recording.metadata.log_time_offset`); :func:`im_recording.recorded_run.load_run` turns a
recording into a :class:`~im_recording.recorded_run.RecordedRun`. Any unreadable, truncated or
missing file raises :class:`~im_recording.files.BagError` naming the file and what is wrong.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from operator import itemgetter
from pathlib import Path
import struct
from typing import Dict, Iterable, Iterator, Optional, Tuple
import zlib

from im_common import cdr
from mcap.reader import make_reader

from .files import BagError, partial_path
from .mcap_records import (chunk_records, Damage, MAGIC, OP_CHUNK, OP_DATA_END, OP_FOOTER,
                           REC, U32)
from .metadata import log_time_offset

_LOG_TIME = itemgetter(1)
#: the shortest closed file: magic, a Footer record (opcode, length, 20 bytes), magic
_CLOSED_MIN = 8 + 9 + 20 + 8


@dataclass
class BagInfo:
    path: str
    topics: Dict[str, str]                  # topic -> type
    counts: Dict[str, int]                  # topic -> messages
    start_ns: int
    end_ns: int
    message_count: int
    metadata: Dict[str, Dict[str, str]]
    channels: dict = field(default_factory=dict, repr=False)   # cid -> (topic, type, metadata)

    @property
    def log_time_offset(self) -> int:
        """Return log time − stamp [ns] (:func:`log_time_offset`); start/end_ns are log times."""
        return log_time_offset(self.metadata, self.path)


def _open_checked(path):
    p = Path(path)
    if not p.exists():
        if partial_path(p).exists():
            raise BagError(p, f'no such file, but an interrupted (truncated) recording is at '
                           f'{partial_path(p)}; salvage it with '
                           f'`ros2 run im_recording recover {partial_path(p)} -o {p}`')
        raise BagError(p, 'no such file')
    if p.is_dir():
        raise BagError(p, 'is a directory; expected an .mcap file')
    size = p.stat().st_size
    with open(p, 'rb') as f:
        head = f.read(8)
        if head != MAGIC:
            raise BagError(p, 'not an MCAP file (bad magic bytes at the start)'
                           if size >= 8 else f'not an MCAP file (only {size} bytes)')
        f.seek(max(0, size - 8))
        tail = f.read(8)
    if size < _CLOSED_MIN or tail != MAGIC:
        raise BagError(p, 'truncated: no MCAP footer (the writer did not close the file - killed?)'
                       f'; salvage it with `ros2 run im_recording recover {p}`')
    return p


def _check_summary_crc(p: Path) -> None:
    """Return the footer's summary CRC (summary start .. footer's own fields) must match."""
    size = p.stat().st_size
    with open(p, 'rb') as f:
        f.seek(size - 8 - 29)
        foot = f.read(29)
        op, length = REC.unpack_from(foot, 0)
        if op != OP_FOOTER or length != 20:
            raise BagError(p, 'corrupt footer (the last record is not an MCAP Footer)')
        start, _offsets, crc = struct.unpack_from('<QQI', foot, 9)
        if not crc or not start:
            return
        if start > size - 8 - 29:
            raise BagError(p, f'corrupt footer: summary start {start} past the footer')
        f.seek(start)
        body = f.read(size - 8 - 4 - start)
    got = zlib.crc32(body)
    if got != crc:
        raise BagError(p, f'summary section CRC mismatch (stored {crc:#010x}, computed '
                          f'{got:#010x}): the index is damaged; '
                          f'`ros2 run im_recording recover {p}` '
                          'rebuilds it from the data')


def check_data_crc(path) -> None:
    """Return the Data End record's CRC over the whole data section (BagError on a mismatch)."""
    p = _open_checked(path)
    size = p.stat().st_size
    with open(p, 'rb') as f:
        f.seek(size - 8 - 29)
        foot = f.read(29)
        start = struct.unpack_from('<Q', foot, 9)[0] or (size - 8 - 29)
        f.seek(start - 13)
        end_rec = f.read(13)
        op, length = REC.unpack_from(end_rec, 0)
        if op != OP_DATA_END or length != 4:
            return                  # a writer that does not put Data End right before
        (stored,) = U32.unpack_from(end_rec, 9)
        if not stored:
            return
        f.seek(0)
        crc, left = 0, start - 13
        while left > 0:
            block = f.read(min(left, 1 << 22))
            if not block:
                break
            crc = zlib.crc32(block, crc)
            left -= len(block)
    if crc != stored:
        raise BagError(p, f'data section CRC mismatch (stored {stored:#010x}, computed '
                          f'{crc:#010x}): the file was altered after it was written')


def _summary(path):
    p = _open_checked(path)
    _check_summary_crc(p)
    try:
        with open(p, 'rb') as f:
            reader = make_reader(f)
            summary = reader.get_summary()
            if summary is None:
                raise BagError(p, 'no summary section (cannot index the recording)')
            metadata = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
    except BagError:
        raise
    except Exception as exc:   # mcap raises many kinds on corrupt input
        raise BagError(p, f'corrupt MCAP summary: {type(exc).__name__}: {exc}') from None
    return p, summary, metadata


def info(path) -> BagInfo:
    """Topics, types, counts, time range and metadata of a recording."""
    p, summary, metadata = _summary(path)
    topics, counts, channels = {}, {}, {}
    st = summary.statistics
    for cid, ch in summary.channels.items():
        sch = summary.schemas.get(ch.schema_id)
        tname = sch.name if sch else ''
        topics[ch.topic] = tname
        counts[ch.topic] = st.channel_message_counts.get(cid, 0) if st else 0
        channels[cid] = (ch.topic, tname, dict(ch.metadata))
    return BagInfo(str(p), topics, counts, st.message_start_time if st else 0,
                   st.message_end_time if st else 0, st.message_count if st else 0,
                   metadata, channels)


def iter_raw(path, topics: Optional[Iterable[str]] = None, log_time: bool = False
             ) -> Iterator[Tuple[str, str, int, bytes]]:
    """
    (topic, type, stamp_ns, cdr bytes) in log-time order (stable within equal times).

    ``stamp_ns`` is simulated time: the log time less the file's log-time offset
    (:func:`log_time_offset`); with ``log_time`` the log time as stored.
    """
    p, summary, metadata = _summary(path)
    off = 0 if log_time else log_time_offset(metadata, p)
    if off:
        for topic, tname, t, data in _iter_raw(p, summary, topics):
            yield topic, tname, t - off, data
    else:
        yield from _iter_raw(p, summary, topics)


def _iter_raw(p, summary, topics):
    want = None if topics is None else set(topics)
    chans = {}
    for cid, ch in summary.channels.items():
        if want is None or ch.topic in want:
            sch = summary.schemas.get(ch.schema_id)
            chans[cid] = (ch.topic, sch.name if sch else '')
    if want is not None:
        missing = want - {c[0] for c in chans.values()}
        if missing:
            raise BagError(p, f'topic(s) not in the recording: {sorted(missing)}')
    idx = sorted(summary.chunk_indexes, key=lambda c: (c.message_start_time, c.chunk_start_offset))
    overlapping = any(b.message_start_time < a.message_end_time for a, b in zip(idx, idx[1:]))
    if overlapping:
        yield from _iter_raw_mcap(p, chans)
        return
    with open(p, 'rb') as f:
        for ci in idx:
            if want is not None and not (set(ci.message_index_offsets) & set(chans)):
                continue
            yield from _chunk_messages(p, f, ci, chans)


def _chunk_messages(p, f, ci, chans):
    """Yield the messages on ``chans`` of the chunk ``ci`` points at, in log-time order."""
    try:
        f.seek(ci.chunk_start_offset)
        raw = f.read(ci.chunk_length)
        op, length = REC.unpack_from(raw, 0)
        if op != OP_CHUNK:
            raise Damage(f'chunk index points at opcode {op}')
        data, msgs, _decls = chunk_records(memoryview(raw)[9:9 + length])
    except Exception as exc:    # noqa: BLE001 - Damage, or a short read of a damaged file
        raise BagError(p, f'corrupt chunk at byte {ci.chunk_start_offset}: {exc}') from None
    msgs.sort(key=_LOG_TIME)            # stable: equal log times stay in file order
    get = chans.get
    for cid, log_time, start, end in msgs:
        c = get(cid)
        if c is not None:
            yield c[0], c[1], log_time, data[start:end]


def _iter_raw_mcap(p, chans):
    try:
        with open(p, 'rb') as f:
            for sch, ch, m in make_reader(f,
                                          validate_crcs=True).iter_messages(log_time_order=True):
                if m.channel_id in chans:
                    topic, tname = chans[m.channel_id]
                    yield topic, tname, m.log_time, m.data
    except BagError:
        raise
    except Exception as exc:
        raise BagError(p, f'corrupt MCAP data: {type(exc).__name__}: {exc}') from None


def read_messages(path, topics: Optional[Iterable[str]] = None
                  ) -> Iterator[Tuple[str, int, object]]:
    """(topic, stamp_ns, rclpy message) in log-time order (stamps as :func:`iter_raw`)."""
    from rclpy.serialization import deserialize_message   # heavy: rclpy, only to deserialize
    classes = {}
    for topic, tname, t, data in iter_raw(path, topics):
        cls = classes.get(tname)
        if cls is None:
            try:
                cls = classes[tname] = cdr.message_class(tname)
            except ValueError as exc:
                raise BagError(path, str(exc)) from None
        try:
            msg = deserialize_message(data, cls)
        except Exception as exc:
            raise BagError(path, f'message on {topic} at t = {t} ns does not deserialize as '
                           f'{tname}: {exc}') from None
        yield topic, t, msg
