"""
A 2-minute duty on the ROS-free loop with a shipped motor's thermal block (docs/plant.md §4).

The speed task (the thesis's speed profile, ending at 180 rad/s) on a shipped motor file with
its own ``thermal`` block, a constant load and the controller's current limit at a multiple of
the rated current, for ``--duration`` simulated seconds; prints the windings' temperature rises
next to the first-order closed form at the run's mean losses, R_th P̄ (1 − e^{−t/τ}).

    python tools/thermal_duty.py thesis --load 16 --current-factor 2
"""
from __future__ import annotations

import argparse
import json
import math
import os

from im_bringup import offline
from im_bringup.run_file import Scenario
from im_common.params import load_motor_blocks, load_motor_file, shipped_motors_dir
from im_common.thermal import thermal_from_dict


def run(motor: str, load: float, current_factor: float, strategy: str,
        duration: float) -> dict:
    """Run the duty; return the temperatures, mean losses and the closed form's rises."""
    path = os.path.join(shipped_motors_dir(), f'{motor}.yaml')
    params = load_motor_file(path)
    th = thermal_from_dict(load_motor_blocks(path)['thermal'])
    sc = Scenario.from_mapping({'task': 'speed', 'strategy': strategy, 'motor': path,
                                'thermal': 'motor', 'duration': duration,
                                'load': {'kind': 'constant', 'tau': load},
                                'current_limit': current_factor * params.rated_current})
    held = {}
    build = offline.build

    def keep(scenario):
        out = build(scenario)
        held['plant'] = out[0]
        return out

    offline.build = keep
    try:
        res = offline.simulate(sc, record_every=1000)
    finally:
        offline.build = build
    tr = held['plant'].truth()
    t = sc.duration
    p_r = tr['E_cu_r'] / t
    p_s = tr['E_cu_s'] / t
    return {'motor': motor, 'strategy': strategy, 'load_Nm': load,
            'rated_torque_Nm': params.rated_torque, 'duration_s': t,
            'current_A': math.hypot(tr['i_alpha'], tr['i_beta']),
            'rated_current_A': params.rated_current, 'omega_rad_s': tr['omega_r'],
            'rotor_loss_mean_W': p_r, 'stator_loss_mean_W': p_s,
            'dT_rotor_K': tr['T_rotor'] - th.T_ambient,
            'dT_stator_K': tr['T_stator'] - th.T_ambient,
            'dT_rotor_closed_form_K': th.R_th_r * p_r * (1.0 - math.exp(-t / th.tau_r)),
            'dT_stator_closed_form_K': th.R_th_s * p_s * (1.0 - math.exp(-t / th.tau_s)),
            'trip': res.summary.get('trip')}


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('motor', help='a shipped motor file: thesis or krause_3hp')
    ap.add_argument('--load', type=float, required=True, help='constant load torque [N m]')
    ap.add_argument('--current-factor', type=float, default=2.0,
                    help='the controller current limit over the rated current')
    ap.add_argument('--strategy', default='min_energy', help='flux strategy')
    ap.add_argument('--duration', type=float, default=120.0, help='simulated seconds')
    a = ap.parse_args(argv)
    print(json.dumps(run(a.motor, a.load, a.current_factor, a.strategy, a.duration), indent=1))


if __name__ == '__main__':
    main()
