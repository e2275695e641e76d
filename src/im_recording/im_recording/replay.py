"""
Replay a recording, or re-run the observer on it.

Publishing::

    ros2 run im_recording replay bags/run.mcap [--rate X | --lockstep] [--topics T ...]
                                             [--remap /old:=/new ...] [--no-clock]

publishes the recorded topics (the recorded bytes, so the original header stamps) and drives
``/clock`` from the recording: one Clock message at each new stamp, before that stamp's messages
(a recorded ``/clock`` topic is not republished twice). Pacing: ``--rate X`` plays X times the
recorded speed (1 = real time) against the wall clock; ``--lockstep`` plays as fast as the
subscribers keep up — after each stamp it waits until every reliable subscriber acknowledged
(``Publisher.wait_for_all_acked``). Publishers use the recorded offered QoS (reliability,
durability, depth).

Re-estimation (no ROS graph needed)::

    ros2 run im_recording replay bags/run.mcap --reestimate --out bags/run_reest.mcap
        [--k-e K] [--param R_r=0.9 ...] [--use-adapter] [--force]

feeds the recorded measured current (/im/measured/current), command voltage
(/im/command/voltage) and speed (/im/measured/shaft) into a fresh
:class:`im_observer.observer.RotorFluxObserver`, stepped as in the live graph: at step k it uses
V_k, i_k, ω_k (and, with ``--use-adapter``, the estimates stamped t_k) and produces x̂_{k+1},
stamped t_{k+1}. The new file holds every recorded message plus
``/im/reestimate/observer/flux`` and ``/im/reestimate/observer/current``. Observer parameters are
taken from the recording's ``parameters/observer`` metadata when present, then the command line.
"""
from __future__ import annotations

import argparse
import ast
from dataclasses import fields
import heapq
import math
import sys
import time
from typing import Dict, List, Optional, Sequence, Tuple

from im_common import cdr
from im_common.cli import error as cli_error, parse_args
from im_common.conversions import NS_PER_S, ns_to_s
from im_common.params import estimate_arguments, MotorParams
from im_common.stopping import StopSignals
from im_common.topics import ADAPT_ESTIMATE, CLOCK, CMD_VOLTAGE, MEAS_CURRENT, MEAS_SHAFT
from im_observer.observer import RotorFluxObserver
import numpy as np
import yaml

from .bag import BagError, BagWriter, check_data_crc, check_output, info, iter_raw
from .recorded_run import REEST_CURRENT, REEST_FLUX


# ------------------------------------------------------------------------------------------
# Re-estimation
# ------------------------------------------------------------------------------------------
def _lit(text: str):
    try:
        return ast.literal_eval(text)
    except (ValueError, SyntaxError):
        return text


def observer_config(metadata: Dict[str, Dict[str, str]],
                    overrides: Optional[Dict[str, float]] = None) -> dict:
    """Observer settings: recorded ``parameters/observer`` metadata, then ``overrides``."""
    rec = {k: _lit(v) for k, v in metadata.get('parameters/observer', {}).items()}
    rec.update(overrides or {})
    names = {f.name for f in fields(MotorParams)}
    motor = {k: (int(v) if k == 'pole_pairs' else float(v)) for k, v in rec.items() if k in names}
    gain = rec.get('injection_gain')
    gain = list(gain) if isinstance(gain, (list, tuple)) and len(gain) == 8 else None
    return {
        'params': MotorParams(**motor),
        'k_e': float(rec.get('k_e_injection', 0.0)) or None,
        'max_substep': float(rec.get('max_substep', 1e-4)),
        'injection_gain': gain,
        'gain_period': float(rec.get('gain_period', 0.0)) or None,
        'use_adapter': bool(rec.get('use_adapter', False)),
        'x0': tuple(rec.get('x0', (0.0, 0.0, 0.0, 0.0))),
    }


def _series(path) -> Dict[str, Dict[int, tuple]]:
    want = [MEAS_CURRENT, MEAS_SHAFT, CMD_VOLTAGE, ADAPT_ESTIMATE]
    present = [t for t in want if t in info(path).topics]
    out: Dict[str, Dict[int, tuple]] = {t: {} for t in want}
    for topic, tname, _t, data in iter_raw(path, present):
        if topic == MEAS_SHAFT:
            sec, ns, _names, pos, vel, _eff = cdr.decode_joint_state(data)
            if vel:
                out[topic][sec * NS_PER_S + ns] = (vel[0],)
        elif topic == ADAPT_ESTIMATE:
            sec, ns, names, pos, _v, _e = cdr.decode_joint_state(data)
            out[topic][sec * NS_PER_S + ns] = dict(zip(names, pos))
        else:
            sec, ns, x, y, _z = cdr.decode_vector3_stamped(data)
            out[topic][sec * NS_PER_S + ns] = (x, y)
    return out


