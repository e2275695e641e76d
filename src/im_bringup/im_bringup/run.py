"""A recording turned into analysis arrays: :func:`load_run` -> :class:`Run`.

The trace follows the :mod:`im_common.metrics` format: equal-length 1-D arrays sampled at the
control instants t_k (the stamps of ``/im/measured/current``), every topic aligned on its header
stamp (simulated time, exact integer ns). A topic without a sample at some t_k gives NaN there;
the observer's prediction x̂_{k+1} is stamped t_{k+1}, so it lines up with the truth at t_{k+1}.

==============================  ==========================================================
trace key                        source (``im_common.topics``)
==============================  ==========================================================
t [s], t_ns [ns]                 stamps of /im/measured/current (else /im/measured/shaft, ...)
i_alpha, i_beta                  /im/measured/current
theta_r, omega_r                 /im/measured/shaft position, velocity
theta_ref, omega_ref, tau_ref    /im/reference/shaft position, velocity, effort
v_cmd_alpha, v_cmd_beta          /im/command/voltage
v_alpha, v_beta                  /im/truth/voltage (applied; the command if not recorded)
i_ref_alpha, i_ref_beta          /im/reference/current
phi_ref_alpha/beta, phi_ref_mag  /im/reference/flux (x, y, z)
phi_r_alpha, phi_r_beta          /im/truth/flux
phi_hat_alpha, phi_hat_beta      /im/observer/flux
i_hat_alpha, i_hat_beta          /im/observer/current
tau_m, tau_L, tau_friction       /im/truth/torque (x, y, z)
<name>_hat                       /im/adapter/estimate, names R_r, theta, L_M, R_R
R_s, R_r, ..., L_M, R_R          /im/truth/parameters
P_in, ..., P_param               /im/truth/power
E_in, ..., W_mag, E_kin          /im/truth/energy
phi_reest_*, i_reest_*           /im/reestimate/observer/flux, /current (replay --reestimate)
==============================  ==========================================================

``truth_final`` holds the energy books over the recorded window in the key names of
:meth:`im_common.plant_sim.PlantSimulator.truth` (integrals as last − first sample, which is the
plant's own value when the recording starts at t = 0), the last parameter values, and
``dW_mag``, ``dE_kin`` and ``balance_residual`` computed exactly as the plant does.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Dict, List, Optional, Tuple

import numpy as np

from im_common import cdr

try:
    from im_common import topics as T
except ImportError:  # pragma: no cover - im_common is an exec_depend
    T = None

REEST_FLUX = '/im/reestimate/observer/flux'
REEST_CURRENT = '/im/reestimate/observer/current'

# topic -> trace keys for x, y, z (None: not used)
V3_KEYS: Dict[str, Tuple[Optional[str], Optional[str], Optional[str]]] = {
    '/im/measured/current': ('i_alpha', 'i_beta', None),
    '/im/command/voltage': ('v_cmd_alpha', 'v_cmd_beta', None),
    '/im/truth/voltage': ('v_alpha', 'v_beta', None),
    '/im/observer/flux': ('phi_hat_alpha', 'phi_hat_beta', None),
    '/im/observer/current': ('i_hat_alpha', 'i_hat_beta', None),
    '/im/reference/current': ('i_ref_alpha', 'i_ref_beta', None),
    '/im/reference/flux': ('phi_ref_alpha', 'phi_ref_beta', 'phi_ref_mag'),
    '/im/truth/flux': ('phi_r_alpha', 'phi_r_beta', None),
    '/im/truth/torque': ('tau_m', 'tau_L', 'tau_friction'),
    REEST_FLUX: ('phi_reest_alpha', 'phi_reest_beta', None),
    REEST_CURRENT: ('i_reest_alpha', 'i_reest_beta', None),
}
# JointState topics with fixed meaning of position/velocity/effort
JS_FIELDS = {
    '/im/measured/shaft': ('theta_r', 'omega_r', None),
    '/im/reference/shaft': ('theta_ref', 'omega_ref', 'tau_ref'),
}
# JointState topics carrying named values in position: topic -> key suffix
JS_NAMED = {
    '/im/adapter/estimate': '_hat',
    '/im/truth/parameters': '',
    '/im/truth/power': '',
    '/im/truth/energy': '',
}
MASTER_TOPICS = ('/im/measured/current', '/im/measured/shaft', '/im/truth/energy',
                 '/im/command/voltage')
ENERGY_INTEGRALS = ('E_in', 'E_cu_s', 'E_cu_r', 'E_core', 'E_friction', 'W_load', 'E_param')
PARAM_KEYS = ('R_s', 'R_r', 'L_s', 'L_r', 'L_sr', 'theta', 'L_M', 'R_R')

_V3_DTYPE = np.dtype([('enc', 'V4'), ('sec', '<i4'), ('nsec', '<u4'), ('slen', '<u4'),
                      ('pad', 'V4'), ('x', '<f8'), ('y', '<f8'), ('z', '<f8')])


@dataclass
class Run:
    """One recording, ready for analysis."""

    path: str
    trace: Dict[str, np.ndarray]
    truth_final: Dict[str, float]
    metadata: Dict[str, Dict[str, str]]
    counts: Dict[str, int] = field(default_factory=dict)
    types: Dict[str, str] = field(default_factory=dict)

    @property
    def task(self) -> Optional[str]:
        """'position', 'speed' or 'torque' if the run's metadata says so."""
        for name in ('scenario', 'run'):
            t = self.metadata.get(name, {}).get('task')
            if t:
                return t
        return None

    @property
    def label(self) -> str:
        sc = self.metadata.get('scenario', {})
        parts = [sc.get(k) for k in ('task', 'strategy', 'controller') if sc.get(k)]
        from pathlib import Path
        return Path(self.path).stem + (f" ({', '.join(parts)})" if parts else '')


