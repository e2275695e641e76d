"""
The MCAP writer of recordings (ROS 2 profile).

:class:`BagWriter` writes an MCAP file that rosbag2's MCAP storage (``ros2 bag info/play``),
Foxglove, PlotJuggler and ``rosbags`` open:

* profile ``ros2``; one Schema per type, encoding ``ros2msg`` with the full dependency text
  (:mod:`im_recording.msgdefs`); one Channel per topic, message encoding ``cdr``, channel metadata
  ``offered_qos_profiles`` (rosbag2 metadata version 9 YAML) and ``topic_type_hash``
  (``RIHS01_...``);
* messages in chunks (zstd, lz4 or none), each followed by its Message Index records; a summary
  section with Schemas, Channels, Chunk Indexes, Metadata Indexes and Statistics, Summary Offsets,
  CRCs; a ``rosbag2`` Metadata record with ``serialized_metadata`` as ``ros2 bag record`` writes
  it;
* run metadata (scenario, parameters, versions, git revision) as named Metadata records.

Every message's log time and publish time is its stamp in simulated time (integer ns), plus the
writer's log-time offset: 0 (``log_time='simulated'``: log time = stamp) or, for a recording of a
run (``log_time='wall'``, the default of ``scenario --record``, ``launch record:=`` and the
recorder), the wall-clock time at which the recording started, so that viewers (Foxglove,
``ros2 bag info``) place the run at its date. The offset is written in the ``log_time`` Metadata
record (:data:`LOG_TIME_RECORD`); the headers' stamps stay simulated time either way, and every
reader here (:func:`iter_raw`, :func:`read_messages`, replay, recover, reports) gives stamps in
simulated time whichever the file holds (:func:`log_time_offset`). A recorder
sets a reorder window (:meth:`BagWriter.set_reorder_window`): each chunk is then written sorted by
stamp, so log times never decrease in file order; a message later than the window keeps its stamp
as publish time and is logged at the file's latest log time.
Schemas, Channels and Metadata are written to the file as soon as they are declared, and a chunk
is closed and flushed to the OS (and ``fsync``-ed) as soon as it holds
:data:`FLUSH_BYTES` (4 MiB uncompressed) or has been open for :data:`FLUSH_WALL_S` (1 s of wall
time), whichever comes first: checked on every write and by :meth:`BagWriter.flush_due`, which a
recorder calls from a timer so that a quiet run is flushed too. A hard kill (SIGKILL, power
loss) therefore costs at most the last second or 4 MiB, and ``recover`` salvages the rest.

The per-message path is a dict lookup, one ``struct.pack`` and two ``bytearray`` appends;
messages are encoded with :mod:`im_common.cdr` (exact-length CDR). Cost: see
``benchmarks/bench_bag.py`` and ``docs/recording.md``.
"""
from __future__ import annotations

import atexit
import contextlib
import os
from pathlib import Path
import signal
import struct
from time import monotonic as _monotonic
from typing import Callable, Dict, List, Mapping, Optional, Tuple
import weakref
import zlib

from im_common import cdr
from im_common.conversions import NS_PER_S
from im_common.topics import TOPIC_TYPES
import lz4.frame
import yaml
import zstandard

from .files import BagError, partial_path
from .mcap_records import (blob, MAGIC, MSG_FIXED, MSG_HDR, OP_CHANNEL, OP_CHUNK,
                           OP_CHUNK_INDEX, OP_DATA_END, OP_FOOTER, OP_HEADER, OP_MESSAGE,
                           OP_MESSAGE_INDEX, OP_METADATA, OP_METADATA_INDEX, OP_SCHEMA,
                           OP_STATISTICS, OP_SUMMARY_OFFSET, QQ, REC, record, string,
                           string_map, U16, U32, U64)
from .metadata import LOG_TIME_RECORD, log_time_record
from .msgdefs import full_definition, ros_distro, type_hash
from .qos_yaml import DEFAULT_QOS, parse_qos_yaml

PROFILE = 'ros2'
LIBRARY = 'im_recording.bag 0.1 (MCAP writer for the IM drive stack)'
ROSBAG2_METADATA_VERSION = 9

