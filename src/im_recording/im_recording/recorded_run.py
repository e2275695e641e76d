"""
A recording turned into analysis arrays: :func:`load_run` -> :class:`RecordedRun`.

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
theta_true, omega_true           /im/truth/shaft position, velocity (no measurement noise)
V_max, i_max                     /im/truth/peaks (largest |V_s|, |i_s| of every step since the
                                 previous sample)
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
:meth:`im_plant.plant_sim.PlantSimulator.truth` (integrals as last − first sample, which is the
plant's own value when the recording starts at t = 0), the last parameter values, and
``dW_mag``, ``dE_kin`` and ``balance_residual`` computed exactly as the plant does.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Dict, List, Optional, Tuple

from im_common import cdr
from im_common import topics as T
from im_common.conversions import NS_PER_S, ns_to_s
from im_common.loads import load_from_dict, load_from_parameters
from im_common.metrics import LoadStepFigures
from im_common.params import THESIS_MOTOR
import numpy as np
import yaml

from .bag import BagError, check_data_crc, info, iter_raw

REEST_FLUX, REEST_CURRENT = T.REEST_FLUX, T.REEST_CURRENT

# topic -> trace keys for x, y, z (None: not used)
V3_KEYS: Dict[str, Tuple[Optional[str], Optional[str], Optional[str]]] = {
    T.MEAS_CURRENT: ('i_alpha', 'i_beta', None),
    T.CMD_VOLTAGE: ('v_cmd_alpha', 'v_cmd_beta', None),
    T.TRUTH_VOLTAGE: ('v_alpha', 'v_beta', None),
    T.OBS_FLUX: ('phi_hat_alpha', 'phi_hat_beta', None),
    T.OBS_CURRENT: ('i_hat_alpha', 'i_hat_beta', None),
    T.REF_CURRENT: ('i_ref_alpha', 'i_ref_beta', None),
    T.REF_FLUX: ('phi_ref_alpha', 'phi_ref_beta', 'phi_ref_mag'),
    T.TRUTH_FLUX: ('phi_r_alpha', 'phi_r_beta', None),
    T.TRUTH_TORQUE: ('tau_m', 'tau_L', 'tau_friction'),
    REEST_FLUX: ('phi_reest_alpha', 'phi_reest_beta', None),
    REEST_CURRENT: ('i_reest_alpha', 'i_reest_beta', None),
}
# JointState topics with fixed meaning of position/velocity/effort
JS_FIELDS = {
    T.MEAS_SHAFT: ('theta_r', 'omega_r', None),
    T.OBS_SPEED: ('theta_hat', 'omega_hat', None),
    T.REF_SHAFT: ('theta_ref', 'omega_ref', 'tau_ref'),
    T.TRUTH_SHAFT: ('theta_true', 'omega_true', None),
}
# JointState topics carrying named values in position: topic -> key suffix
JS_NAMED = {
    T.ADAPT_ESTIMATE: '_hat',
    T.TRUTH_PARAMS: '',
    T.TRUTH_POWER: '',
    T.TRUTH_ENERGY: '',
    T.TRUTH_PEAKS: '',
    T.TRUTH_TEMPERATURE: '',
    T.TRUTH_INVERTER: '',
}
TRACE_TOPICS = frozenset(V3_KEYS) | frozenset(JS_FIELDS) | frozenset(JS_NAMED)
MASTER_TOPICS = (T.MEAS_CURRENT, T.MEAS_SHAFT, T.TRUTH_ENERGY,
                 T.CMD_VOLTAGE)
ENERGY_INTEGRALS = ('E_in', 'E_cu_s', 'E_cu_r', 'E_core', 'E_friction', 'W_load', 'E_param',
                    T.IRON_LOSS_NAME, T.INVERTER_LOSS_NAME, T.SWITCHING_LOSS_NAME)
PARAM_KEYS = ('R_s', 'R_r', 'L_s', 'L_r', 'L_sr', 'theta', 'L_M', 'R_R')


@dataclass
class RecordedRun:
    """One recording, ready for analysis."""

    path: str
    trace: Dict[str, np.ndarray]
    truth_final: Dict[str, float]
    metadata: Dict[str, Dict[str, str]]
    counts: Dict[str, int] = field(default_factory=dict)
    types: Dict[str, str] = field(default_factory=dict)
    #: running figures over every control instant (:class:`RunningFigures`); when None,
    #: :func:`im_recording.report.figures_of_merit` computes them from ``trace``
    running: Optional['RunningFigures'] = None
    #: messages stamped before rows already summarized (not in the figures)
    late: int = 0
    #: the run-protocol events on /im/status that end a node's run (:class:`RunEvents`)
    events: List[dict] = field(default_factory=list)

    @property
    def task(self) -> Optional[str]:
        """'position', 'speed' or 'torque' if the run's metadata says so."""
        for name in ('scenario', 'run'):
            t = self.metadata.get(name, {}).get('task')
            if t:
                return t
        return None

    @property
    def refused(self) -> Dict[str, int]:
        """
        Count the messages not signed by the recorded graph, per topic.

        Messages not signed by the recorded graph (a rogue publisher, another graph), per topic
        they came on, as the recorder kept them on ``/im/refused<topic>``.
        """
        n = len(T.REFUSED_PREFIX)
        return {t[n:]: c for t, c in sorted(self.counts.items())
                if t.startswith(T.REFUSED_PREFIX + '/') and c}

    @property
    def label(self) -> str:
        sc = self.metadata.get('scenario', {})
        parts = [sc.get(k) for k in ('task', 'strategy', 'controller') if sc.get(k)]
        return Path(self.path).stem + (f" ({', '.join(parts)})" if parts else '')