def _stamp_ns(sec, nsec):
    return np.asarray(sec, dtype=np.int64) * 1_000_000_000 + np.asarray(nsec, dtype=np.int64)


def _decode_v3(payloads: List[bytes]):
    if payloads and all(len(p) == cdr.V3_EMPTY_SIZE for p in payloads):
        a = np.frombuffer(b''.join(payloads), dtype=_V3_DTYPE)
        return _stamp_ns(a['sec'], a['nsec']), a['x'].copy(), a['y'].copy(), a['z'].copy()
    if payloads:
        n = len(payloads[0])
        head = payloads[0][12:n - 24]
        if n >= 44 and all(len(p) == n and p[12:n - 24] == head for p in payloads):
            # one frame_id throughout: fixed layout, decode in one go
            dt = np.dtype({'names': ['sec', 'nsec', 'x', 'y', 'z'],
                           'formats': ['<i4', '<u4', '<f8', '<f8', '<f8'],
                           'offsets': [4, 8, n - 24, n - 16, n - 8], 'itemsize': n})
            a = np.frombuffer(b''.join(payloads), dtype=dt)
            return _stamp_ns(a['sec'], a['nsec']), a['x'].copy(), a['y'].copy(), a['z'].copy()
    rows = [cdr.decode_vector3_stamped(p) for p in payloads]
    if not rows:
        e = np.zeros(0)
        return np.zeros(0, np.int64), e, e, e
    sec, nsec, x, y, z = (np.array(c) for c in zip(*rows))
    return _stamp_ns(sec, nsec), x.astype(float), y.astype(float), z.astype(float)


def _align(master: np.ndarray, stamps: np.ndarray, values: np.ndarray) -> np.ndarray:
    """values sampled at ``stamps`` picked at ``master`` (NaN where absent; last one wins)."""
    out = np.full(master.shape, np.nan)
    if len(stamps) == 0:
        return out
    order = np.argsort(stamps, kind='stable')
    s = stamps[order]
    v = values[order]
    # keep the last of equal stamps
    keep = np.ones(len(s), bool)
    keep[:-1] = s[1:] != s[:-1]
    s, v = s[keep], v[keep]
    idx = np.searchsorted(s, master)
    ok = idx < len(s)
    ok[ok] = s[idx[ok]] == master[ok]
    out[ok] = v[idx[ok]]
    return out


