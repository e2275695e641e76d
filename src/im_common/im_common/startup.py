"""
An executable's start-up: its stop signals are taken from its first line, before the heavy imports.

Every executable of the stack (``setup.py``'s console scripts) starts through :func:`entry`: its
script imports a package's light ``entry`` module, which names the real ``main`` by its module
path; nothing heavy (rclpy, numpy, the middleware) is imported before the handlers are in place.

- *While the executable's modules are imported* (seconds on a loaded machine; ~30 s was seen at
  nice 19 beside a busy process) SIGINT, SIGTERM and SIGHUP only set a flag: once the imports are
  done the executable exits with one line (``record: SIGINT during start-up: exiting``) and the
  shell's code, 128 + the signal's number (130, 143, 129), before it starts anything.
- *From then on until its own handling takes over* (a node's or tool's
  :class:`~im_common.stopping.StopSignals`, which takes a signal at a step) a stop signal raises
  :class:`~im_common.stopping.Interrupted` where the program is; what the program does not catch
  itself ends it with one line and 128 + the number, no traceback.

Before, a signal during the imports was a KeyboardInterrupt traceback, or — in a process that
inherited SIGINT ignored (a shell script's background job) — lost: a recorder started by hand
took ~30 s to start, then waited ten minutes for a plant that had long finished. What is left:
Python's own start-up before the script's first line (the interpreter and its ``site`` import,
and the script's look-up of the entry point): there a SIGINT or SIGTERM ends the process by the
signal's default action (the shell's 130/143 too), or a SIGINT is a KeyboardInterrupt traceback.

Stdlib only: this module must import nothing heavy.
"""
from __future__ import annotations

import importlib
import os
import signal
import sys
from typing import Callable, Optional

from .stopping import exit_code_for, Interrupted, STOP_SIGNALS

#: The first stop signal that came while the executable's modules were imported (its name).
_pending: Optional[str] = None
#: The process that installed the handlers (a forked child gets the signal's default action).
_owner: Optional[int] = None
#: 'flag' while importing, 'raise' once the program runs.
_mode = 'flag'


def _handler(signum, _frame) -> None:
    global _pending
    if os.getpid() != _owner:           # a forked child (a worker): as if never installed
        signal.signal(signum, signal.SIG_DFL)
        os.kill(os.getpid(), signum)
        return
    name = signal.Signals(signum).name
    if _mode == 'flag':
        if _pending is None:
            _pending = name
        return
    raise Interrupted(name)


def install() -> None:
    """Take SIGINT, SIGTERM and SIGHUP as a flag from here on (see the module's docstring)."""
    global _owner, _mode, _pending
    _owner, _mode, _pending = os.getpid(), 'flag', None
    for s in STOP_SIGNALS:
        signal.signal(s, _handler)


def pending() -> Optional[str]:
    """Return the name of the stop signal that came during the imports, or None."""
    return _pending


def run(target: str, prog: Optional[str] = None) -> int:
    """
    Run ``'package.module:function'`` as the process's main, the stop signals taken first.

    Return its exit code (see the module's docstring for a signal's).
    """
    global _mode
    prog = prog or os.path.basename(sys.argv[0] or target)
    install()
    module, _, name = target.partition(':')
    try:
        main: Callable = getattr(importlib.import_module(module), name)
    except KeyboardInterrupt:           # a SIGINT before install() took effect
        return _said(prog, 'SIGINT', 'during start-up')
    if _pending is not None:
        return _said(prog, _pending, 'during start-up')
    _mode = 'raise'
    try:
        code = main()
    except KeyboardInterrupt as exc:
        return _said(prog, getattr(exc, 'signame', 'SIGINT'), '')
    finally:
        _ignore()
    return code


def _ignore() -> None:
    """
    Ignore the stop signals from here to the exit: the process ends anyway.

    The interpreter's finalization puts a Python handler back to the default action, and a
    second Ctrl-C then killed a process that had said it was exiting (exit code -2, not 130).
    """
    for s in STOP_SIGNALS:
        signal.signal(s, signal.SIG_IGN)


def _said(prog: str, signame: str, when: str) -> int:
    _ignore()
    text = f'{prog}: {signame} {when}: exiting' if when else f'{prog}: stopped by {signame}'
    print(text, file=sys.stderr, flush=True)
    return exit_code_for(signame)


def entry(target: str) -> Callable[[], int]:
    """Return a console script's function that runs ``target`` through :func:`run`."""
    def main() -> int:
        return run(target)
    main.__doc__ = f'Run {target} with its stop signals taken from the start (im_common.startup).'
    return main
