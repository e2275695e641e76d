"""
The real plant: what :class:`im_common.plant_sim.PlantSimulator` does when a block is on.

A :class:`PlantSimulator` given any of ``inverter``, ``saturation``, ``thermal``, ``sensors`` or
``iron_loss`` builds one :class:`RealPlant`, which replaces the simulator's ``step``,
``state_currents``, ``measure`` and ``truth`` on that instance; the ideal plant (every block
absent) never reaches this module, so its path and its numbers are unchanged.

Per control period (docs/plant.md):

1. the command passes the ideal plant's limit and rating checks, then (with an inverter) the
   carrier comparison of :mod:`im_common.inverter` computes the period's switching instants once,
   at its start;
2. between consecutive instants the pole voltages are constant: the interval is integrated with
   RK4 (:meth:`im_common.model.RealMotorModel.rk4`), one step per interval, at most
   ``max_substep`` long — a bounded number per period, no zero-crossing search. The dead bands
   are resolved by the phase currents' signs at the period's start; if a current's sign at any
   interval boundary differs, the period is integrated again with explicit dead bands, each
   taking the sign of its leg's current at the band's start;
3. after the period: the winding temperatures (exact first-order step, :mod:`im_common.thermal`),
   the DC link (energy form), the encoder's count and the protection.
"""
from __future__ import annotations

import math
from typing import Mapping

from .inverter import (check_against_motor, duties, Inverter, inverter_from_dict, period_plan,
                       phase_values)
from .model import E_CORE, E_CU_R, E_CU_S, E_IN, E_INV, RealMotorModel
from .params import clarke
from .saturation import Saturation, saturation_from_dict
from .sensors import Measurement, Sensors, sensors_from_dict, SpeedFromCounts
from .thermal import first_order, Thermal, thermal_from_dict

TWO_PI = 2.0 * math.pi
#: RK4 steps per switching interval for the saturated (nonlinear) model: one is enough on
#: intervals of at most T_s (a 0.5 s DOL start through the inverter with the shipped curve: the
#: state within 1.4e-8 relative of eight steps per interval; docs/plant.md §1)
SATURATED_SUBSTEPS = 1


#: the pole state a dead band gives by the current's sign: the lower diode for i > 0, the upper
#: for i < 0, and with no current (neither conducts) the middle of the rails
_DIODE = {1.0: 0, -1.0: 1, 0.0: 0.5}


def _sgn(x: float) -> float:
    return 1.0 if x > 0.0 else (-1.0 if x < 0.0 else 0.0)