def _stamp_ns(sec, nsec):
    return np.asarray(sec, dtype=np.int64) * NS_PER_S + np.asarray(nsec, dtype=np.int64)


def _decode_v3(payloads: List[bytes]):
    batch = cdr.vector3_stamped_batch(payloads)     # one layout: one read
    if batch is not None:
        return batch
    rows = [cdr.decode_vector3_stamped(p) for p in payloads]
    if not rows:
        e = np.zeros(0)
        return np.zeros(0, np.int64), e, e, e
    sec, nsec, x, y, z = (np.array(c) for c in zip(*rows))
    return _stamp_ns(sec, nsec), x.astype(float), y.astype(float), z.astype(float)


def _align(master: np.ndarray, stamps: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Pick the values sampled at ``stamps`` at ``master`` (NaN where absent; last one wins)."""
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


def _decode_js(topic: str, payloads: List[bytes]):
    fixed = cdr.joint_state_batch(payloads)        # one layout: one read
    if fixed is not None:
        st, row_names, seqs = fixed
        cols = {}
        if topic in JS_FIELDS:
            for j, key in enumerate(JS_FIELDS[topic]):
                if key is None:
                    continue
                col = (seqs[j][:, 0].astype(float) if seqs[j] is not None
                       else np.full(len(st), np.nan))
                if np.isfinite(col).any():
                    cols[key] = col
            return st, cols
        suffix = JS_NAMED[topic]
        pos = seqs[0]
        for name in dict.fromkeys(row_names):
            i = row_names.index(name)
            cols[name + suffix] = (pos[:, i].astype(float) if pos is not None and
                                   i < pos.shape[1] else np.full(len(st), np.nan))
        return st, cols
    rows = [cdr.decode_joint_state(p) for p in payloads]
    st = _stamp_ns([r[0] for r in rows], [r[1] for r in rows]) if rows else np.zeros(0, np.int64)
    cols = {}
    if topic in JS_FIELDS:
        for j, key in enumerate(JS_FIELDS[topic]):
            if key is None:
                continue
            col = np.array([r[3 + j][0] if r[3 + j] else np.nan for r in rows], float)
            if np.isfinite(col).any():
                cols[key] = col
        return st, cols
    suffix = JS_NAMED[topic]
    names: List[str] = []
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
    return st, cols


def decode_topic(topic: str, payloads: List[bytes]):
    """
    (stamps ns, {trace key: values}) of one topic's payloads, in their order.

    None for a topic the trace does not use.
    """
    if topic in V3_KEYS:
        st, x, y, z = _decode_v3(payloads)
        kx, ky, kz = V3_KEYS[topic]
        cols = {kx: x, ky: y}
        if kz:
            cols[kz] = z
        return st, cols
    if topic in JS_FIELDS or topic in JS_NAMED:
        return _decode_js(topic, payloads)
    return None


class TraceStream:
    """
    Align a trace in bounded memory.

    :func:`build_trace` in bounded memory: payloads go in with :meth:`add`, and every ``batch``
    messages the rows older than the newest ``margin`` master stamps are aligned and handed to
    ``sinks`` (objects with ``rows(chunk)`` and ``series(series_chunk)``), then dropped. A message
    stamped before rows already handed on cannot be aligned any more: it is counted in :attr:`late`
    (the caller reports it), never silently merged.
    """

    def __init__(self, sinks=(), batch: int = 40000, margin: int = 256):
        self.sinks = list(sinks)
        self.batch, self.margin = int(batch), int(margin)
        self.pending: Dict[str, List[bytes]] = {}
        self.counts: Dict[str, int] = {}
        self.master: Optional[str] = None      # '' = union of all stamps
        self.cutoff: Optional[int] = None      # rows before it were handed on
        self.late = 0
        self._n = 0

    def add(self, topic: str, data: bytes) -> None:
        self.counts[topic] = self.counts.get(topic, 0) + 1
        if topic not in TRACE_TOPICS:
            return
        lst = self.pending.get(topic)
        if lst is None:
            lst = self.pending[topic] = []
        lst.append(data)
        self._n += 1
        if self._n >= self.batch:
            self.flush(final=False)

    def _pick_master(self, series) -> None:
        if self.master is not None:
            return
        for topic in MASTER_TOPICS:
            if topic in series and len(series[topic][0]):
                self.master = topic
                return
        self.master = ''

    def flush(self, final: bool = True) -> None:
        series = {}
        for topic, payloads in self.pending.items():
            dec = decode_topic(topic, payloads)
            if dec is not None:
                series[topic] = dec
        if not series:
            self._n = 0
            return
        self._pick_master(series)
        if self.master:
            ms = series[self.master][0] if self.master in series else np.zeros(0, np.int64)
        else:
            ms = np.concatenate([st for st, _ in series.values()])
        ms = np.unique(ms)
        if self.cutoff is not None:
            ms = ms[ms >= self.cutoff]
        if final:
            cutoff = None
        elif len(ms) <= self.margin:
            self._n = sum(len(v) for v in self.pending.values()) // 2   # wait for more
            return
        else:
            cutoff = int(ms[-self.margin])
            ms = ms[ms < cutoff]
        chunk: Dict[str, np.ndarray] = {'t_ns': ms, 't': ns_to_s(ms.astype(float))}
        sent: Dict[str, dict] = {}
        for topic, (st, cols) in series.items():
            now = np.ones(len(st), bool) if cutoff is None else st < cutoff
            if self.cutoff is not None:
                old = st < self.cutoff
                self.late += int(old.sum())
                now &= ~old
            for key, col in cols.items():
                chunk[key] = _align(ms, st[now], col[now])
            chunk['present:' + topic] = _align(ms, st[now], np.ones(int(now.sum())))
            sent[topic] = {'t_ns': st[now], **{k: c[now] for k, c in cols.items()}}
            if cutoff is not None:
                keep = np.flatnonzero(st >= cutoff)
                payloads = self.pending[topic]
                self.pending[topic] = [payloads[i] for i in keep]
        if cutoff is None:
            self.pending = {t: [] for t in self.pending}
        if cutoff is not None:
            self.cutoff = cutoff
        self._n = sum(len(v) for v in self.pending.values())
        for sink in self.sinks:
            sink.series(sent)
            if len(ms):
                sink.rows(chunk)


class TraceKeeper:
    """
    Sink of a :class:`TraceStream` that keeps the aligned rows.

    All of them, or (``limit``) at most about 2·limit, thinned to every S-th control instant
    where S is a multiple of every topic's own publishing period (so decimated topics keep
    their samples).
    """

    def __init__(self, limit: Optional[int] = None):
        self.limit = limit
        self.stride = 1
        self.parts: List[Dict[str, np.ndarray]] = []
        self.n = 0
        self._t0: Optional[int] = None
        self._dt: Dict[str, int] = {}       # topic -> smallest stamp step seen

    def series(self, sent) -> None:
        for topic, cols in sent.items():
            st = np.unique(cols['t_ns'])
            if len(st) > 1:
                d = int(np.min(np.diff(st)))
                self._dt[topic] = min(d, self._dt.get(topic, d))

    def _base(self) -> int:
        if not self._dt:
            return 2
        step = min(self._dt.values())
        base = 1
        for d in self._dt.values():
            base = int(np.lcm(base, max(1, int(round(d / step)))))
        return max(base, 2)

    def rows(self, chunk) -> None:
        if self._t0 is None:
            self._t0 = int(chunk['t_ns'][0])
        if self.stride > 1:
            chunk = self._thin(chunk, self.stride)
        self.parts.append(chunk)
        self.n += len(chunk['t_ns'])
        if self.limit is not None and self.n > 2 * self.limit:
            self.stride = self._base() if self.stride == 1 else 2 * self.stride
            whole = self._thin(self.trace(raw=True), self.stride)
            self.parts, self.n = [whole], len(whole['t_ns'])

    def _thin(self, chunk, stride):
        step = min(self._dt.values()) if self._dt else 1
        k = (chunk['t_ns'] - self._t0) // max(step, 1)
        sel = k % stride == 0
        return {key: v[sel] for key, v in chunk.items()}

    def trace(self, raw: bool = False) -> Dict[str, np.ndarray]:
        keys: List[str] = []
        for part in self.parts:
            keys += [k for k in part if k not in keys]
        out = {}
        for key in keys:
            out[key] = np.concatenate([p[key] if key in p else np.full(len(p['t_ns']), np.nan)
                                       for p in self.parts]) if self.parts else np.zeros(0)
        if not self.parts:
            out = {'t_ns': np.zeros(0, np.int64), 't': np.zeros(0)}
        if raw:
            return out
        out['t_ns'] = out['t_ns'].astype(np.int64)
        out = {k: v for k, v in out.items() if not k.startswith('present:')}
        if 'v_alpha' not in out and 'v_cmd_alpha' in out:
            out['v_alpha'] = out['v_cmd_alpha']
            out['v_beta'] = out['v_cmd_beta']
        return out


class TruthBooks:
    """
    Keep what :func:`truth_final_from` needs from a trace stream.

    Sink of a :class:`TraceStream` keeping the first and last energy sample and the last parameter
    sample: all :func:`truth_final_from` needs.
    """

    def __init__(self):
        self.first: Optional[tuple] = None
        self.last: Optional[tuple] = None
        self.par: Optional[tuple] = None

    def series(self, sent) -> None:
        en = sent.get(T.TRUTH_ENERGY)
        if en is not None and len(en['t_ns']):
            order = np.argsort(en['t_ns'], kind='stable')
            i0, i1 = order[0], order[-1]
            if self.first is None or en['t_ns'][i0] < self.first[0]:
                self.first = (int(en['t_ns'][i0]), {k: v[i0] for k, v in en.items()})
            if self.last is None or en['t_ns'][i1] >= self.last[0]:
                self.last = (int(en['t_ns'][i1]), {k: v[i1] for k, v in en.items()})
        par = sent.get(T.TRUTH_PARAMS)
        if par is not None and len(par['t_ns']):
            i = int(np.argmax(par['t_ns']))
            if self.par is None or par['t_ns'][i] > self.par[0]:
                self.par = (int(par['t_ns'][i]), {k: v[i] for k, v in par.items()})

    def rows(self, chunk) -> None:
        pass

    def final(self) -> Dict[str, float]:
        series = {}
        if self.first is not None:
            keys = [k for k in self.last[1] if k in self.first[1]]
            first, last = self.first[1], self.last[1]
            series[T.TRUTH_ENERGY] = {k: np.array([first[k], last[k]]) for k in keys}
        if self.par is not None:
            series[T.TRUTH_PARAMS] = {k: np.array([v]) for k, v in self.par[1].items()}
        return truth_final_from(series)


def _diff(a, b):
    return lambda tr: tr[a] - tr[b]


def _norm_diff(a, b):
    return lambda tr: np.hypot(tr[a + '_alpha'] - tr[b + '_alpha'],
                               tr[a + '_beta'] - tr[b + '_beta'])


def _norm(a):
    return lambda tr: np.hypot(tr[a + '_alpha'], tr[a + '_beta'])


# (figure, RMS figure or None, keys that must be in the trace, signal): the definitions of
# im_common.metrics.tracking_figures, as running maxima and sums of squares. A figure with
# several rows takes the first whose keys the run recorded: tracking errors from the true shaft
# (/im/truth/shaft) and peaks from every step (/im/truth/peaks); recordings made before those
# topics existed, from the measurement and the sampled voltage.
TRACKING = (
    ('pos_err_max_rad', 'pos_err_rms_rad', ('theta_ref', 'theta_true'),
     _diff('theta_true', 'theta_ref')),
    ('pos_err_max_rad', 'pos_err_rms_rad', ('theta_ref', 'theta_r'),
     _diff('theta_r', 'theta_ref')),
    ('speed_err_max_rad_s', 'speed_err_rms_rad_s', ('omega_ref', 'omega_true'),
     _diff('omega_true', 'omega_ref')),
    ('speed_err_max_rad_s', 'speed_err_rms_rad_s', ('omega_ref', 'omega_r'),
     _diff('omega_r', 'omega_ref')),
    ('torque_err_max_Nm', 'torque_err_rms_Nm', ('tau_ref', 'tau_m'), _diff('tau_m', 'tau_ref')),
    ('flux_err_max_Wb', 'flux_err_rms_Wb', ('phi_ref_alpha', 'phi_r_alpha'),
     _norm_diff('phi_r', 'phi_ref')),
    ('flux_est_err_max_Wb', 'flux_est_err_rms_Wb', ('phi_hat_alpha', 'phi_r_alpha'),
     _norm_diff('phi_r', 'phi_hat')),
    ('V_max_V', None, ('V_max',), lambda tr: tr['V_max']),
    ('V_max_V', None, ('v_alpha',), _norm('v')),
    ('V_max_V', None, ('v_cmd_alpha',), _norm('v_cmd')),
    ('i_max_A', None, ('i_max',), lambda tr: tr['i_max']),
    ('i_max_A', None, ('i_alpha',), _norm('i')),
)
ESTIMATED = ('R_r', 'theta', 'L_M', 'R_R')


class _Acc:
    __slots__ = ('mx', 'ss', 'n')

    def __init__(self):
        self.mx, self.ss, self.n = -np.inf, 0.0, 0

    def add(self, e) -> None:
        e = e[np.isfinite(e)]
        if len(e):
            self.mx = max(self.mx, float(np.max(np.abs(e))))
            self.ss += float(np.sum(np.square(e)))
            self.n += len(e)

    def max(self) -> float:  # noqa: A003
        return self.mx if self.n else float('nan')

    def rms(self) -> float:
        return float(np.sqrt(self.ss / self.n)) if self.n else float('nan')


def held_model_estimates(model) -> Dict[str, float]:
    """
    Return the estimates a controller without an adapter holds: its model's, as ESTIMATED.

    ``model``: its motor parameters (R_r, L_r, L_sr; a node's parameters — those not given are
    the node's defaults, the thesis motor's — or MotorParams-like).
    """
    def get(k):
        v = model.get(k) if isinstance(model, dict) else getattr(model, k, None)
        return getattr(THESIS_MOTOR, k) if v is None else v
    th = float(get('L_sr')) / float(get('L_r'))
    R_r = float(get('R_r'))
    return {'R_r': R_r, 'theta': th, 'L_M': float(get('L_sr')) * th, 'R_R': R_r * th * th}


class RunningFigures:
    """
    Sink of a :class:`TraceStream` (or fed a whole trace with :meth:`rows`).

    The tracking, peak and estimate figures of :func:`im_recording.report.figures_of_merit`
    from running maxima, sums of squares and the last ``last_window`` seconds only, plus the
    lock-step topics' missing control instants (:meth:`gaps`).
    """

    def __init__(self, last_window: float = 1.0, lockstep_topics=(), max_ranges: int = 20,
                 load_step: Optional[float] = None, held: Optional[Dict[str, float]] = None):
        #: the speed figures of a load step at ``load_step`` [s] (a speed run's), or None
        self.load_step = None if load_step is None else LoadStepFigures(load_step)
        self.window = float(last_window)
        self.seen: set = set()
        self.acc = {f[2]: _Acc() for f in TRACKING}         # by the keys they need
        self.est = {n: _Acc() for n in ESTIMATED}
        #: estimates held where no adapter publishes any (a nominal controller's model)
        self.held = dict(held or {})
        self.est_last: Dict[str, tuple] = {}
        self.est_win: Dict[str, List[np.ndarray]] = {n: [] for n in ESTIMATED}
        self.t_first: Optional[float] = None
        self.t_last: Optional[float] = None
        self.steps = 0
        self.lockstep = tuple(lockstep_topics)
        self.missing = dict.fromkeys(self.lockstep, 0)
        self.ranges: Dict[str, List[list]] = {t: [] for t in self.lockstep}
        self._open: Dict[str, bool] = dict.fromkeys(self.lockstep, False)
        self.max_ranges = max_ranges

    def series(self, sent) -> None:
        pass

    def rows(self, tr) -> None:
        t = np.asarray(tr['t'], float)
        if not len(t):
            return
        self.seen.update(tr)
        if self.t_first is None:
            self.t_first = float(t[0])
        self.t_last = float(t[-1])
        self.steps += len(t)
        nan = np.full(len(t), np.nan)
        full = {k: (np.asarray(tr[k], float) if k in tr else nan) for k in _SIGNAL_KEYS}
        for _mx, _rms, keys, fn in TRACKING:
            if all(k in tr for k in keys):
                self.acc[keys].add(fn(full))
        omega = 'omega_true' if 'omega_true' in tr else 'omega_r'
        if self.load_step is not None and omega in tr and 'omega_ref' in tr:
            self.load_step.add(t, full[omega] - full['omega_ref'])
        for n in ESTIMATED:
            if n not in tr:
                continue
            if n + '_hat' in tr:
                self._estimate(n, t, np.asarray(tr[n + '_hat'], float), np.asarray(tr[n], float))
            elif n in self.held:
                self._estimate(n, t, np.full(len(t), self.held[n]), np.asarray(tr[n], float))
        for topic in self.lockstep:
            self._gaps(topic, t, tr.get('present:' + topic))

    def _estimate(self, n, t, hat, true) -> None:
        e = hat - true
        ok = np.isfinite(e)
        self.est[n].add(e)
        if not ok.any():
            return
        last = np.flatnonzero(ok)[-1]
        self.est_last[n] = (float(t[last]), float(hat[last]), float(true[last]), float(e[last]))
        win = self.est_win[n]
        win.append(np.stack([t[ok], e[ok], true[ok]]))
        t_cut = self.est_last[n][0] - self.window
        while win and win[0][0, -1] <= t_cut:
            win.pop(0)

    def _gaps(self, topic, t, present) -> None:
        absent = np.ones(len(t), bool) if present is None else ~(present == 1)
        if not absent.any():
            self._open[topic] = False
            return
        self.missing[topic] += int(absent.sum())
        edges = np.flatnonzero(np.diff(np.concatenate([[0], absent.astype(np.int8), [0]])))
        rs = self.ranges[topic]
        for a, b in zip(edges[::2], edges[1::2]):
            if a == 0 and self._open[topic] and rs:
                rs[-1][1] = float(t[b - 1])
            elif len(rs) < self.max_ranges:
                rs.append([float(t[a]), float(t[b - 1])])
        self._open[topic] = bool(absent[-1])

    def gaps(self) -> Dict[str, dict]:
        """
        Lock-step topics with control instants that have no message: count and ranges [s].

        The run's last instant is not a gap: the plant's final measurement is answered by no one.
        """
        out = {}
        for t in self.lockstep:
            if 'present:' + t not in self.seen:
                continue                # not in this run at all (node not started/recorded)
            n, rs = self.missing[t], [tuple(r) for r in self.ranges[t]]
            if rs and rs[-1] == (self.t_last, self.t_last) and self._open[t]:
                n, rs = n - 1, rs[:-1]
            if n:
                out[t] = {'missing': n, 'ranges': rs}
        return out

    def tracking(self, task: Optional[str]) -> Dict[str, float]:
        out: Dict[str, float] = {}
        for mx_name, rms_name, keys, _fn in TRACKING:
            if mx_name in out or not all(k in self.seen for k in keys):
                continue            # an earlier row of this figure, or not recorded
            acc = self.acc[keys]
            position_only = mx_name.startswith('pos_') and task not in (None, 'position')
            out[mx_name] = float('nan') if position_only else acc.max()
            if rms_name:
                out[rms_name] = float('nan') if position_only else acc.rms()
        return out

    def load_step_figures(self) -> Dict[str, float]:
        """Return the load step's speed figures (:class:`im_common.metrics.LoadStepFigures`)."""
        if self.load_step is None:
            return {}
        return dict(self.load_step.figures(), load_step_t=self.load_step.t_step)

    def estimates(self) -> Dict[str, float]:
        out: Dict[str, float] = {}
        for n in ESTIMATED:
            if n not in self.est_last:
                continue
            acc = self.est[n]
            t_last, hat, tv, e_last = self.est_last[n]
            out[f'{n}_est_err_max'] = acc.max()
            out[f'{n}_est_err_rms'] = acc.rms()
            out[f'{n}_est_err_final_rel'] = float(abs(e_last) / abs(tv)) if tv else float('nan')
            out[f'{n}_hat_final'] = hat
            out[f'{n}_true_final'] = tv
            w = np.concatenate(self.est_win[n], axis=1)
            w = w[:, w[0] > t_last - self.window]
            if w.shape[1] and np.all(w[2] != 0):
                rel = w[1] / w[2]
                out[f'{n}_err_rms_rel_last1s'] = float(np.sqrt(np.mean(rel ** 2)))
                out[f'{n}_err_ptp_rel_last1s'] = float(np.ptp(w[1]) / abs(np.mean(w[2])))
        return out


