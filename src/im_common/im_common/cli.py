r"""
Command-line helpers shared by every executable: one way to parse arguments, log, show progress.

- :func:`error`: the one line ``<prog>: error: <what was wrong>`` on stderr and the exit code,
  for every executable.
- :func:`parse_args` strips the ROS arguments (``--ros-args ... --``) that ``ros2 run`` / launch
  append, then parses with argparse. rclpy is always installed with the stack, so a broken rclpy
  is an ImportError, not a silent fallback.
- :func:`logger` / :func:`gated_logger`: progress and diagnostics on stderr, one line each,
  prefixed with the tool's name, flushed (stdout stays for results).
- :func:`progress`: the ``[k/n] label`` line long batch tools print before each item;
  :func:`status_line`: the in-place ``\r`` status of one long run.

ROS-free at import time (rclpy is imported inside :func:`strip_ros_args`).
"""
from __future__ import annotations

import argparse
import os
import sys
from typing import Callable, List, Optional, Sequence


def strip_ros_args(argv: Sequence[str], prog: str = 'prog') -> List[str]:
    """``argv`` (without the program name) with the ROS arguments removed."""
    from rclpy.utilities import remove_ros_args  # heavy: rclpy, only for ROS arguments
    return list(remove_ros_args(args=[prog] + list(argv))[1:])


def parse_args(parser: argparse.ArgumentParser, argv: Optional[Sequence[str]] = None
               ) -> argparse.Namespace:
    """Parse ``argv`` (default ``sys.argv[1:]``) after removing the ROS arguments."""
    raw = sys.argv[1:] if argv is None else list(argv)
    return parser.parse_args(strip_ros_args(raw, parser.prog))


def error(prog: str, problem, code: int = 2) -> int:
    """
    Print the error line every executable prints, ``<prog>: error: <problem>``; return ``code``.

    ``problem`` (a message or an exception) is kept on one line: a multi-line text is joined with
    "; ". The exit code is 2 for bad input (argparse's), 1 for a run that failed.
    """
    lines = [line.strip() for line in str(problem).splitlines() if line.strip()]
    print(f'{prog}: error: ' + '; '.join(lines), file=sys.stderr, flush=True)
    return code


def logger(prefix: Optional[str] = None, stream=None) -> Callable[[str], None]:
    """Return a function printing ``[prefix] msg`` (or ``msg``) as one flushed line on stderr."""
    head = f'[{prefix}] ' if prefix else ''

    def log(msg: str) -> None:
        print(head + msg, file=stream or sys.stderr, flush=True)

    return log


def gated_logger(prefix: Optional[str] = None, stream=None) -> Callable[[bool, str], None]:
    """
    Return a logger called as ``log(enabled, msg)``, like :func:`logger`.

    For functions with a ``progress`` flag.
    """
    log = logger(prefix, stream)

    def gated(enabled: bool, msg: str) -> None:
        if enabled:
            log(msg)

    return gated


def progress(k: int, n: int, label: str, log: Optional[Callable[[str], None]] = None) -> None:
    """Announce item k of n: ``[k/n] label``."""
    (log or logger())(f'[{k}/{n}] {label}')


def status_line(text: str, *, done: bool = False, stream=None) -> None:
    r"""
    Rewrite the one-line status of a long run in place on stderr (``\r``); ``done`` ends it.

    For loops that report how far they are (``status_line(f'{label}: {pct:5.1f} %')``) and their
    final line (``status_line(f'{label}: done in {s:.1f} s', done=True)``).
    """
    print('\r' + text, end='\n' if done else '', file=stream or sys.stderr, flush=True)


#: The highest DDS domain id the middleware can open (Fast DDS's port formula on Linux; ROS 2's
#: "The ROS_DOMAIN_ID" guide).
MAX_DOMAIN_ID = 232


def ros_domain_id(explicit: Optional[int] = None) -> int:
    """
    Return the ROS domain a tool runs on, as every ROS 2 tool chooses it.

    ``explicit`` (a ``--domain-id``) wins, else ``ROS_DOMAIN_ID`` from the environment, else 0.
    A value the middleware cannot open is one ValueError line naming where it came from.
    """
    if explicit is not None:
        where, text = f'--domain-id {explicit}', str(explicit)
    else:
        text = os.environ.get('ROS_DOMAIN_ID', '').strip()
        where = f'ROS_DOMAIN_ID={text!r}'
        if not text:
            return 0
    if not text.isdigit() or int(text) > MAX_DOMAIN_ID:
        raise ValueError(f'{where}: not a ROS domain (an integer 0-{MAX_DOMAIN_ID})')
    return int(text)