def reestimate_series(path, config: dict, stop=None
                      ) -> List[Tuple[int, Tuple[float, float, float, float]]]:
    """
    Re-run the observer on the recorded inputs.

    [(t_{k+1} ns, (î_α, î_β, φ̂_α, φ̂_β))] from the recorded inputs of every step k (up to the step
    at which ``stop()`` turned true, if given).
    """
    s = _series(path)
    steps = sorted(set(s[MEAS_CURRENT]) & set(s[MEAS_SHAFT]) & set(s[CMD_VOLTAGE]))
    if not steps:
        raise BagError(path, 'nothing to re-estimate: needs /im/measured/current, '
                       '/im/measured/shaft and /im/command/voltage at common stamps')
    kw = {k: config[k] for k in ('k_e', 'max_substep', 'injection_gain', 'gain_period', 'x0')}
    obs = RotorFluxObserver(config['params'], **kw)
    grid = sorted(s[MEAS_CURRENT])
    nxt = dict(zip(grid, grid[1:]))
    period = int(np.median(np.diff(grid))) if len(grid) > 1 else None
    out = []
    for t in steps:
        t1 = nxt.get(t, t + period if period else None)
        if t1 is None or (stop is not None and stop()):
            break
        if config.get('use_adapter'):
            est = s[ADAPT_ESTIMATE].get(t)
            if est is None:
                raise BagError(path, f'--use-adapter: no /im/adapter/estimate stamped {t} ns')
            obs.set_estimates(**estimate_arguments(est))
        va, vb = s[CMD_VOLTAGE][t]
        ia, ib = s[MEAS_CURRENT][t]
        (w,) = s[MEAS_SHAFT][t]
        x = obs.step(ns_to_s(t1 - t), va, vb, ia, ib, w)
        out.append((t1, tuple(x)))
    return out


def reestimate(path, out_path, overrides: Optional[Dict[str, float]] = None,
               use_adapter: Optional[bool] = None, force: bool = False, stop=None) -> dict:
    """
    Write ``out_path``: every message of ``path`` plus the re-estimated observer outputs.

    ``out_path`` is never ``path`` (FileExistsError, even with ``force``); an existing file only
    with ``force``. ``stop()`` (e.g. a :class:`im_common.stopping.StopSignals` flag) ends the
    work early: the file is then closed complete up to the last finished step, and
    ``'interrupted'`` in the result is True.
    """
    check_output(out_path, [path], force, what='--out file')
    bi = info(path)
    check_data_crc(path)    # the observer's parameters are a record of the data section
    cfg = observer_config(bi.metadata, overrides)
    if use_adapter is not None:
        cfg['use_adapter'] = use_adapter
    est = reestimate_series(path, cfg, stop)
    new = []
    for t, (ia, ib, pa, pb) in est:
        s_, ns = divmod(t, NS_PER_S)
        new.append((t, 1, REEST_FLUX, cdr.pack_vector3_stamped(s_, ns, pa, pb, 0.0)))
        new.append((t, 2, REEST_CURRENT, cdr.pack_vector3_stamped(s_, ns, ia, ib, 0.0)))
    md = {k: v for k, v in bi.metadata.items() if k != 'rosbag2'}
    md['reestimate'] = {'source': str(path), 'k_e': repr(cfg['k_e']),
                        'max_substep': repr(cfg['max_substep']),
                        'use_adapter': repr(cfg['use_adapter']),
                        **{f'param/{f.name}': repr(getattr(cfg['params'], f.name))
                           for f in fields(cfg['params'])}}
    old = ((t, 0, topic, data) for topic, _tn, t, data in iter_raw(path))
    n = 0
    check = stop
    if stop is not None and stop():     # interrupted while estimating: up to that step only
        last = est[-1][0] if est else -1
        old = (e for e in old if e[0] <= last)
        check = None
    # the output keeps the input's log times (its log_time record and offset; stamps as read)
    with BagWriter(out_path, force=force, metadata=md,
                   log_time_offset_ns=bi.log_time_offset) as w:
        for topic, tname in bi.topics.items():
            meta = next((m for (tp, _, m) in bi.channels.values() if tp == topic), {})
            w.add_topic(topic, tname, qos=meta.get('offered_qos_profiles'))
        w.add_topic(REEST_FLUX, 'geometry_msgs/msg/Vector3Stamped')
        w.add_topic(REEST_CURRENT, 'geometry_msgs/msg/Vector3Stamped')
        t_prev = None
        for t, _o, topic, data in heapq.merge(old, new, key=lambda e: (e[0], e[1])):
            if t != t_prev and check is not None and check():
                break               # a signal while writing: end after the last complete stamp
            w.write_serialized(topic, data, t)
            t_prev = t
            n += 1
    return {'input': str(path), 'output': str(out_path), 'steps': len(est), 'messages': n,
            'interrupted': bool(stop is not None and stop())}


