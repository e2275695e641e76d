"""
Runs recorded to MCAP (ROS 2 profile) and read back.

Writing
-------
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

Reading
-------
:func:`read_messages` yields deserialized rclpy messages; :func:`iter_raw` yields raw CDR;
:func:`im_recording.run.load_run` turns a recording into a :class:`~im_recording.run.Run` (trace
arrays in the :mod:`im_common.metrics` format, the final energy books, the metadata). Any
unreadable, truncated or missing file raises :class:`BagError` naming the file and what is wrong.

Where it lives
--------------
This module is the public face of the recording's file parts; each has its own module:
:mod:`~im_recording.writer` (:class:`BagWriter`), :mod:`~im_recording.reader` (:func:`info`,
:func:`iter_raw`, :func:`read_messages`, :func:`check_data_crc`),
:mod:`~im_recording.mcap_records` (opcodes, record encoding, the one record parser ``recover``
uses too), :mod:`~im_recording.qos_yaml` (``offered_qos_profiles``),
:mod:`~im_recording.metadata` (the ``log_time`` and ``parameters/<node>`` records) and
:mod:`~im_recording.files` (:class:`BagError`, outputs that never overwrite an input, atomic
writes, the ``.part``).
"""
from __future__ import annotations

from .files import (BagError, check_output, check_writable, PART_SUFFIX, partial_path,
                    write_atomic)
from .mcap_records import MAGIC
from .metadata import (log_time_offset, log_time_offset_for, LOG_TIME_RECORD, log_time_record,
                       LOG_TIMES, parameters_metadata, wall_clock_offset)
from .qos_yaml import (DEFAULT_QOS, INFINITE, INFINITE_NS, offered_qos_yaml, parse_qos_yaml,
                       qos_profile_dict, qos_yaml)
from .reader import BagInfo, check_data_crc, info, iter_raw, read_messages
from .writer import (BagWriter, FLUSH_BYTES, FLUSH_WALL_S, LIBRARY, PROFILE,
                     ROSBAG2_METADATA_VERSION)

__all__ = ['BagError', 'BagInfo', 'BagWriter', 'check_data_crc', 'check_output',
           'check_writable', 'DEFAULT_QOS', 'FLUSH_BYTES', 'FLUSH_WALL_S', 'INFINITE',
           'INFINITE_NS', 'info', 'iter_raw', 'LIBRARY', 'log_time_offset', 'log_time_offset_for',
           'log_time_record', 'LOG_TIME_RECORD', 'LOG_TIMES', 'MAGIC', 'offered_qos_yaml',
           'parameters_metadata', 'parse_qos_yaml', 'PART_SUFFIX', 'partial_path', 'PROFILE',
           'qos_profile_dict', 'qos_yaml', 'read_messages', 'ROSBAG2_METADATA_VERSION',
           'wall_clock_offset', 'write_atomic']
