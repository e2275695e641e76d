"""
Runs recorded to MCAP (ROS 2 profile) and read back.

Writing: :class:`BagWriter` (:mod:`~im_recording.writer`, whose docstring says what it writes:
the ``ros2`` profile rosbag2, Foxglove and ``rosbags`` open, log times, chunk flushing and what a
hard kill costs).

Reading
-------
:func:`read_messages` yields deserialized rclpy messages; :func:`iter_raw` yields raw CDR;
:func:`im_recording.recorded_run.load_run` turns a recording into a
:class:`~im_recording.recorded_run.RecordedRun` (trace arrays in the :mod:`im_common.metrics`
format, the final energy books, the metadata). Any unreadable, truncated or missing file raises
:class:`BagError` naming the file and what is wrong.

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