# ------------------------------------------------------------------------------------------
# Publishing
# ------------------------------------------------------------------------------------------
def _qos_from_yaml(text: Optional[str], topic: str = '?'):
    """
    Return the recorded offered QoS of ``topic``.

    A record without one gets reliable/volatile, a record that does not parse is a ValueError
    naming the topic (never a silent default).
    """
    # heavy: rclpy, only for publishing (--reestimate needs no ROS)
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
    rel, dur, depth = ReliabilityPolicy.RELIABLE, DurabilityPolicy.VOLATILE, 100
    try:
        prof = (yaml.safe_load(text) or [{}])[0] if text else {}
        r = str(prof.get('reliability', 'reliable')).lower()
        d = str(prof.get('durability', 'volatile')).lower()
        depth = max(int(prof.get('depth', 100) or 100), 100)
    except (yaml.YAMLError, AttributeError, TypeError, ValueError, IndexError, KeyError) as exc:
        raise ValueError(f'{topic}: recorded offered_qos_profiles does not parse '
                         f'({type(exc).__name__}: {exc})') from None
    rel = ReliabilityPolicy.BEST_EFFORT if r in ('best_effort', '2') else rel
    dur = DurabilityPolicy.TRANSIENT_LOCAL if d in ('transient_local', '1') else dur
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth, reliability=rel,
                      durability=dur)


def parse_remaps(items: Optional[Sequence[str]]) -> Dict[str, str]:
    out = {}
    for it in items or ():
        if ':=' not in it:
            raise ValueError(f'--remap takes /old:=/new, not {it!r}')
        a, b = it.split(':=', 1)
        out[a] = b
    return out


class Player:
    """Publishes a recording on ``node``; ``play()`` returns the number of messages sent."""

    def __init__(self, node, path, topics: Optional[Sequence[str]] = None,
                 remap: Optional[Dict[str, str]] = None, rate: float = 1.0,
                 lockstep: bool = False, clock: bool = True, ack_timeout: float = 5.0):
        from rosgraph_msgs.msg import Clock     # heavy: ROS messages, only for publishing
        self.node, self.path = node, path
        self.rate, self.lockstep, self.clock = float(rate), lockstep, clock
        self.ack_timeout = ack_timeout
        self.published = 0          # messages sent so far by play()
        bi = info(path)
        sel = list(bi.topics) if not topics else list(topics)
        missing = [t for t in sel if t not in bi.topics]
        if missing:
            raise BagError(path, f'topic(s) not in the recording: {missing}')
        if clock and CLOCK in sel:
            sel.remove(CLOCK)      # /clock is driven from the stamps
        self.topics = sel
        remap = remap or {}
        qos = {tp: m.get('offered_qos_profiles') for tp, _, m in bi.channels.values()}
        self.pubs = {}
        for tp in sel:
            cls = cdr.message_class(bi.topics[tp])
            self.pubs[tp] = node.create_publisher(cls, remap.get(tp, tp),
                                                  _qos_from_yaml(qos[tp], tp))
        self.clock_pub = node.create_publisher(Clock, remap.get(CLOCK, CLOCK), 10) if clock \
            else None

    def wait_for_subscribers(self, count: int = 1, timeout: float = 10.0, spin=None) -> bool:
        t_end = time.monotonic() + timeout
        while time.monotonic() < t_end:
            if all(p.get_subscription_count() >= count for p in self.pubs.values()):
                return True
            if spin:
                spin()
            else:
                time.sleep(0.01)
        return False

    def _ack(self):
        from rclpy.duration import Duration     # heavy: rclpy, only for publishing
        for p in self.pubs.values():
            if p.get_subscription_count():
                p.wait_for_all_acked(Duration(seconds=self.ack_timeout))

    def play(self, spin=None) -> int:
        self.published = n = 0
        t0 = None
        wall0 = time.monotonic()
        last = None
        for topic, _tn, t, data in iter_raw(self.path, self.topics):
            if t != last:
                if last is not None and self.lockstep:
                    self._ack()
                if self.clock_pub is not None:
                    self.clock_pub.publish(cdr.pack_clock(*divmod(t, NS_PER_S)))
                last = t
                if t0 is None:
                    t0 = t
                if not self.lockstep and self.rate > 0:
                    delay = wall0 + ns_to_s(t - t0) / self.rate - time.monotonic()
                    if delay > 0:
                        time.sleep(delay)
                if spin:
                    spin()
            self.pubs[topic].publish(data)
            n += 1
            self.published = n
        if self.lockstep:
            self._ack()
        return n


