"""
Latency accounting of the fixed-rate (``free_run``) loop: a histogram with fixed edges.

The plant adds one sample per step (measurement k published → command k received, wall clock);
the histogram is reported at the end of the run (log, ``/im/status`` values, the report). Fixed
edges keep memory constant however long the run, and make runs comparable.
"""
from __future__ import annotations

import bisect
from typing import Dict, List, Sequence

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