def build_trace(raw: Dict[str, List[bytes]]) -> Tuple[Dict[str, np.ndarray], Dict[str, dict]]:
    """Trace arrays from raw payloads grouped by topic; also the per-topic decoded series."""
    series: Dict[str, Tuple[np.ndarray, Dict[str, np.ndarray]]] = {}
    for topic, payloads in raw.items():
        if topic in V3_KEYS:
            st, x, y, z = _decode_v3(payloads)
            kx, ky, kz = V3_KEYS[topic]
            cols = {kx: x, ky: y}
            if kz:
                cols[kz] = z
            series[topic] = (st, cols)
        elif topic in JS_FIELDS or topic in JS_NAMED:
            rows = [cdr.decode_joint_state(p) for p in payloads]
            st = _stamp_ns([r[0] for r in rows], [r[1] for r in rows]) if rows else \
                np.zeros(0, np.int64)
            cols = {}
            if topic in JS_FIELDS:
                for j, key in enumerate(JS_FIELDS[topic]):
                    if key is None:
                        continue
                    col = np.array([r[3 + j][0] if r[3 + j] else np.nan for r in rows], float)
                    if np.isfinite(col).any():
                        cols[key] = col
            else:
                suffix = JS_NAMED[topic]
                names = []
                for r in rows:
                    for n in r[2]:
                        if n not in names:
                            names.append(n)
                for n in names:
                    col = np.full(len(rows), np.nan)
                    for i, r in enumerate(rows):
                        try:
                            col[i] = r[3][r[2].index(n)]
                        except (ValueError, IndexError):
                            pass
                    cols[n + suffix] = col
            series[topic] = (st, cols)
    master = None
    for topic in MASTER_TOPICS:
        if topic in series and len(series[topic][0]):
            master = np.unique(series[topic][0])
            break
    if master is None:
        allst = [s for s, _ in series.values() if len(s)]
        master = np.unique(np.concatenate(allst)) if allst else np.zeros(0, np.int64)
    trace: Dict[str, np.ndarray] = {'t_ns': master, 't': master.astype(float) * 1e-9}
    for topic, (st, cols) in series.items():
        for key, col in cols.items():
            trace[key] = _align(master, st, col)
    if 'v_alpha' not in trace and 'v_cmd_alpha' in trace:
        trace['v_alpha'] = trace['v_cmd_alpha']
        trace['v_beta'] = trace['v_cmd_beta']
    return trace, {t: {'t_ns': s, **c} for t, (s, c) in series.items()}


def truth_final_from(series: Dict[str, dict]) -> Dict[str, float]:
    """The energy books over the recorded window (see module doc)."""
    out: Dict[str, float] = {}
    en = series.get('/im/truth/energy')
    if en is not None and len(en['t_ns']):
        order = np.argsort(en['t_ns'], kind='stable')
        first, last = order[0], order[-1]
        for k, v in en.items():
            if k == 't_ns':
                continue
            if k in ENERGY_INTEGRALS:
                out[k] = float(v[last] - v[first])
            else:
                out[k] = float(v[last])
        if 'W_mag' in en:
            out['dW_mag'] = float(en['W_mag'][last] - en['W_mag'][first])
        if 'E_kin' in en:
            out['dE_kin'] = float(en['E_kin'][last] - en['E_kin'][first])
        need = ('E_in', 'E_cu_s', 'E_cu_r', 'E_friction', 'W_load', 'E_param', 'dW_mag', 'dE_kin')
        if all(k in out for k in need):
            # the plant's definition (PlantSimulator.truth): core loss is an accounting model,
            # outside the balance
            out['balance_residual'] = (out['E_in'] - out['E_cu_s'] - out['E_cu_r']
                                       - out['E_friction'] - out['W_load'] - out['E_param']
                                       - out['dW_mag'] - out['dE_kin'])
        out['t_final'] = float(en['t_ns'][last]) * 1e-9
    par = series.get('/im/truth/parameters')
    if par is not None and len(par['t_ns']):
        last = int(np.argmax(par['t_ns']))
        for k, v in par.items():
            if k != 't_ns':
                out[k] = float(v[last])
    return out


def load_run(path) -> Run:
    """Read a recording into a :class:`Run`; :class:`~im_bringup.bag.BagError` if unreadable."""
    from .bag import BagError, info, iter_raw
    bi = info(path)
    raw: Dict[str, List[bytes]] = {}
    wanted = set(V3_KEYS) | set(JS_FIELDS) | set(JS_NAMED)
    for topic, tname, _t, data in iter_raw(path, [t for t in bi.topics if t in wanted]):
        raw.setdefault(topic, []).append(data)
    try:
        trace, series = build_trace(raw)
    except cdr.CdrError as exc:
        raise BagError(path, f'undecodable message: {exc}') from None
    meta = {k: v for k, v in bi.metadata.items() if k != 'rosbag2'}
    return Run(str(path), trace, truth_final_from(series), meta, dict(bi.counts), dict(bi.topics))