class RealPlant:
    """The real plant's blocks and state beside a :class:`PlantSimulator` (module doc)."""

    def __init__(self, sim, inverter=None, saturation=None, thermal=None, sensors=None,
                 iron_loss: bool = False, core_loss_exponent: float = 2.0,
                 locked_rotor: bool = False):
        base = sim.schedule.base
        if isinstance(inverter, Mapping):
            inverter = inverter_from_dict(inverter)
        if isinstance(saturation, Mapping):
            saturation = saturation_from_dict(saturation, base.L_M)
        if isinstance(thermal, Mapping):
            thermal = thermal_from_dict(thermal)
        if isinstance(sensors, Mapping):
            sensors = sensors_from_dict(sensors)
        for name, obj, cls in (('inverter', inverter, Inverter),
                               ('saturation', saturation, Saturation),
                               ('thermal', thermal, Thermal), ('sensors', sensors, Sensors)):
            if obj is not None and not isinstance(obj, cls):
                raise TypeError(f'{name} must be a {cls.__name__} or a mapping')
        if inverter is not None:
            check_against_motor(inverter, base.rated_voltage, sim.T_s)
        self.sim = sim
        self.inverter = inverter
        self.saturation = saturation
        self.thermal = thermal
        self.sensors = sensors
        self.iron_loss = bool(iron_loss)
        self.model = RealMotorModel(sim.schedule, sim.load, core_loss_exponent, locked_rotor,
                                    saturation, iron_loss,
                                    inverter.r_on if inverter is not None else 0.0)
        sim.model = self.model
        sim.x = list(sim.x) + [0.0]
        self.max_substep = sim.h
        self.sat_sub = SATURATED_SUBSTEPS if saturation is not None else 1
        # unit switch-state vectors: clarke of the pole voltages (s_a, s_b, s_c) for V_dc = 1
        self._sv = {(a, b, c): clarke(a, b, c) for a in (0, 1) for b in (0, 1) for c in (0, 1)}
        self.temps = None
        if thermal is not None:
            self.temps = list(thermal.initial())
            self._decay = thermal.decay(sim.T_s)
            self._set_resistances()
        self.V = inverter.V_dc if inverter is not None else math.nan
        self.E_source = self.E_chopper = 0.0
        self.W_cap0 = (0.5 * inverter.C_dc * self.V ** 2) if inverter is not None else 0.0
        self.P_inverter = 0.0
        self.ripple = 0.0
        self._speed = None
        self._omega_meas = sim.x[5]
        if sensors is not None and sensors.encoder_lines > 0:
            self._speed = SpeedFromCounts(sensors.counts_per_rev, sensors.speed_window, sim.T_s,
                                          sensors.count(sim.x[4]))
            self._omega_meas = 0.0
        sim.step = self.step
        sim.state_currents = self.state_currents
        sim.measure = self.measure
        sim.truth = self.truth

    def describe(self) -> dict:
        """Return the blocks as written in the run and motor files (the run record)."""
        return {'inverter': None if self.inverter is None else self.inverter.describe(),
                'saturation': None if self.saturation is None else self.saturation.describe(),
                'thermal': None if self.thermal is None else self.thermal.describe(),
                'sensors': None if self.sensors is None else self.sensors.describe(),
                'iron_loss': self.iron_loss}

    def _set_resistances(self) -> None:
        self.model.set_temperature_factors(*self.thermal.resistance_factors(*self.temps))

    # Stepping ----------------------------------------------------------------------------
    def step(self, v_a: float, v_b: float) -> None:
        """Integrate [t_k, t_k+1] with the command (PlantSimulator.step, module doc)."""
        sim = self.sim
        v_a, v_b = sim.admit(v_a, v_b)
        x0 = sim.x
        t0 = sim.t
        x, v_avg = self._integrate(x0, t0, v_a, v_b, sim.trip is not None)
        if not all(map(math.isfinite, x)):
            sim.trip = (t0 + sim.T_s, 'non-finite state')
            x, v_avg = self._integrate(x0, t0, 0.0, 0.0, True)
            if not all(math.isfinite(v) for v in x):
                raise FloatingPointError(
                    f'plant state became non-finite at t = {t0 + sim.T_s:.9f} s '
                    'even at zero voltage')
        sim.v_applied = v_avg
        sim.x = x
        sim.k += 1
        self._after_period(x0, x)
        if sim.trip is None:
            sim.protect()

    def _integrate(self, x, t0: float, v_a: float, v_b: float, tripped: bool):
        sim = self.sim
        T_s = sim.T_s
        rk4 = self.model.rk4
        inv = self.inverter
        if inv is None:
            if tripped:
                v_a = v_b = 0.0
            n = max(1, int(math.ceil(T_s / self.max_substep - 1e-9))) * self.sat_sub
            h = T_s / n
            for j in range(n):
                x = rk4(t0 + j * h, x, h, v_a, v_b)
            return x, (v_a, v_b)
        V = self.V
        if tripped:                             # every lower device on: the stator shorted
            return self._run_plan(x, t0, [(T_s, (0, 0, 0))], None)
        d, _ = duties(v_a, v_b, V)
        half = sim.k % 2 if inv.update == 'double' else 0
        # with on-state drops, their signs are taken again at the carrier's valley too
        extra = (0.5 * inv.T_c,) if inv.v_on > 0.0 and inv.update == 'single' else ()
        if inv.deadtime > 0.0:
            # the dead bands resolved by the currents' signs at the period's start; if a current
            # changes sign within the period, the period again with explicit dead bands
            ph = phase_values(*self.model.stator_current(t0, x))
            signs = tuple(_sgn(i) for i in ph)
            if 0.0 not in signs:
                plan = period_plan(d, half, inv.T_c, T_s, inv.deadtime, signs, extra)
                out = self._run_plan(x, t0, plan, signs)
                if out is not None:
                    return out
        plan = period_plan(d, half, inv.T_c, T_s, inv.deadtime, extra=extra)
        return self._run_plan(x, t0, plan, None)

    def _run_plan(self, x, t0: float, plan, signs):
        """
        Integrate the period's intervals in order; return (x, mean voltage).

        With ``signs`` (the dead bands resolved by them), None when a phase current's sign at an
        interval boundary differs from its assumed sign.
        """
        T_s = self.sim.T_s
        model = self.model
        rk4 = model.rk4
        V = self.V
        v_on = self.inverter.v_on
        sv = self._sv
        t = t0
        sa = sb = 0.0
        lo = math.inf
        hi = -math.inf
        for length, states in plan:
            i_sa, i_sb = model.stator_current(t, x)
            ph = phase_values(i_sa, i_sb)
            if signs is not None and (ph[0] * signs[0] <= 0.0 or ph[1] * signs[1] <= 0.0
                                      or ph[2] * signs[2] <= 0.0):
                return None
            lo = min(lo, ph[0])
            hi = max(hi, ph[0])
            if None in states:              # a dead band: the freewheeling diode's rail
                states = tuple(s if s is not None else _DIODE[_sgn(i)]
                               for s, i in zip(states, ph))
            ua, ub = sv[states] if states in sv else clarke(*states)
            va, vb = V * ua, V * ub
            if v_on > 0.0:
                da, db = clarke(_sgn(ph[0]), _sgn(ph[1]), _sgn(ph[2]))
                da *= v_on
                db *= v_on
                model.drop = (da, db)
                va -= da
                vb -= db
            n = max(1, int(math.ceil(length / self.max_substep - 1e-9))) * self.sat_sub
            h = length / n
            for _ in range(n):
                x = rk4(t, x, h, va, vb)
                t += h
            sa += va * length
            sb += vb * length
        i_sa, i_sb = model.stator_current(t, x)
        ph = phase_values(i_sa, i_sb)
        if signs is not None and (ph[0] * signs[0] <= 0.0 or ph[1] * signs[1] <= 0.0
                                  or ph[2] * signs[2] <= 0.0):
            return None
        self.ripple = max(hi, ph[0]) - min(lo, ph[0])
        return x, (sa / T_s, sb / T_s)

    def _after_period(self, x0, x) -> None:
        sim = self.sim
        T_s = sim.T_s
        th = self.thermal
        if th is not None:
            p_s = x[E_CU_S] - x0[E_CU_S]
            if self.iron_loss:
                p_s += x[E_CORE] - x0[E_CORE]
            p_r = (x[E_CU_R] - x0[E_CU_R]) / T_s
            ds, dr = self._decay
            self.temps = [first_order(self.temps[0], th.T_ambient, th.R_th_s, p_s / T_s, ds),
                          first_order(self.temps[1], th.T_ambient, th.R_th_r, p_r, dr)]
            self._set_resistances()
        inv = self.inverter
        if inv is not None:
            e_inv = x[E_INV] - x0[E_INV]
            self.P_inverter = e_inv / T_s
            e_dc = x[E_IN] - x0[E_IN] + e_inv
            if inv.C_dc > 0:
                V = self.V
                e_src = max(0.0, (inv.V_dc - V) / inv.R_source) * V * T_s
                e_ch = (V * V / inv.R_chopper * T_s
                        if inv.V_chopper > 0 and V > inv.V_chopper else 0.0)
                self.E_source += e_src
                self.E_chopper += e_ch
                w = 0.5 * inv.C_dc * V * V + e_src - e_ch - e_dc
                self.V = math.sqrt(max(0.0, 2.0 * w / inv.C_dc))
                if sim.trip is None and self.V > inv.trip_voltage:
                    sim.trip = (sim.t, f'DC-link over-voltage: V_dc = {self.V:.4g} V > V_trip '
                                       f'{inv.trip_voltage:g} V (regeneration the brake chopper '
                                       f'did not absorb)')
            else:
                self.E_source += e_dc
        if self._speed is not None:
            self._omega_meas = self._speed.update(self.sensors.count(x[4]))

    # Outputs -----------------------------------------------------------------------------
    def state_currents(self):
        """Return (i_sα, i_sβ, i_rα, i_rβ) at t_k (the rotor current in the model's gauge)."""
        out = self.model.outputs(self.sim.t, self.sim.x)
        return out['i_alpha'], out['i_beta'], out['i_r_alpha'], out['i_r_beta']

    def measure(self):
        """Return what the sensors give at t_k, the carrier's peak (im_common.sensors)."""
        sim = self.sim
        i_sa, i_sb = self.model.stator_current(sim.t, sim.x)
        theta, omega = sim.x[4], sim.x[5]
        se = self.sensors
        v_dc = self.V
        if se is not None:
            ph = phase_values(i_sa, i_sb)
            i_sa, i_sb = clarke(*(se.phase_current(k, ph[k]) for k in range(3)))
            if se.encoder_lines > 0:
                theta = se.count(theta) * TWO_PI / se.counts_per_rev
                omega = self._omega_meas
            if self.inverter is not None:
                v_dc = se.adc(v_dc, 0.0, se.vdc_range)
        i_sa, i_sb, omega = sim.add_noise(i_sa, i_sb, omega)
        return Measurement(sim.t, i_sa, i_sb, theta, omega, v_dc)

    def truth(self) -> dict:
        """Return the ground truth: the ideal plant's keys plus the blocks' quantities."""
        sim = self.sim
        t = sim.t
        x = sim.x
        out = self.model.outputs(t, x)
        d = self.model.rhs(t, x, sim.v_applied[0], sim.v_applied[1])
        out.update({
            'v_alpha': sim.v_applied[0], 'v_beta': sim.v_applied[1],
            'P_in': d[E_IN], 'P_cu_s': d[E_CU_S], 'P_cu_r': d[E_CU_R], 'P_core': d[E_CORE],
            'P_friction': d[10], 'P_load': d[11], 'P_param': d[12],
            'E_in': x[E_IN], 'E_cu_s': x[E_CU_S], 'E_cu_r': x[E_CU_R], 'E_core': x[E_CORE],
            'E_friction': x[10], 'W_load': x[11], 'E_param': x[12], 'E_inv': x[E_INV],
        })
        out['tripped'] = 0.0 if sim.trip is None else 1.0
        out['trip_t'] = math.nan if sim.trip is None else sim.trip[0]
        out['trip_reason'] = '' if sim.trip is None else sim.trip[1]
        out['dW_mag'] = out['W_mag'] - sim.W_mag0
        out['dE_kin'] = out['E_kin'] - sim.E_kin0
        out['balance_residual'] = (out['E_in'] - out['E_cu_s'] - out['E_cu_r']
                                   - out['E_friction'] - out['W_load'] - out['E_param']
                                   - out['dW_mag'] - out['dE_kin']
                                   - (out['E_core'] if self.iron_loss else 0.0))
        if self.iron_loss:
            out['E_iron'] = out['E_core']       # dissipated, inside the balance (topics.py)
        if self.temps is not None:
            out['T_stator'], out['T_rotor'] = self.temps
        inv = self.inverter
        if inv is not None:
            i_a, i_b, i_c = phase_values(out['i_alpha'], out['i_beta'])
            w_cap = 0.5 * inv.C_dc * self.V ** 2
            out.update({'V_dc': self.V, 'i_a': i_a, 'i_b': i_b, 'i_c': i_c,
                        'i_ripple_pp': self.ripple, 'P_inverter': self.P_inverter,
                        'E_source': self.E_source, 'E_chopper': self.E_chopper,
                        'dW_cap': w_cap - self.W_cap0})
            out['balance_residual_dc'] = (self.E_source - self.E_chopper - out['dW_cap']
                                          - out['E_in'] - out['E_inv'])
        return out
