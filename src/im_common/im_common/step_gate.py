"""
The step gate: which inputs of a lock-step node make up step k, and when that step is complete.

ROS-free (plain Python, unit-tested without rclpy in ``tests/test_lockstep_parts.py``). A node
(:class:`im_common.lockstep.LockstepNode`) feeds every decoded input into its gate by topic and
stamp (:meth:`StepGate.put`); the gate hands back a step's inputs once every one of them has
arrived, the node computes that step and asks the gate for the next one (:meth:`StepGate.advance`).
Inputs are identified by their stamps, never by arrival order, so the same run gives the same
numbers whatever the scheduling (``docs/architecture.md``, *Gates*).

The gate also keeps the bookkeeping the watchdog and the end-of-run report need: the stamp it
waits for (``expected``), since when (``since``), the inputs still missing for it
(:meth:`StepGate.missing`), and, for a *follow* gate, the steps it jumped over (``gaps``,
``gap_ranges``).
"""
from __future__ import annotations

import math
import time
from typing import Dict, List, Mapping, Optional, Sequence

# NS_PER_S from its definition: conversions (its usual source) reaches this module through
# topics, so importing it here would close a circle (tests/test_architecture.py)
from .cdr import NS_PER_S

#: Bound of the lock-step protocol's windows: a lossless follower stays within half of it
#: (``follower_window``), a node keeps that many early or pending steps.
LOCKSTEP_DEPTH = 100


class StepGate:
    """
    Collects the inputs of step k by stamp; ``put`` returns them once all have arrived.

    ``follow=False`` (*exact*): steps are taken strictly in order; inputs stamped before the
    expected step (replays of transient-local history) are ignored, inputs for later steps wait in
    ``pending`` until their step comes.

    ``follow=True`` (*follow*): as above, but when a later step is complete while the expected one
    is not, the expected one can never complete — each publisher delivers its samples in order, so
    every sample of the earlier step that was ever going to arrive has arrived — and the gate
    jumps to the complete step. The steps jumped over are counted in ``gaps`` and their stamp
    ranges kept (the first ``MAX_GAP_RANGES``). ``pending`` is bounded to ``max_pending`` steps.

    ``lags`` = {topic: L}: that input's value stamped t_j belongs to step j + L (the command of a
    computational delay, :mod:`im_common.delay`: step k of the observer takes the command that
    acts over it, stamped t_k−L), and its first value (stamped ``first_ns``) also to the L steps
    before that — the delay line's first command acts from t_0.
    """

    MAX_GAP_RANGES = 100

    __slots__ = ('required', 'n', 'period', 'expected', 'pending', 'since', 'follow', 'gaps',
                 'gap_ranges', 'max_pending', 'first', 'lags')

    def __init__(self, required: Sequence[str], period_ns: int, first_ns: int = 0,
                 follow: bool = False, max_pending: int = 4 * LOCKSTEP_DEPTH,
                 lags: Optional[Mapping[str, int]] = None):
        self.required = tuple(required)
        self.n = len(self.required)
        self.period = int(period_ns)
        self.first = self.expected = int(first_ns)
        self.lags = {t: int(L) * self.period for t, L in (lags or {}).items() if L}
        unknown = [t for t in self.lags if t not in self.required]
        if unknown:
            raise ValueError(f'lagged inputs {unknown} are not required inputs of the gate')
        self.pending: Dict[int, dict] = {}
        self.since = time.monotonic()
        self.follow = follow
        self.gaps = 0
        self.gap_ranges: List[tuple] = []
        self.max_pending = max_pending

    def put(self, topic: str, ns: int, value) -> Optional[dict]:
        """
        Take ``topic``'s value stamped ``ns``; return a completed step's inputs, else None.

        The inputs (topic -> value) are the expected step's if this completes it (a follow gate:
        or a later step's, jumping to it).
        """
        if self.lags and topic in self.lags:
            return self._put_lagged(topic, ns, value)
        if ns < self.expected:
            return None
        pending = self.pending
        slot = pending.get(ns)
        if slot is None:
            slot = pending[ns] = {}
            if self.follow and len(pending) > self.max_pending:
                self._drop_oldest()
        slot[topic] = value
        if len(slot) == self.n:
            if ns == self.expected:
                del pending[ns]
                return slot
            if self.follow:
                self._skip_to(ns)
                del pending[ns]
                return slot
        return None

    def _put_lagged(self, topic: str, ns: int, value) -> Optional[dict]:
        """Put a lagged input into its step (and the first one into the steps before it too)."""
        lag = self.lags[topic]
        start = self.first if ns == self.first else ns + lag
        pending = self.pending
        for s in range(max(start, self.expected), ns + lag + 1, self.period):
            slot = pending.get(s)
            if slot is None:
                slot = pending[s] = {}
            slot[topic] = value
        if self.follow and len(pending) > self.max_pending:
            self._drop_oldest()
        return self._complete()

    def _complete(self) -> Optional[dict]:
        """Return the expected step's inputs if complete (a follow gate: the first complete)."""
        slot = self.pending.get(self.expected)
        if slot is not None and len(slot) == self.n:
            return self.pending.pop(self.expected)
        if self.follow:
            done = [t for t, s in self.pending.items() if len(s) == self.n]
            if done:
                ns = min(done)
                self._skip_to(ns)
                return self.pending.pop(ns)
        return None

    def skip_to(self, ns: int) -> Optional[dict]:
        """
        Give up every step before ``ns`` (counted as gaps) and wait for ``ns``.

        Returns its inputs if they are already complete. A follower whose node bridged those
        steps itself (the observer, :meth:`im_observer.observer_node.ObserverNode.on_incomplete`)
        calls it; the gate never moves backwards.
        """
        if ns > self.expected:
            self._skip_to(ns)
            self.since = time.monotonic()
        slot = self.pending.get(self.expected)
        if slot is not None and len(slot) == self.n:
            return self.pending.pop(self.expected)
        return None

    def _skip_to(self, ns: int) -> None:
        lost = (ns - self.expected) // self.period
        if lost > 0:
            self.gaps += lost
            if len(self.gap_ranges) < self.MAX_GAP_RANGES:
                self.gap_ranges.append((self.expected, ns - self.period))
        for old in [t for t in self.pending if t < ns]:
            del self.pending[old]
        self.expected = ns

    def _drop_oldest(self) -> None:
        oldest = min(self.pending)
        del self.pending[oldest]
        if oldest == self.expected:
            self._skip_to(min(self.pending) if self.pending else oldest + self.period)

    def advance(self) -> Optional[dict]:
        """Move to the next step; return its inputs if they are already complete."""
        self.expected += self.period
        self.since = time.monotonic()
        return self._complete()     # a follow gate: a later complete step may already be waiting

    def missing(self) -> list:
        """Return the required topics that have not brought the expected step yet."""
        have = self.pending.get(self.expected, {})
        return [t for t in self.required if t not in have]

    def step(self) -> int:
        """Return the number of the step the gate waits for."""
        return self.expected // self.period

    def gap_text(self, n: int = 5) -> str:
        """Return the first ``n`` stamp ranges jumped over, as ``a-b s`` items (end report)."""
        return ', '.join(f'{a / NS_PER_S:.4f}-{b / NS_PER_S:.4f} s'
                         for a, b in self.gap_ranges[:n])


def finite(value, _isfinite=math.isfinite) -> bool:
    """Every number in a decoded input (a tuple of floats or a dict of them) is finite."""
    return all(map(_isfinite, value.values() if isinstance(value, dict) else value))
