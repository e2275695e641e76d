"""
Stop signals, one way for every process of the stack: SIGINT, SIGTERM and SIGHUP.

A node or tool asks to be told, instead of being interrupted wherever it happens to be::

    with StopSignals() as stop:
        while not stop.requested:
            executor.spin_once(timeout_sec=0.05)
    return stop.exit_code        # 130 / 143 / 129 after a signal, else 0

Nodes start rclpy with ``signal_handler_options=SignalHandlerOptions.NO`` so that a signal does
not invalidate the context under a callback that is publishing (the cause of ``Failed to publish:
publisher's context is invalid`` on Ctrl-C); the loop sees the flag, the node says it is stopping,
and the context is shut down once, at the node's edge.

Tools whose work is a plain Python loop (replay, report, recover) can ask for ``raise_=True``:
the first signal raises :class:`Interrupted` (a :class:`KeyboardInterrupt`) at the next bytecode,
which their ``try/finally`` turns into a clean close.
"""
from __future__ import annotations

import signal
from typing import Optional

STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)


class Interrupted(KeyboardInterrupt):
    """Raised by :class:`StopSignals` with ``raise_=True``; carries the signal's name."""

    def __init__(self, signame: str):
        super().__init__(signame)
        self.signame = signame


def exit_code_for(signame: Optional[str]) -> int:
    """Shell convention: 128 + signal number (SIGINT 130, SIGTERM 143, SIGHUP 129); 0 if none."""
    if not signame:
        return 0
    return 128 + int(getattr(signal, signame))


class StopSignals:
    """
    Context manager: SIGINT/SIGTERM/SIGHUP set :attr:`requested` (the signal's name).

    The previous handlers are restored on exit. Outside the main thread (where Python cannot
    install handlers) it does nothing and :attr:`installed` is False.
    """

    def __init__(self, raise_: bool = False, signals=STOP_SIGNALS):
        self.raise_ = raise_
        self.signals = tuple(signals)
        self.requested: Optional[str] = None
        self.installed = False
        self._old = {}

    def _handler(self, signum, _frame):
        name = signal.Signals(signum).name
        first = self.requested is None
        if first:
            self.requested = name
        if self.raise_ and first:
            raise Interrupted(name)

    def request(self, name: str = 'SIGINT') -> None:
        """Ask for a stop from code (tests, a supervising thread)."""
        if self.requested is None:
            self.requested = name

    @property
    def exit_code(self) -> int:
        return exit_code_for(self.requested)

    def __enter__(self) -> 'StopSignals':
        try:
            for s in self.signals:
                self._old[s] = signal.signal(s, self._handler)
            self.installed = True
        except ValueError:          # not the main thread
            self._old.clear()
        return self

    def __exit__(self, *exc) -> None:
        for s, old in self._old.items():
            signal.signal(s, old)
        self._old.clear()
        self.installed = False