#: A chunk is closed and flushed when it holds this many uncompressed bytes ...
FLUSH_BYTES = 4 << 20
#: ... or has been open this long [s of wall time], whichever comes first.
FLUSH_WALL_S = 1.0


@contextlib.contextmanager
def _signals_held():
    """Hold SIGINT and SIGTERM back (delivered on exit) where the platform allows it."""
    try:
        old = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT, signal.SIGTERM})
    except (AttributeError, OSError, ValueError):
        yield
        return
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, old)


def _compressor(name: str):
    if name in ('', 'none', None):
        return '', None
    if name == 'zstd':
        c = zstandard.ZstdCompressor(level=3)
        return 'zstd', c.compress
    if name == 'lz4':
        return 'lz4', lz4.frame.compress
    raise ValueError(f"compression must be 'zstd', 'lz4' or 'none', not {name!r}")


def _complete_messages(buf, ix: list):
    """
    Return the index entries of the complete messages of ``buf`` and where the last one ends.

    A signal handler may have interrupted write() between its two appends: the last message may
    be incomplete, and is then left out.
    """
    n = len(ix)
    last_off = ix[-1][2]
    (length,) = U64.unpack_from(buf,
                                last_off + 1) if len(buf) >= last_off + 9 else (None,)
    if length is None or last_off + 9 + length > len(buf):
        n -= 1
        end = last_off
    else:
        end = last_off + 9 + length
    if n < len(ix):
        ix = ix[:n]
    return ix, end


def _topic_type_default(topic: str) -> Optional[str]:
    return TOPIC_TYPES.get(topic)


class _Output:
    """
    The writer's file.

    An OS error on a write or flush (disk full, I/O error, a file system gone read-only)
    becomes one :class:`BagError` naming the ``.part`` and the cause, and the writer stops
    there — what reached the file stays for ``recover``.
    """

    def __init__(self, f, failed):
        self._f = f
        self._failed = failed

    def write(self, data) -> None:
        try:
            self._f.write(data)
        except OSError as exc:
            self._failed(exc)

    def flush(self) -> None:
        try:
            self._f.flush()
        except OSError as exc:
            self._failed(exc)

    def fileno(self) -> int:
        return self._f.fileno()

    def sync(self) -> None:
        """``fsync``: what was flushed survives a power loss (an error stops the writer)."""
        try:
            os.fsync(self._f.fileno())
        except OSError as exc:
            self._failed(exc)

    def close(self) -> None:
        try:
            self._f.close()
        except OSError:         # its buffer could not be written either: already reported
            pass