_SIGNAL_KEYS = sorted({k for _m, _r, keys, _f in TRACKING for k in keys}
                      | {'theta_r', 'omega_r', 'tau_m', 'phi_r_beta', 'phi_ref_beta',
                         'phi_hat_beta', 'v_beta', 'v_cmd_beta', 'i_beta'})


def build_trace(raw: Dict[str, List[bytes]]) -> Tuple[Dict[str, np.ndarray], Dict[str, dict]]:
    """Trace arrays from raw payloads grouped by topic; also the per-topic decoded series."""
    series = {}
    for topic, payloads in raw.items():
        dec = decode_topic(topic, payloads)
        if dec is not None:
            series[topic] = {'t_ns': dec[0], **dec[1]}
    keeper = TraceKeeper()
    stream = TraceStream([keeper])
    for topic, payloads in raw.items():
        stream.pending[topic] = list(payloads)
    stream.flush(final=True)
    return keeper.trace(), series


def truth_final_from(series: Dict[str, dict]) -> Dict[str, float]:
    """Return the energy books over the recorded window (see module doc)."""
    out: Dict[str, float] = {}
    en = series.get(T.TRUTH_ENERGY)
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
                                       - out['dW_mag'] - out['dE_kin']
                                       - out.get(T.IRON_LOSS_NAME, 0.0))   # an acting core loss
        out['t_final'] = ns_to_s(float(en['t_ns'][last]))
    par = series.get(T.TRUTH_PARAMS)
    if par is not None and len(par['t_ns']):
        last = int(np.argmax(par['t_ns']))
        for k, v in par.items():
            if k != 't_ns':
                out[k] = float(v[last])
    return out


