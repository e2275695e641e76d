"""Messages of a run → the trace arrays of :mod:`im_common.metrics`.

Used live (tapping the in-process graph) and on recordings (feeding the messages read from an
MCAP), so the figures of a run are computed the same way in both places. Samples are aligned on
the instants where the decimated analysis topics (references, ground truth) exist.
"""
from __future__ import annotations

from typing import Dict, Optional, Sequence

import numpy as np

from im_common import topics as T

# topic -> list of (trace key, extractor)
_V3 = {
    T.MEAS_CURRENT: ('i_alpha', 'i_beta', None),
    T.CMD_VOLTAGE: ('v_alpha', 'v_beta', None),
    T.OBS_FLUX: ('phi_hat_alpha', 'phi_hat_beta', None),
    T.OBS_CURRENT: ('i_hat_alpha', 'i_hat_beta', None),
    T.REF_CURRENT: ('i_alpha_ref', 'i_beta_ref', None),
    T.REF_FLUX: ('phi_ref_alpha', 'phi_ref_beta', 'phi_d_ref'),
    T.TRUTH_VOLTAGE: ('v_applied_alpha', 'v_applied_beta', None),
    T.TRUTH_FLUX: ('phi_r_alpha', 'phi_r_beta', None),
    T.TRUTH_TORQUE: ('tau_m', 'tau_L', 'tau_friction'),
}
_JS_NAMED = {
    T.ADAPT_ESTIMATE: lambda n: f'{n}_hat',
    T.TRUTH_PARAMS: lambda n: f'{n}_true',
    T.TRUTH_POWER: lambda n: n,
    T.TRUTH_ENERGY: lambda n: n,
}


class TraceBuilder:
    """Accumulates ``add(topic, ns, msg)`` and returns aligned arrays with :meth:`trace`."""

    def __init__(self):
        self.samples: Dict[str, Dict[int, float]] = {}

    def _put(self, key: str, ns: int, value: float) -> None:
        d = self.samples.get(key)
        if d is None:
            d = self.samples[key] = {}
        d[ns] = value

    def add(self, topic: str, ns: int, msg) -> None:
        keys = _V3.get(topic)
        if keys is not None:
            v = msg.vector
            self._put(keys[0], ns, v.x)
            self._put(keys[1], ns, v.y)
            if keys[2] is not None:
                self._put(keys[2], ns, v.z)
            return
        if topic == T.MEAS_SHAFT:
            self._put('theta_r', ns, msg.position[0])
            self._put('omega_r', ns, msg.velocity[0])
        elif topic == T.REF_SHAFT:
            self._put('theta_ref', ns, msg.position[0])
            self._put('omega_ref', ns, msg.velocity[0])
            self._put('tau_ref', ns, msg.effort[0])
        elif topic in _JS_NAMED:
            rename = _JS_NAMED[topic]
            for n, v in zip(msg.name, msg.position):
                self._put(rename(n), ns, v)

    def trace(self, align_on: Optional[Sequence[str]] = None) -> Dict[str, np.ndarray]:
        """Arrays on the instants where all of ``align_on`` (default: the energy books, the
        references and the shaft measurement, those present) were sampled; keys without a sample
        at every one of those instants are dropped."""
        if not self.samples:
            return {}
        core = [k for k in (align_on or ('E_in', 'tau_ref', 'theta_r')) if k in self.samples]
        if not core:
            core = [next(iter(self.samples))]
        stamps = sorted(set.intersection(*(set(self.samples[k]) for k in core)))
        out = {'t': np.array(stamps, dtype=float) / 1e9}
        for key, d in self.samples.items():
            if all(s in d for s in stamps):
                out[key] = np.array([d[s] for s in stamps])
        return out

    def final(self, key: str) -> Optional[float]:
        d = self.samples.get(key)
        if not d:
            return None
        return d[max(d)]


class Tap:
    """Graph publisher tap: every message goes to the trace builder and, if given, to a bag."""

    def __init__(self, builder: TraceBuilder, writer=None):
        self.builder, self.writer = builder, writer

    def write(self, topic, msg, ns) -> None:
        self.builder.add(topic, ns, msg)
        if self.writer is not None:
            self.writer.write(topic, msg, ns)
