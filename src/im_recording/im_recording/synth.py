"""
A small synthetic recording, for tests and demos of the bag tools without the ROS graph.

:func:`make_synthetic_bag` drives :class:`im_plant.plant_sim.PlantSimulator` open loop with a
rotating stator-voltage vector (v_α, v_β) = V (cos 2πft, sin 2πft) and records every step the
way the live graph stamps it: measurements, command and truth at t_k; if an observer is given
(an object with ``step(T_s, v_a, v_b, i_a, i_b, omega) -> (i_a, i_b, phi_a, phi_b)``), its
prediction x̂_{k+1} stamped t_{k+1}. Returns the plant's final ``truth()`` for checking.
"""
from __future__ import annotations

import math
from typing import Optional

from im_common import topics as T
from im_common.cdr import pack_clock
from im_common.conversions import NS_PER_S
from im_common.loads import ConstantLoad
from im_plant.plant_sim import PlantSimulator

from .bag import BagWriter

SEC = NS_PER_S


def truth_params(tr: dict) -> list:
    th = tr['L_sr'] / tr['L_r']
    return [tr['R_s'], tr['R_r'], tr['L_s'], tr['L_r'], tr['L_sr'], th, tr['L_sr'] * th,
            tr['R_r'] * th * th]


def make_synthetic_bag(path, steps: int = 400, T_s: float = 1e-3, V: float = 60.0,
                       f: float = 20.0, observer=None, metadata: Optional[dict] = None,
                       force: bool = False, load_tau: float = 0.5,
                       chunk_size: Optional[int] = None):
    plant = PlantSimulator(T_s=T_s, load=ConstantLoad(load_tau))
    dt_ns = int(round(T_s * SEC))
    md = {'scenario': {'task': 'speed', 'strategy': 'open_loop', 'T_s': repr(T_s),
                       'V': repr(V), 'f': repr(f)}}
    md.update(metadata or {})
    w = BagWriter(path, force=force, metadata=md,
                  **({} if chunk_size is None else {'chunk_size': chunk_size}))
    try:
        for k in range(steps + 1):
            t = k * dt_ns
            tk = k * T_s
            m = plant.measure()
            tr = plant.truth()
            va, vb = V * math.cos(2 * math.pi * f * tk), V * math.sin(2 * math.pi * f * tk)
            w.write_serialized(T.CLOCK, _clock(t), t)
            w.write_vector3(T.MEAS_CURRENT, t, m.i_alpha, m.i_beta)
            w.write_joint_state(T.MEAS_SHAFT, t, ('rotor',), (m.theta_r,), (m.omega_r,))
            w.write_joint_state(T.REF_SHAFT, t, ('rotor',), (0.0,), (2 * math.pi * f / 2,),
                                (0.0,))
            w.write_vector3(T.TRUTH_FLUX, t, tr['phi_r_alpha'], tr['phi_r_beta'])
            w.write_vector3(T.TRUTH_TORQUE, t, tr['tau_m'], tr['tau_L'],
                            plant.params.b * tr['omega_r'])
            w.write_joint_state(T.TRUTH_PARAMS, t, T.PARAM_NAMES, truth_params(tr))
            w.write_joint_state(T.TRUTH_POWER, t, T.POWER_NAMES, [tr[n] for n in T.POWER_NAMES])
            w.write_joint_state(T.TRUTH_ENERGY, t, T.ENERGY_NAMES,
                                [tr[n] for n in T.ENERGY_NAMES])
            if k == steps:
                break
            w.write_vector3(T.CMD_VOLTAGE, t, va, vb)
            plant.step(va, vb)
            w.write_vector3(T.TRUTH_VOLTAGE, t, *plant.v_applied)
            if observer is not None:
                ia, ib, pa, pb = observer.step(T_s, va, vb, m.i_alpha, m.i_beta, m.omega_r)
                w.write_vector3(T.OBS_FLUX, t + dt_ns, pa, pb)
                w.write_vector3(T.OBS_CURRENT, t + dt_ns, ia, ib)
    finally:
        w.close()
    return plant.truth()


def _clock(t_ns: int) -> bytes:
    return pack_clock(*divmod(t_ns, SEC))