class RunEvents:
    """
    The /im/status events that end a node's part of the run.

    ``finished``, ``stopped``, ``failed`` — as dicts (node, state, t [s], reason, time_master),
    in recorded order: how the run ended, whoever recorded it (the in-process graph's tap or
    the recorder node).
    """

    ENDS = ('finished', 'stopped', 'failed')

    def __init__(self):
        self.events: List[dict] = []
        self.undecodable = 0

    def add(self, data: bytes) -> None:
        from diagnostic_msgs.msg import DiagnosticArray  # heavy: ROS messages, /im/status only
        try:
            msg, _ = cdr.decode_generic(DiagnosticArray, data)
        except cdr.CdrError:
            self.undecodable += 1
            return
        stamp = msg['header']['stamp']
        for st in msg['status']:
            if st['message'] not in self.ENDS:
                continue
            values = {kv['key']: kv['value'] for kv in st['values']}
            e = {'node': st['name'], 'state': st['message'],
                 't': stamp['sec'] + ns_to_s(stamp['nanosec']),
                 'reason': values.get('reason', ''),
                 'time_master': values.get('time_master') == 'true'}
            # the plant's count of commands not signed by its graph, and who sent them
            if values.get('unsigned_commands'):
                e['unsigned_commands'] = int(values['unsigned_commands'])
                e['foreign_publishers'] = values.get('foreign_publishers', '').split()
            self.events.append(e)


