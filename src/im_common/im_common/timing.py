"""
Timing of the fixed-rate (``free_run``) loop: latency histogram, pre-flight probe, watchdog.

The plant adds one sample per step (measurement k published → command k received, wall clock);
the histogram is reported at the end of the run (log, ``/im/status`` values, the report). Fixed
edges keep memory constant however long the run, and make runs comparable.

Before step 0 the plant probes the loop (:func:`assess_probe`: refuse a rate this machine cannot
hold, naming the rate it can), and during the run a :class:`DeadlineWatchdog` stops a loop whose
commands miss their deadlines (``docs/guarantees.md``, "Fixed-rate real time").
"""
from __future__ import annotations

import bisect
from dataclasses import dataclass
import math
from typing import Dict, List, Optional, Sequence

#: Bin edges [µs]: a sample x falls in bin i when EDGES_US[i-1] <= x < EDGES_US[i]; the last bin
#: is open (>= 20 ms).
EDGES_US = (50, 100, 150, 200, 300, 400, 500, 700, 1000, 1500, 2000, 3000, 5000, 10000, 20000)


class LatencyHistogram:
    """Counts of latencies [s] in the bins of :data:`EDGES_US`, with count, sum and max."""

    __slots__ = ('counts', 'n', 'total', 'max')

    def __init__(self):
        self.counts: List[int] = [0] * (len(EDGES_US) + 1)
        self.n = 0
        self.total = 0.0
        self.max = 0.0

    def add(self, seconds: float) -> None:
        us = seconds * 1e6
        self.counts[bisect.bisect_right(EDGES_US, us)] += 1
        self.n += 1
        self.total += seconds
        if seconds > self.max:
            self.max = seconds

    def quantile(self, q: float) -> float:
        """
        Return the upper edge [s] of the bin holding the q-quantile.

        inf for the open bin, nan if empty.
        """
        if self.n == 0:
            return float('nan')
        need = q * self.n
        run = 0
        for i, c in enumerate(self.counts):
            run += c
            if run >= need and c:
                return EDGES_US[i] * 1e-6 if i < len(EDGES_US) else float('inf')
        return float('inf')

    @property
    def mean(self) -> float:
        return self.total / self.n if self.n else float('nan')

    def describe(self) -> str:
        if not self.n:
            return 'no samples'
        return (f'mean {self.mean * 1e6:.0f} µs, p50 ≤ {self.quantile(0.5) * 1e6:.0f} µs, '
                f'p99 ≤ {self.quantile(0.99) * 1e6:.0f} µs, max {self.max * 1e6:.0f} µs '
                f'({self.n} samples)')

    def as_values(self) -> Dict[str, str]:
        """
        Flat key/values for a status message.

        ``latency_bins_us`` (edges) and ``latency_counts`` as space-separated numbers, plus
        mean and max [s].
        """
        return {'latency_bins_us': ' '.join(str(e) for e in EDGES_US),
                'latency_counts': ' '.join(str(c) for c in self.counts),
                'latency_mean_s': f'{self.mean:.9g}', 'latency_max_s': f'{self.max:.9g}',
                'latency_n': str(self.n)}

    @classmethod
    def from_values(cls, values: Dict[str, str]) -> 'LatencyHistogram':
        """Inverse of :meth:`as_values` (for the report); bins must match :data:`EDGES_US`."""
        edges = tuple(int(e) for e in values['latency_bins_us'].split())
        if edges != EDGES_US:
            raise ValueError(f'latency histogram with other bin edges {edges}')
        h = cls()
        h.counts = [int(c) for c in values['latency_counts'].split()]
        h.n = int(values['latency_n'])
        h.total = float(values['latency_mean_s']) * h.n if h.n else 0.0
        h.max = float(values['latency_max_s'])
        return h


def edges_seconds() -> Sequence[float]:
    return tuple(e * 1e-6 for e in EDGES_US)


# Pre-flight probe and deadline watchdog of the fixed-rate loop --------------------------------
#: The rates a free_run loop is judged at (the probe names the highest one this machine holds;
#: ``make bench`` measures each one beside a busy process) [Hz].
CANDIDATE_RATES_HZ = (250, 500, 1000, 2000)
#: Share of the period the probe's loop latency may take at its :data:`PROBE_QUANTILE`. The probe
#: times the loop's two hops (measurement out, command back) through the nodes' own executors and
#: the plant's own step, not the controller's and observer's computation nor a loaded run's
#: jitter: half the period is left for those.
PROBE_BUDGET = 0.5
#: The quantile of the probe's latencies held against the budget (a 1 % miss rate is the limit).
PROBE_QUANTILE = 0.99


