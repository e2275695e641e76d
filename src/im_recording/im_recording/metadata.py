"""
The named Metadata records a recording states itself in: ``log_time`` and ``parameters/<node>``.

``log_time``: the offset of the file's log times from the messages' stamps (simulated time),
``clock``, ``offset_ns``, ``started_utc``; a reader subtracts it (:func:`log_time_offset`).
``parameters/<node>``: every parameter of a node of the run with its value.
"""
from __future__ import annotations

import datetime
import time
from typing import Dict, Mapping

from im_common.conversions import ns_to_s

from .files import BagError

#: the Metadata record that states a file's log-time offset: ``clock`` (``wall``),
#: ``offset_ns`` (log time − stamp, ns since the Unix epoch) and ``started_utc`` (ISO 8601)
LOG_TIME_RECORD = 'log_time'
#: the ``log_time`` choices: the stamp itself, or offset to the wall-clock start of the recording
LOG_TIMES = ('wall', 'simulated')


def parameters_metadata(values: Mapping[str, object]) -> Dict[str, str]:
    """
    Return a node's parameters as a ``parameters/<node>`` metadata record.

    Name -> ``repr`` of the value, arrays as lists (the same text whether the values come from
    the node itself or over its parameter services).
    """
    def norm(v):
        if isinstance(v, (list, tuple)) or type(v).__name__ == 'array' or hasattr(v, 'tolist'):
            return [norm(x) for x in (v.tolist() if hasattr(v, 'tolist') else v)]
        return v
    return {str(k): repr(norm(values[k])) for k in sorted(values)}


def wall_clock_offset() -> int:
    """Return the log-time offset of a recording that starts now: the wall clock [ns]."""
    return time.time_ns()


def log_time_offset_for(log_time: str) -> int:
    """Return the offset a new recording takes for ``log_time`` (:data:`LOG_TIMES`)."""
    if log_time == 'simulated':
        return 0
    if log_time == 'wall':
        return wall_clock_offset()
    raise ValueError(f'invalid log_time {log_time!r}: one of {", ".join(LOG_TIMES)}')


def log_time_record(offset_ns: int) -> Dict[str, str]:
    """Return the ``log_time`` Metadata record of a file whose log times are offset."""
    started = datetime.datetime.fromtimestamp(ns_to_s(offset_ns), tz=datetime.timezone.utc)
    return {'clock': 'wall', 'offset_ns': str(int(offset_ns)),
            'started_utc': started.isoformat(timespec='microseconds')}


def log_time_offset(metadata: Mapping[str, Mapping[str, str]], where='recording') -> int:
    """
    Return a file's log-time offset [ns] from its metadata records (0 without ``log_time``).

    Log time − offset is the simulated stamp; a malformed record is a BagError naming it.
    """
    rec = metadata.get(LOG_TIME_RECORD)
    if not rec:
        return 0
    try:
        off = int(rec.get('offset_ns', '0'))
    except ValueError:
        off = -1
    if off < 0:
        raise BagError(where, f'metadata record {LOG_TIME_RECORD!r}: offset_ns '
                              f'{rec.get("offset_ns")!r} is not an integer >= 0')
    return off