def lockstep_topics() -> Tuple[str, ...]:
    """Return the topics every control instant must have (``critical`` rows of the topic table)."""
    return tuple(t.name for t in T.TOPICS if t.critical)


def load_step_time(metadata: Optional[dict] = None,
                   parameters: Optional[dict] = None) -> Optional[float]:
    """
    Return when a speed run's load steps [s], None if it does not (or it is not a speed run).

    From a recording's ``run`` record (``metadata``) or from the nodes' ``parameters`` (the
    plant's ``load`` and ``load_<field>``, the controller's ``mode``).
    """
    if parameters is not None:
        if parameters.get('controller', {}).get('mode') != 'speed':
            return None
        return load_from_parameters(parameters.get('plant', {})).change_time()
    text = (metadata or {}).get('run', {}).get('yaml')
    if not text:
        return None
    record = yaml.safe_load(text)
    if not isinstance(record, dict) or record.get('task') != 'speed' \
            or not isinstance(record.get('load'), dict):
        return None
    return load_from_dict(record['load'], source='run record: load').change_time()


def stream_run(messages, path: str, metadata: dict, trace: Optional[str] = 'full',
               limit: int = 10000, types: Optional[dict] = None) -> RecordedRun:
    """
    Analyse a run from its ``(topic, payload)`` pairs.

    Return a :class:`RecordedRun` from ``(topic, payload)`` pairs in stamp order, in bounded
    memory unless ``trace='full'`` (every row kept); ``'decimated'`` keeps about
    ``limit``-``2·limit`` rows for the plots, None none. The figures always cover every control
    instant.
    """
    books = TruthBooks()
    figs = RunningFigures(lockstep_topics=lockstep_topics(),
                          load_step=load_step_time(metadata=metadata))
    sinks = [books, figs]
    keeper = None
    if trace is not None:
        keeper = TraceKeeper(None if trace == 'full' else limit)
        sinks.append(keeper)
    stream = TraceStream(sinks)
    events = RunEvents()
    for topic, data in messages:
        if topic == T.STATUS:
            events.add(data)
        stream.add(topic, data)
    stream.flush(final=True)
    tr = keeper.trace() if keeper is not None else {}
    return RecordedRun(str(path), tr, books.final(), metadata, dict(stream.counts),
                       dict(types or {}), running=figs, late=stream.late, events=events.events)


def load_run(path, trace: Optional[str] = 'full', limit: int = 10000) -> RecordedRun:
    """
    Read a recording into a :class:`RecordedRun`; :class:`~im_recording.bag.BagError` if not.

    ``trace``: 'full' (every control instant), 'decimated' (about ``limit`` rows, what the
    report's plots need) or None; the figures cover the whole run either way. Every CRC is
    checked (data section, chunks, summary).
    """
    bi = info(path)
    check_data_crc(path)
    wanted = [t for t in bi.topics if t in TRACE_TOPICS or t == T.STATUS]
    meta = {k: v for k, v in bi.metadata.items() if k != 'rosbag2'}
    try:
        run = stream_run(((topic, data) for topic, _tn, _t, data in iter_raw(path, wanted)),
                         str(path), meta, trace, limit, bi.topics)
    except cdr.CdrError as exc:
        raise BagError(path, f'undecodable message: {exc}') from None
    run.counts = dict(bi.counts)
    return run