def main(argv=None) -> int:
    full = list(sys.argv if argv is None else ['replay'] + list(argv))    # rclpy.init's args
    ap = argparse.ArgumentParser(prog='replay', description='Replay a recording (or re-run the '
                                 'observer on it with --reestimate).')
    ap.add_argument('bag')
    g = ap.add_mutually_exclusive_group()
    g.add_argument('--rate', type=float, default=1.0, help='multiple of the recorded speed')
    g.add_argument('--lockstep', action='store_true',
                   help='as fast as the subscribers acknowledge each stamp')
    ap.add_argument('--topics', nargs='+', default=None)
    ap.add_argument('--remap', nargs='+', default=None, metavar='/OLD:=/NEW')
    ap.add_argument('--no-clock', action='store_true', help='do not publish /clock')
    ap.add_argument('--wait-subscribers', type=float, default=2.0,
                    help='seconds to wait for subscribers before playing')
    ap.add_argument('--reestimate', action='store_true', help='re-run the observer offline')
    ap.add_argument('--out', '-o', default=None, help='output of --reestimate')
    ap.add_argument('--force', action='store_true')
    ap.add_argument('--k-e', type=float, default=None, help='observer injection gain k_e')
    ap.add_argument('--param', nargs='+', default=None, metavar='NAME=VALUE',
                    help='observer model parameters (R_s, R_r, L_s, L_r, L_sr, pole_pairs, ...)')
    ap.add_argument('--use-adapter', action='store_true', default=None,
                    help='apply the recorded /im/adapter/estimate at each step')
    a = parse_args(ap, full[1:])
    try:
        if a.reestimate:
            over: Dict[str, float] = {}
            for it in a.param or ():
                k, _, v = it.partition('=')
                over[k] = float(v)
            if a.k_e is not None:
                over['k_e_injection'] = a.k_e
            out = a.out or a.bag.rsplit('.mcap', 1)[0] + '_reest.mcap'
            with StopSignals() as sig:
                r = reestimate(a.bag, out, over, a.use_adapter, a.force,
                               stop=lambda: sig.requested is not None)
            print(f"replay: re-estimated {r['steps']} steps; {r['messages']} messages "
                  f"written to {r['output']}")
            if r['interrupted']:
                print(f'replay: interrupted by {sig.requested}; {r["output"]} is complete up to '
                      'the last finished step', file=sys.stderr)
            return sig.exit_code
        if a.rate is not None and not (a.rate > 0 and math.isfinite(a.rate)):
            raise ValueError(f'--rate must be > 0, not {a.rate}')
        return _play(a, full)
    except (BagError, FileExistsError, ValueError, OSError) as exc:
        return cli_error('replay', exc)


def _play(a, full) -> int:
    # heavy: rclpy, only for publishing (--reestimate needs no ROS)
    import rclpy
    from rclpy.executors import ExternalShutdownException
    from rclpy.node import Node
    remap = parse_remaps(a.remap)
    info(a.bag)   # fail with BagError before starting ROS
    rclpy.init(args=full)
    node = player = None
    n = 0
    try:
        node = Node('replay')
        player = Player(node, a.bag, a.topics, remap, rate=a.rate, lockstep=a.lockstep,
                        clock=not a.no_clock)
        player.wait_for_subscribers(timeout=a.wait_subscribers)
        n = player.play()
    except (KeyboardInterrupt, ExternalShutdownException):
        n = player.published if player is not None else 0
    except BagError as exc:     # damage found while playing: one line, with what was sent
        n = player.published if player is not None else 0
        raise BagError(exc.path, f'{exc.problem} (after {n} messages published)') from None
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    print(f'replay: {n} messages published from {a.bag}', file=sys.stderr)
    return 0


if __name__ == '__main__':
    sys.exit(main())
