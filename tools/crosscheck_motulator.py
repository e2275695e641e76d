"""
Cross-check the real plant's switched inverter against motulator 0.18 (docs/plant.md §8).

motulator needs Python >= 3.12 and the project runs on 3.11, so this runs from a scratch
environment outside the repository; the project's plant (pure Python) is imported from src/::

    python3.12 -m venv ../mot-env && ../mot-env/bin/pip install 'motulator==0.18.*'
    ../mot-env/bin/python tools/crosscheck_motulator.py [--duration 0.2] [--json out.json]

The same motor (the thesis motor, unsaturated: motulator saturates the Γ model's L_s(|ψ_s|),
this plant the inverse-Γ L_M(|ψ_R|), so the saturated models are not the same machine), the same
shaft speed (held), the same duty sequence (an open-loop rotating command turned into duties by
:func:`im_common.inverter.duties`, min-max zero sequence), carrier comparison at 5 kHz with single
update (T_s = 200 µs), the same dead time and on-state (threshold) drop, no computational delay.
motulator's counter quantization of the duties is switched off (N = 2^40; ``--counter-bits 12``
puts back its default 2^12) and its solver tolerances tightened (rtol 1e-10, atol 1e-12), so what
is left is the two integrators' error. motulator's space
vectors are peak-value scaled; this plant's are power-invariant (×√(3/2)).

Printed: the relative RMS difference of the stator current and the stator flux over the run,
sampled at every period start (the carrier peak), and the wall time of both simulations.
"""
from __future__ import annotations

import argparse
import math
import os
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))   # tools/: motulator_common
from motulator_common import K, rel_rms, write_json  # noqa: E402


def command(k: int, T_s: float, V: float, f: float):
    """Return the open-loop command of period k: V e^{j 2π f t_k} (power-invariant, V)."""
    a = 2.0 * math.pi * f * k * T_s
    return V * math.cos(a), V * math.sin(a)


def run_ours(motor, n: int, T_s: float, V_dc: float, t_d: float, v_on: float, w_m: float,
             V: float, f: float):
    from im_plant.plant_sim import PlantSimulator
    sim = PlantSimulator(motor, None, T_s=T_s, omega0=w_m, v_limit=None,
                         inverter={'V_dc': V_dc, 'pwm_frequency': 1.0 / T_s, 'deadtime': t_d,
                                   'v_on': v_on})
    out = []
    t0 = time.perf_counter()
    for k in range(n):
        i_a, i_b, _, _ = sim.state_currents()
        out.append((i_a, i_b, sim.x[0], sim.x[1]))
        sim.step(*command(k, T_s, V, f))
    return out, time.perf_counter() - t0


def run_motulator(motor, n: int, T_s: float, V_dc: float, t_d: float, v_on: float, w_m: float,
                  V: float, f: float, counter_bits: int = 40):
    import motulator.drive.model as model
    from motulator.common.model import Simulation, SolverCfg
    from im_common.inverter import duties

    par = model.InductionMachineInvGammaPars(n_p=motor.pole_pairs, R_s=motor.R_s, R_R=motor.R_R,
                                             L_sgm=motor.L_sigma, L_M=motor.L_M)
    machine = model.InductionMachine(par)
    mech = model.ExternalRotorSpeed()
    mech.set_external_rotor_speed(w_m)
    conv = model.VoltageSourceConverter(u_dc=V_dc, t_d=t_d, u_th=v_on)
    mdl = model.Drive(machine, mech, conv, pwm=True, delay=0, single_update=True)
    mdl.pwm.N = 2 ** counter_bits           # 40: no counter quantization of the instants
    samples = []

    class OpenLoop:
        """The duty sequence, and the samples at each period start (the carrier's peak)."""

        def __init__(self):
            self.t = 0.0
            self.k = 0

        def get_enable(self):
            return True

        def __call__(self, m):
            st = m.machine.state
            i_s = m.machine.out.i_s_ab
            samples.append((K * i_s.real, K * i_s.imag, K * st.psi_s_ab.real,
                            K * st.psi_s_ab.imag))
            d, _ = duties(*command(self.k, T_s, V, f), V_dc)
            self.k += 1
            self.t += T_s
            return T_s, list(d)

        def post_process(self):
            return None

    sim = Simulation(mdl, OpenLoop(), show_progress=False,
                     cfg=SolverCfg(rtol=1e-10, atol=1e-12))
    t0 = time.perf_counter()
    sim.simulate(t_stop=(n - 1) * T_s - 1e-9)
    return samples[:n], time.perf_counter() - t0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[1])
    ap.add_argument('--duration', type=float, default=0.2, help='simulated time [s]')
    ap.add_argument('--pwm-frequency', type=float, default=5000.0, help='[Hz], single update')
    ap.add_argument('--deadtime', type=float, default=2e-6, help='[s]')
    ap.add_argument('--v-on', type=float, default=1.0, help='on-state (threshold) drop [V]')
    ap.add_argument('--counter-bits', type=int, default=40,
                    help="motulator's PWM counter resolution (its default is 12)")
    ap.add_argument('--json', default=None, help='write the numbers here')
    args = ap.parse_args(argv)
    from im_common.params import THESIS_MOTOR
    motor = THESIS_MOTOR.with_values(b=0.0, J=1e9)     # the speed held, as motulator's
    T_s = 1.0 / args.pwm_frequency
    n = int(round(args.duration / T_s))
    case = {'n': n, 'T_s': T_s, 'V_dc': 400.0, 't_d': args.deadtime, 'v_on': args.v_on,
            'w_m': 80.0, 'V': 120.0, 'f': 30.0}
    ours, t_ours = run_ours(motor, **case)
    theirs, t_mot = run_motulator(motor, counter_bits=args.counter_bits, **case)
    res = {'duration_s': args.duration, 'pwm_frequency_hz': args.pwm_frequency,
           'deadtime_s': args.deadtime, 'v_on_V': args.v_on, 'periods': n,
           'counter_bits': args.counter_bits,
           'stator_current_rel_rms': rel_rms(ours, theirs, (0, 1)),
           'stator_flux_rel_rms': rel_rms(ours, theirs, (2, 3)),
           'wall_s_ours': t_ours, 'wall_s_motulator': t_mot,
           'motulator_over_ours_wall': t_mot / t_ours}
    for k, v in res.items():
        print(f'{k:28s} {v:.6g}' if isinstance(v, float) else f'{k:28s} {v}')
    write_json(args.json, res)
    return 0


if __name__ == '__main__':
    sys.exit(main())