class BagWriter:
    """
    MCAP writer for ROS 2 runs (context manager).

    Parameters
    ----------
    path : str or Path
        Output file; parent directories are created.
    force : bool
        Overwrite an existing file (otherwise :class:`FileExistsError` naming the path).
    metadata : dict of name -> dict of str
        Metadata records written at once (e.g. ``{'scenario': {...}}``).
    compression : 'zstd', 'lz4' or 'none'
        Chunk compression.
    chunk_size : int
        Uncompressed chunk size [bytes] at which a chunk is closed and flushed
        (:data:`FLUSH_BYTES`).
    flush_wall_s : float
        Wall time [s] after its first message at which a chunk is closed, flushed and
        ``fsync``-ed (:data:`FLUSH_WALL_S`; None: by size only, for files written offline).
    close_at_exit : bool
        Also close from an ``atexit`` hook (the interpreter exiting without ``close``).
    part : str or Path, optional
        Where the file is written until ``close`` renames it to ``path`` (default
        ``<path>.part``); ``recover`` passes its own so it never writes over its input.
    log_time_offset_ns : int
        Added to every stamp to give the message's log and publish time (0: log time = stamp);
        a non-zero offset is stated in the ``log_time`` Metadata record. See
        :func:`wall_clock_offset`.

    Attributes
    ----------
    offered_qos : callable topic -> ``offered_qos_profiles`` YAML, or None
        Where a topic declared without ``qos`` (by :meth:`add_topic`, on its first message, or
        by :meth:`declare_expected`) takes its profiles from; a recorder sets it to the
        publishers the ROS graph lists. None: :data:`DEFAULT_QOS`.

    """

    def __init__(self, path, force: bool = False,
                 metadata: Optional[Dict[str, Dict[str, str]]] = None,
                 compression: str = 'zstd', chunk_size: int = FLUSH_BYTES,
                 close_at_exit: bool = True, part=None,
                 flush_wall_s: Optional[float] = FLUSH_WALL_S, log_time_offset_ns: int = 0):
        self.path = Path(path)
        if int(log_time_offset_ns) < 0:
            raise ValueError(f'log_time_offset_ns must be >= 0, not {log_time_offset_ns!r}')
        self.log_time_offset_ns = self._off = int(log_time_offset_ns)
        self._compression, self._compress = _compressor(compression)
        if int(chunk_size) < 1024:
            raise ValueError(f'chunk_size must be >= 1024 bytes, not {chunk_size!r}')
        self._chunk_size = int(chunk_size)
        if flush_wall_s is not None and not float(flush_wall_s) > 0:
            raise ValueError(f'flush_wall_s must be > 0 s or None, not {flush_wall_s!r}')
        self._flush_wall = None if flush_wall_s is None else float(flush_wall_s)
        self._chunk_due = float('inf')      # monotonic time at which the open chunk is flushed
        self.flushes = {'size': 0, 'time': 0}   # chunks closed by each rule (measured)
        self._closed = True
        self.part = partial_path(self.path) if part is None else Path(part)
        if self.path.is_dir():
            raise IsADirectoryError(f'{self.path}: is a directory, not an MCAP file path')
        if self.path.exists() and not force:
            raise FileExistsError(f'{self.path}: refusing to overwrite an existing recording '
                                  '(pass force=True / --force)')
        if self.part.exists() and not force:
            raise FileExistsError(f'{self.part}: an interrupted recording is in the way; salvage '
                                  f'it with `ros2 run im_recording recover {self.part} -o '
                                  f'{self.path}` or pass '
                                  'force=True / --force to discard it')
        self.failed: Optional[BagError] = None     # the write error that stopped this writer
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            # written under <name>.part and renamed into place by close(): an interrupted or
            # killed write never leaves a half-written file under the final name
            f = open(self.part, 'wb')
        except OSError as exc:
            raise BagError(self.part, f'cannot create the recording ({exc.strerror or exc})') \
                from None
        self._f = _Output(f, self._write_failed)
        self._crc = 0
        self._pos = 0
        self._schemas: Dict[str, int] = {}          # type -> schema id
        self._schema_recs: List[bytes] = []
        self._channel_recs: List[bytes] = []
        self._topics: Dict[str, Tuple[int, str]] = {}   # topic -> (channel id, type)
        self._chan: Dict[str, tuple] = {}           # hot path: topic -> (cid, cls, encoder)
        self._qos: Dict[str, list] = {}
        self.offered_qos = None
        self._expected: Dict[str, str] = {}         # topic -> type, declared on first use
        self._chunk_indexes: List[bytes] = []
        self._metadata_index: List[bytes] = []
        self._counts: Dict[int, int] = {}
        self._t_min: Optional[int] = None
        self._t_max: Optional[int] = None
        self._buf = bytearray()
        self._ix: list = []
        self._flushing = False
        self._close_pending = False
        self._closed = False
        self._write(MAGIC)
        self._write(record(OP_HEADER, string(PROFILE) + string(LIBRARY)))
        if self._off:
            self.add_metadata(LOG_TIME_RECORD, log_time_record(self._off))
        for name, data in (metadata or {}).items():
            if name != LOG_TIME_RECORD:         # a copied file's own: this writer states its own
                self.add_metadata(name, data)
        self._f.flush()
        if close_at_exit:
            ref = weakref.ref(self)
            self._atexit = lambda: (ref() is not None) and ref().close()
            atexit.register(self._atexit)
        else:
            self._atexit = None

    # -- context manager ------------------------------------------------------------------
    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False

    def __del__(self):
        try:
            self.close()
        except Exception:
            pass

    @property
    def closed(self) -> bool:
        return self._closed

    def discard(self) -> None:
        """
        Abandon a file nothing was written to yet (its ``.part``).

        An existing ``path`` is left as it was.
        """
        if not self._closed:
            self._closed = True
            self._f.close()
            os.remove(self.part)

    # -- low level ------------------------------------------------------------------------
    def _write_failed(self, exc: OSError) -> None:
        """
        Return the file cannot be written.

        Stop here (no later write or close touches it), keep the ``.part`` for ``recover``,
        raise one :class:`BagError` (also kept in :attr:`failed`).
        """
        self.failed = BagError(self.part, f'cannot write the recording '
                                          f'({exc.strerror or exc}); what was written is kept: '
                                          f'`ros2 run im_recording recover {self.part} -o '
                                          f'{self.path}`')
        self._closed = True
        self._chan = {}
        self._f.close()
        if getattr(self, '_atexit', None) is not None:
            atexit.unregister(self._atexit)
            self._atexit = None
        raise self.failed

    def _write(self, data: bytes) -> None:
        self._f.write(data)
        self._crc = zlib.crc32(data, self._crc)
        self._pos += len(data)

    # -- declarations ---------------------------------------------------------------------
    def add_topic(self, topic: str, type_name: str, qos: Optional[str] = None) -> int:
        """
        Declare a topic (idempotent for the same type); returns its channel id.

        ``qos`` is the ``offered_qos_profiles`` YAML list, one profile per publisher
        (:func:`offered_qos_yaml`; default: one reliable, volatile, keep_last 10 profile); a
        string that is not such a list is a ValueError naming the topic.
        """
        if self._closed:
            raise BagError(self.path, f'cannot add topic {topic!r}: the bag is closed')
        if not topic.startswith('/'):
            raise ValueError(f'topic names must be absolute (start with /): {topic!r}')
        if topic in self._topics:
            cid, t = self._topics[topic]
            if t != type_name:
                raise ValueError(f'topic {topic!r} is already recorded as {t}, not {type_name}')
            return cid
        cls = cdr.message_class(type_name)      # fails early on unknown types
        if qos is None:
            qos = self.offered_qos(topic) if self.offered_qos is not None else DEFAULT_QOS
        q = qos
        profiles = parse_qos_yaml(q, topic)
        sid = self._schemas.get(type_name)
        if sid is None:
            sid = len(self._schemas) + 1
            rec = record(OP_SCHEMA, U16.pack(sid) + string(type_name) + string('ros2msg')
                         + blob(full_definition(type_name).encode('utf-8')))
            self._schemas[type_name] = sid
            self._schema_recs.append(rec)
            self._write(rec)
        cid = len(self._topics) + 1
        meta = {'offered_qos_profiles': q, 'topic_type_hash': type_hash(type_name)}
        rec = record(OP_CHANNEL, U16.pack(cid) + U16.pack(sid) + string(topic) + string('cdr')
                     + string_map(meta))
        self._channel_recs.append(rec)
        self._write(rec)
        self._f.flush()
        self._topics[topic] = (cid, type_name)
        self._qos[topic] = profiles
        self._counts[cid] = 0
        self._chan[topic] = (cid, cls, cdr.encoder_for(cls))
        return cid

    def expect_topic(self, topic: str, type_name: str) -> None:
        """
        Return a topic to declare on its first message.

        Its publishers are known by then; or declared by :meth:`declare_expected`.
        """
        cdr.message_class(type_name)            # fails early on unknown types
        self._expected[topic] = type_name

    def declare_expected(self) -> None:
        """Declare every expected topic that had no message (a channel with a count of 0)."""
        for topic, type_name in self._expected.items():
            if topic not in self._topics:
                self.add_topic(topic, type_name)

    def _lookup_slow(self, topic: str):
        if self._closed:
            raise BagError(self.path, f'write to {topic!r} after the bag was closed')
        if topic not in self._topics:
            t = self._expected.get(topic) or _topic_type_default(topic)
            if t is None:
                raise KeyError(f'topic {topic!r} is not declared and not in im_common.topics; '
                               'call add_topic(topic, type_name) first')
            self.add_topic(topic, t)
        return self._chan[topic]

    def add_metadata(self, name: str, data: Mapping[str, str]) -> None:
        """Return a named Metadata record (string -> string), written to the file at once."""
        if self._closed:
            raise BagError(self.path, f'cannot add metadata {name!r}: the bag is closed')
        rec = record(OP_METADATA,
                     string(name) + string_map({str(k): str(v) for k, v in data.items()}))
        off = self._pos
        self._write(rec)
        self._f.flush()
        self._metadata_index.append(
            record(OP_METADATA_INDEX, QQ.pack(off, len(rec)) + string(name)))

    # -- the hot path ---------------------------------------------------------------------
    def write(self, topic: str, msg, stamp_ns: int) -> None:
        """Record an rclpy message at log/publish time ``stamp_ns`` (simulated time, ns)."""
        try:
            cid, cls, enc = self._chan[topic]
        except KeyError:
            cid, cls, enc = self._lookup_slow(topic)
        if msg.__class__ is not cls:
            raise TypeError(f'{topic}: expected {cls.__module__}.{cls.__name__}, got '
                            f'{type(msg).__module__}.{type(msg).__name__}')
        self.write_serialized(topic, enc(msg), stamp_ns)

    def write_serialized(self, topic: str, data: bytes, stamp_ns: int,
                         publish_ns: Optional[int] = None) -> None:
        """
        Record an already serialized (CDR) message stamped ``stamp_ns`` (simulated time).

        Its log time is ``stamp_ns`` plus the writer's log-time offset. ``publish_ns``: its
        publish stamp when it differs (default ``stamp_ns``), offset alike.
        """
        try:
            cid = self._chan[topic][0]
        except KeyError:
            cid = self._lookup_slow(topic)[0]
        buf = self._buf
        off = len(buf)
        t = stamp_ns + self._off
        buf += MSG_HDR.pack(OP_MESSAGE, MSG_FIXED + len(data), cid, 0, t,
                            t if publish_ns is None else publish_ns + self._off)
        buf += data
        ix = self._ix
        ix.append((cid, t, off))
        if len(buf) >= self._chunk_size:     # at most chunk_size + one message
            self.flushes['size'] += 1
            self._flush_chunk()
        elif self._flush_wall is not None:
            now = _monotonic()
            if not off:
                self._chunk_due = now + self._flush_wall
            elif now >= self._chunk_due:
                self.flushes['time'] += 1
                self._flush_chunk(sync=True)

    def flush_due(self) -> bool:
        """
        Close, flush and ``fsync`` the open chunk if it has been open for ``flush_wall_s``.

        For a timer of the recorder: a run that went quiet (stalled, or between its last
        message and the end) is on disk within a second too. Returns whether it flushed.
        """
        if self._closed or not self._ix or _monotonic() < self._chunk_due:
            return False
        self.flushes['time'] += 1
        self._flush_chunk(sync=True)
        return True

    def write_vector3(self, topic: str, stamp_ns: int, x: float, y: float, z: float = 0.0) -> None:
        """
        Write a Vector3Stamped without a message object (fast path).

        Fast path: a ``Vector3Stamped`` (frame_id '') stamped ``stamp_ns`` without a message
        object. The topic must be (or default to) a Vector3Stamped topic.
        """
        s, ns = divmod(stamp_ns, NS_PER_S)
        self.write_serialized(topic, cdr.pack_vector3_stamped(s, ns, x, y, z), stamp_ns)

    def write_joint_state(self, topic: str, stamp_ns: int, names, position=(), velocity=(),
                          effort=()) -> None:
        """Fast path: a ``JointState`` stamped ``stamp_ns`` without a message object."""
        s, ns = divmod(stamp_ns, NS_PER_S)
        self.write_serialized(topic, cdr.pack_joint_state(s, ns, names, position, velocity,
                                                          effort), stamp_ns)

    # -- chunks ---------------------------------------------------------------------------
    def set_reorder_window(self, window_ns: Optional[int],
                           progress: Optional[Callable[[], int]] = None) -> None:
        """
        Write each chunk in log-time order, holding back the messages within ``window_ns``.

        Messages may arrive out of stamp order (a recorder of separate processes; in one process
        the observer's x̂_{k+1} before step k+1). A chunk is written sorted by stamp up to
        ``window_ns`` before the newest stamp it holds; the newer messages stay for the next
        chunk (all are written at :meth:`close` and :meth:`flush`). A message that still arrives
        later than that window is written at the latest log time already written, its own stamp
        kept as publish time (and in its header), and counted in :attr:`late_messages`: log
        times never decrease in file order (``mcap doctor --strict-message-order``). None:
        written as they come. ``progress``: returns the stamp the recording has reached; the
        window then trails it instead of the newest stamp held (a message stamped ahead of it,
        e.g. another graph's, waits in the open chunk until the run reaches its stamp).
        """
        if window_ns is not None and int(window_ns) < 0:
            raise ValueError(f'reorder window must be >= 0 ns, not {window_ns!r}')
        self._reorder_ns = None if window_ns is None else int(window_ns)
        self._progress = progress

    _reorder_ns: Optional[int] = None
    _progress: Optional[Callable[[], int]] = None
    _written_max = 0            # the latest log time written (the file's order so far)
    late_messages = 0           # messages that arrived later than the reorder window

    def _in_order(self, buf: bytearray, end: int, ix: list, final: bool):
        """
        Return the chunk in log-time order, keeping the newest back; changes nothing.

        ``buf[:end]`` holds the messages ``ix`` indexes. The messages within the reorder window
        of the newest stamp go back into the open chunk (unless ``final``); a message older than
        what the file already holds is written at that time (its publish time keeps its stamp).
        Returns ``(records, index, kept records, kept index, latest time written, late count)``,
        or None when every message is within the window (the chunk stays open whole).
        """
        ends = [e[2] for e in ix[1:]] + [end]
        order = sorted(range(len(ix)), key=lambda i: ix[i][1])
        cut = len(order)
        if not final:
            newest = ix[order[-1]][1] if self._progress is None else self._progress() + self._off
            horizon = newest - self._reorder_ns
            cut = next((n for n, i in enumerate(order) if ix[i][1] > horizon), len(order))
            if cut == 0 and end < 2 * self._chunk_size:
                return None
            if cut == 0:
                cut = len(order)
        out, out_ix = bytearray(), []
        floor = self._written_max
        late = 0
        for i in order[:cut]:
            cid, t, off = ix[i]
            at = len(out)
            out += buf[off:ends[i]]
            if t < floor:               # later than the window: at the file's latest time
                U64.pack_into(out, at + 15, floor)
                late += 1
                t = floor
            floor = t
            out_ix.append((cid, t, at))
        keep, keep_ix = bytearray(), []
        for i in order[cut:]:
            cid, t, off = ix[i]
            keep_ix.append((cid, t, len(keep)))
            keep += buf[off:ends[i]]
        return bytes(out), out_ix, keep, keep_ix, floor, late

    def _flush_chunk(self, sync: bool = False, final: bool = False) -> None:
        """
        Write the open chunk (or, reordering, its part older than the window) to the file.

        Nothing of the writer's state changes until the chunk is in the file: a stop signal's
        exception (KeyboardInterrupt, a handler's SystemExit or ``Interrupted``) raised anywhere
        before that leaves every message in the open chunk, for the closing flush to write.
        Holding SIGINT/SIGTERM with ``pthread_sigmask`` alone does not do it: a signal sent to
        the process goes to any thread that does not block it (numpy's, rclpy's), and the main
        thread runs the Python handler at once; it only narrows the commit below further.
        """
        if self._closed:
            return
        self._chunk_due = float('inf')
        ix = self._ix
        if not ix:
            self._buf = bytearray()
            return
        self._flushing = True
        try:
            buf = self._buf
            ix, end = _complete_messages(buf, ix)
            keep, keep_ix = bytearray(), []
            written_max, late = self._written_max, 0
            if not ix:
                records = None
            elif self._reorder_ns is not None:
                ordered = self._in_order(buf, end, ix, final)
                if ordered is None:     # everything is within the window: keep it all open
                    if self._flush_wall is not None:
                        self._chunk_due = _monotonic() + self._flush_wall
                    return
                records, ix, keep, keep_ix, written_max, late = ordered
            else:
                with memoryview(buf) as view:
                    records = bytes(view[:end])
            if not ix:                  # only an incomplete message: dropped
                self._buf, self._ix = keep, keep_ix
                return
            out, chunk_index, per_chan, t0, t1 = self._chunk_bytes(records, ix)
            # The commit: the write, then the state that says it happened.
            with _signals_held():
                self._write(out)
                self._buf, self._ix = keep, keep_ix
                self._written_max = written_max
                self.late_messages += late
                for cid in per_chan:
                    self._counts[cid] = self._counts.get(cid, 0) + len(per_chan[cid])
                self._chunk_indexes.append(chunk_index)
                self._t_min = t0 if self._t_min is None else min(self._t_min, t0)
                self._t_max = t1 if self._t_max is None else max(self._t_max, t1)
            if keep_ix and self._flush_wall is not None:
                self._chunk_due = _monotonic() + self._flush_wall
            self._f.flush()
            if sync:                # at most once per flush_wall_s: power loss costs that too
                self._f.sync()
        finally:
            self._flushing = False
        if self._close_pending:
            self.close()

    def _chunk_bytes(self, records: bytes, ix: list):
        """
        Return the chunk of ``records`` and its message indexes as one write, and its index.

        Also the entries per channel and the chunk's first and last log time; nothing of the
        writer's state changes.
        """
        t0 = min(e[1] for e in ix)
        t1 = max(e[1] for e in ix)
        per_chan: Dict[int, list] = {}
        for cid, t, off in ix:
            per_chan.setdefault(cid, []).append((t, off))
        crc = zlib.crc32(records)
        data = self._compress(records) if self._compress else records
        body = (struct.pack('<QQQI', t0, t1, len(records), crc) + string(self._compression)
                + U64.pack(len(data)))
        # The chunk and its message indexes go to the file in one write.
        chunk_start = self._pos
        head = REC.pack(OP_CHUNK, len(body) + len(data)) + body
        chunk_len = len(head) + len(data)
        offsets = {}
        ix_recs = []
        pos = chunk_start + chunk_len
        for cid in sorted(per_chan):
            entries = per_chan[cid]
            entries.sort()
            arr = b''.join(QQ.pack(t, o) for t, o in entries)
            offsets[cid] = pos
            rec = record(OP_MESSAGE_INDEX, U16.pack(cid) + blob(arr))
            ix_recs.append(rec)
            pos += len(rec)
        ix_len = pos - chunk_start - chunk_len
        omap = b''.join(U16.pack(c) + U64.pack(o) for c, o in sorted(offsets.items()))
        chunk_index = record(
            OP_CHUNK_INDEX,
            struct.pack('<QQQQ', t0, t1, chunk_start, chunk_len) + blob(omap)
            + U64.pack(ix_len) + string(self._compression) + QQ.pack(len(data), len(records)))
        return b''.join([head, data] + ix_recs), chunk_index, per_chan, t0, t1

    def flush(self) -> None:
        """Close the open chunk and push it to the OS (the file stays open)."""
        if not self._closed:
            self._flush_chunk(final=True)
            self._f.flush()

    # -- closing --------------------------------------------------------------------------
    @property
    def message_count(self) -> int:
        return sum(self._counts.values()) + len(self._ix)

    def _rosbag2_metadata(self) -> str:
        """
        Return rosbag2's ``BagMetadata`` record (version 9).

        rosbag2's ``BagMetadata`` (version 9) as ``YAML::convert<BagMetadata>::encode`` lays it
        out: the *bare* mapping (``version`` at the top; the ``rosbag2_bagfile_information:``
        wrapper belongs to ``metadata.yaml`` files, not to this record) and each topic's
        ``offered_qos_profiles`` as a YAML list. rosbag2's ``read_metadata()`` decodes it without
        catching, so a wrong layout aborts ``ros2 bag info``/``play``
        (``tests/test_rosbag2_compat.py`` applies its rules).
        """
        start = self._t_min or 0
        dur = (self._t_max - self._t_min) if self._t_min is not None else 0
        topics = []
        for topic, (cid, t) in self._topics.items():
            topics.append({'topic_metadata': {
                'name': topic, 'type': t, 'serialization_format': 'cdr',
                'offered_qos_profiles': self._qos[topic], 'type_description_hash': type_hash(t)},
                'message_count': self._counts.get(cid, 0)})
        total = sum(self._counts.values())
        md = {
            'version': ROSBAG2_METADATA_VERSION, 'storage_identifier': 'mcap',
            'duration': {'nanoseconds': dur},
            'starting_time': {'nanoseconds_since_epoch': start},
            'message_count': total, 'topics_with_message_count': topics,
            'compression_format': '', 'compression_mode': '',
            'relative_file_paths': [self.path.name],
            'files': [{'path': self.path.name, 'starting_time': {'nanoseconds_since_epoch': start},
                       'duration': {'nanoseconds': dur}, 'message_count': total}],
            'custom_data': {}, 'ros_distro': ros_distro(),
        }
        return yaml.safe_dump(md, sort_keys=False, default_flow_style=False)

    def close(self) -> None:
        """
        Finish the file: last chunk, summary, footer.

        Idempotent; safe to call from a signal handler that interrupted :meth:`write` (an
        incomplete last message is dropped) or from ``atexit``.
        """
        if self._closed:
            return
        if self._flushing:          # re-entered from a signal handler during a chunk flush
            self._close_pending = True
            return
        self._chan = {}             # later writes take the slow path and raise BagError
        try:
            self._flush_chunk(final=True)
            if self._closed:        # the flush's pending close already finished the file
                return
            self._closed = True
            # rosbag2's own metadata record (ros2 bag info / play read it)
            rb = self._rosbag2_metadata()
            rec = record(OP_METADATA, string('rosbag2') + string_map({'serialized_metadata': rb}))
            off = self._pos
            self._write(rec)
            self._metadata_index.append(
                record(OP_METADATA_INDEX, QQ.pack(off, len(rec)) + string('rosbag2')))
            self._write(record(OP_DATA_END, U32.pack(self._crc)))
            # summary section
            summary_start = self._pos
            scrc = 0
            groups = []

            def put(op, recs):
                nonlocal scrc
                if not recs:
                    return
                start = self._pos
                for r in recs:
                    self._write(r)
                    scrc = zlib.crc32(r, scrc)
                groups.append((op, start, self._pos - start))
            put(OP_SCHEMA, self._schema_recs)
            put(OP_CHANNEL, self._channel_recs)
            counts = b''.join(U16.pack(c) + U64.pack(n) for c, n in sorted(self._counts.items()))
            stats = record(OP_STATISTICS, struct.pack(
                '<QHIIIIQQ', sum(self._counts.values()), len(self._schemas), len(self._topics), 0,
                len(self._metadata_index), len(self._chunk_indexes), self._t_min or 0,
                self._t_max or 0) + blob(counts))
            put(OP_STATISTICS, [stats])
            put(OP_CHUNK_INDEX, self._chunk_indexes)
            put(OP_METADATA_INDEX, self._metadata_index)
            summary_offset_start = self._pos
            for op, start, length in groups:
                r = record(OP_SUMMARY_OFFSET, struct.pack('<BQQ', op, start, length))
                self._write(r)
                scrc = zlib.crc32(r, scrc)
            head = REC.pack(OP_FOOTER, 20) + QQ.pack(summary_start, summary_offset_start)
            scrc = zlib.crc32(head, scrc)
            self._write(head + U32.pack(scrc))
            self._write(MAGIC)
            self._f.flush()
            try:
                os.fsync(self._f.fileno())
            except OSError:
                pass
            self._f.close()
            os.replace(self.part, self.path)
        finally:
            self._closed = True
            self._f.close()
            if self._atexit is not None:
                atexit.unregister(self._atexit)
                self._atexit = None