@dataclass(frozen=True)
class ProbeVerdict:
    """What the pre-flight probe measured and whether the loop holds 1 / ``period``."""

    period: float           # the run's T_s [s]
    sent: int               # probes sent
    lost: int               # probes without every echo in time (counted as infinitely late)
    p50: float              # loop latency quantiles [s] (inf when too many were lost)
    p99: float
    compute: float          # the plant's own step, part of every latency [s]
    holds: bool
    rate_held: Optional[int]    # the highest of CANDIDATE_RATES_HZ it holds [Hz] (None: none)

    def text(self) -> str:
        """One line: the measured latency against the period, and the rate that is held."""
        rate = 1.0 / self.period
        lat = (f'loop latency p50 {_us(self.p50)}, p99 {_us(self.p99)} (plant step '
               f'{_us(self.compute)}, {self.sent} probes, {self.lost} lost)')
        held = (f'this machine holds {self.rate_held} Hz (T_s = {1.0 / self.rate_held:g} s)'
                if self.rate_held else
                f'this machine holds none of {", ".join(map(str, CANDIDATE_RATES_HZ))} Hz')
        verdict = 'holds' if self.holds else 'cannot hold'
        return (f'free_run at {rate:g} Hz: measured {lat}; budget {PROBE_BUDGET:g} of the '
                f'period = {_us(PROBE_BUDGET * self.period)}: {verdict} it; {held}')


def _us(seconds: float) -> str:
    return f'{seconds * 1e6:.0f} µs' if math.isfinite(seconds) else 'inf'


def assess_probe(latencies: Sequence[float], sent: int, period: float,
                 compute: float = 0.0) -> ProbeVerdict:
    """
    Judge a free_run rate from the pre-flight probe's loop latencies.

    ``latencies``: the round trip [s] of each probe that came back from every node (the slowest
    echo of each); ``sent - len(latencies)`` probes were lost and count as infinitely late.
    ``compute``: the plant's own step at ``period`` [s], added to each: the plant integrates
    step k+1 and publishes its measurements in the period in which step k's command must arrive.
    The loop holds 1 / ``period`` when the :data:`PROBE_QUANTILE` of the latencies is within
    :data:`PROBE_BUDGET` of the period. The rate it holds is judged the same way at each of
    :data:`CANDIDATE_RATES_HZ`, the plant's step scaled with the period (it integrates in
    sub-steps of at most ``max_substep``) and the round trips taken as they are.
    """
    if period <= 0:
        raise ValueError(f'period must be > 0, not {period!r}')
    if sent <= 0:
        raise ValueError('the probe sent nothing: nothing to judge')
    lost = max(sent - len(latencies), 0)
    trips = sorted(latencies) + [math.inf] * lost

    def q(p: float) -> float:
        return trips[min(len(trips) - 1, max(0, math.ceil(p * len(trips)) - 1))]
    p50, p99 = q(0.5) + compute, q(PROBE_QUANTILE) + compute
    trip99 = q(PROBE_QUANTILE)
    held = [f for f in CANDIDATE_RATES_HZ
            if trip99 + compute / (f * period) <= PROBE_BUDGET / f]
    return ProbeVerdict(period, sent, lost, p50, p99, compute, p99 <= PROBE_BUDGET * period,
                        max(held) if held else None)


class DeadlineWatchdog:
    """
    Count the steps whose command missed its deadline over the last ``window`` steps.

    :meth:`add` returns a reason (one line) at the step where more than ``limit`` (a fraction) of
    the last ``window`` steps missed — the loop then stops with zero voltage before a held command
    drives the motor away — and None otherwise. ``limit`` 0 turns it off. Constant memory.
    """

    __slots__ = ('window', 'limit', '_ring', '_i', '_missed', '_steps')

    def __init__(self, window: int = 100, limit: float = 0.1):
        if int(window) < 1:
            raise ValueError(f'deadline_window must be >= 1 step, not {window!r}')
        if not 0.0 <= float(limit) <= 1.0:
            raise ValueError(f'deadline_miss_limit must be within [0, 1], not {limit!r}')
        self.window, self.limit = int(window), float(limit)
        self._ring = bytearray(self.window)
        self._i = self._missed = self._steps = 0

    @property
    def missed_in_window(self) -> int:
        return self._missed

    def add(self, missed: bool) -> Optional[str]:
        ring, i = self._ring, self._i
        self._missed += int(missed) - ring[i]
        ring[i] = 1 if missed else 0
        self._i = (i + 1) % self.window
        self._steps += 1
        if self.limit and self._missed > self.limit * self.window:
            return (f'deadline watchdog: {self._missed} of the last '
                    f'{min(self._steps, self.window)} steps missed their deadline (limit '
                    f'{self.limit:.0%} of {self.window})')
        return None
