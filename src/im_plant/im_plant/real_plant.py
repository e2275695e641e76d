"""
The real plant: the engine of :class:`im_plant.plant_sim.PlantSimulator` when a block is on.

A :class:`PlantSimulator` given any of ``inverter`` (the switched one), ``saturation``,
``thermal``, ``sensors`` or ``iron_loss`` makes one :class:`RealPlant` as its engine
(:class:`im_plant.engine.PlantEngine`, docs/architecture.md "The plant built from parts"); the
ideal plant (every block absent) is :class:`im_plant.engine.IdealPlant` and never reaches this
module, so its path and its numbers are unchanged. The real plant is given what it needs when it
is made: the motor (schedule, live load, core-loss exponent, locked shaft), T_s, the
sub-periods, the start, the typed blocks (:class:`im_common.inverter.Inverter`,
:class:`im_common.saturation.Saturation`, :class:`im_common.thermal.Thermal`,
:class:`im_plant.sensors.Sensors`; a mapping is read into its block) and the protection's
limits. It owns its :class:`im_common.model.RealMotorModel`, its state ``x`` (14 elements: the
ideal plant's and ``E_inv``), ``k`` and ``v_applied``; the simulator hands it each period's
admitted command and whether the protection has latched (:meth:`RealPlant.advance`), latches the
trip the period reports (a non-finite state, the DC link's over-voltage) and checks its limits
when told to; it asks ``state_currents``, ``stator_currents``, ``measure`` (the sensors' reading,
to which the simulator adds its noise) and ``truth``.

Per control period (docs/plant.md):

1. the command passes the simulator's limit and rating checks, then (with an inverter) the
   carrier comparison of :mod:`im_common.inverter` computes the period's switching instants once,
   at its start;
2. between consecutive instants the pole voltages are constant: the interval is solved exactly,
   two complex exponentials of the period's complex-linear electrical system (the speed, the
   magnetizing slope and the iron loss's rotation offset held over the period at predicted
   values, docs/plant.md §1), the energy integrals in closed form from the same solution — a
   bounded number of intervals per period, no zero-crossing search, no sub-steps. The dead bands
   are resolved by the phase currents' signs at the period's start; if a current's sign at any
   interval boundary differs, the period is integrated again with explicit dead bands, each
   taking the sign of its leg's current at the band's start. The shaft then takes the period's
   mean torque (momentum), its angle the trapezoid of the speeds. ``use_reference(n)`` switches
   to RK4 of :meth:`im_common.model.RealMotorModel.rhs`, n steps per interval (the fine-step
   reference of the tests);
3. the switching losses (``e_sw``, :mod:`im_common.inverter`): every pole transition of the
   period — its instants with the dead bands resolved, and a leg's state at the period's start
   against the last period's end — costs ½ k V_dc |i_x| with the leg's current at that instant
   (the exact solution's at the interval boundary), booked with the conduction losses in
   ``E_inv`` (drawn from the DC link) and apart in ``E_switching``;
4. after the period: the winding temperatures (exact first-order step, :mod:`im_common.thermal`),
   the DC link (energy form) and the encoder's count; then the simulator's protection (the
   period's :class:`im_plant.engine.Report`).

Steps 1-4 run compiled (:mod:`im_plant.real_plant_kernel`, numba) when
``RealPlant.use_kernel``, in the same arithmetic; the pure-Python path (:meth:`RealPlant._solve`
and the methods around it) is the reference (``use_kernel = False``, equal to 1e-12,
tests/test_real_plant_kernel.py). One call a period (``real_plant_kernel.step``) where the
plant's parameters are constant (the temperatures aside) and its load is one of
:mod:`im_common.loads`'s: everything above plus the sensors' measurement and the state's
currents, the state kept in one array between periods; the attributes it holds
(``_SYNCED``: ``V``, ``temps``, ``E_switching``, ...) are out of the instance while it steps
and are given back from the array when read (``__getattr__``), its ``x``, ``v_applied`` and
``k`` are set every period, and the kernel's status reports the DC link's trip and whether the
protection's limits are near (else the simulator need not check them). Otherwise the period's
events and, once its predictions are made in Python, the intervals, the sign check, the
switching tally and the closed-form integrals are compiled. Either hands the periods with repeated
eigenvalues (and a non-finite state) to the reference.
"""
from __future__ import annotations

from cmath import exp as cexp, sqrt as csqrt
import math
import os
from typing import Mapping, Optional

from im_common.inverter import (carry_after, check_against_motor, duties, edges, Inverter,
                                period_plan, phase_values)
from im_common.loads import ConstantLoad, LinearLoad, NoLoad, PendulumLoad, ScheduleLoad, StepLoad
from im_common.model import (E_CORE, E_CU_R, E_CU_S, E_IN, E_INV, iron_rotation, N_AUG_REAL,
                             RealMotorModel)
from im_common.params import clarke
from im_common.saturation import Saturation, saturation_from_dict
from im_common.thermal import first_order, Thermal, thermal_from_dict

from . import real_plant_kernel as _kernel
from .engine import add_trip, augmented, CHECK, CLEAR, diverged, NON_FINITE, Report
from .sensors import Measurement, Sensors, SpeedFromCounts

try:
    import numpy as np
except ImportError:                             # pragma: no cover - numpy is pinned
    np = None

TWO_PI = 2.0 * math.pi
SQRT3 = math.sqrt(3.0)
SQRT_2_3 = math.sqrt(2.0 / 3.0)

#: the pole state a dead band gives by the current's sign: the lower diode for i > 0, the upper
#: for i < 0, and with no current (neither conducts) the middle of the rails
_DIODE = {1.0: 0, -1.0: 1, 0.0: 0.5}
#: the switch states as a bit mask (leg a: 1, b: 2, c: 4): the unit stator vector clarke(s)
#: (V_dc = 1) as a complex number, its conjugate and its squared magnitude
_UNIT_VECTORS = tuple(complex(*clarke(c & 1, (c >> 1) & 1, (c >> 2) & 1)) for c in range(8))
_UNIT = (_UNIT_VECTORS, tuple(u.conjugate() for u in _UNIT_VECTORS),
         tuple((u * u.conjugate()).real for u in _UNIT_VECTORS))


#: _UNIT as the compiled kernel takes it (im_plant.real_plant_kernel)
_UNIT_ARRAYS = _kernel.as_table(_UNIT)


#: clarke(x_a, x_b, x_c) as a complex number for the triples a period's plan and the currents'
#: signs give: switch states {0, ½, 1} (½: a dead band without current) and signs {−1, 0, 1}
_CLARKE = {(a, b, c): complex(*clarke(a, b, c)) for vals in ((0, 0.5, 1), (-1.0, 0.0, 1.0))
           for a in vals for b in vals for c in vals}


#: the loads the whole-period kernel evaluates itself, by their exact type (a subclass may
#: override ``torque``): their kind and parameters (real_plant_kernel.LOAD_*, LP0..LP2)
_LOADS = {
    NoLoad: lambda ld: (_kernel.LOAD_NONE, 0.0, 0.0, 0.0),
    ConstantLoad: lambda ld: (_kernel.LOAD_CONSTANT, ld.tau, 0.0, 0.0),
    LinearLoad: lambda ld: (_kernel.LOAD_LINEAR, ld.c1, ld.c2, 0.0),
    PendulumLoad: lambda ld: (_kernel.LOAD_PENDULUM, ld.mgl, 0.0, 0.0),
    StepLoad: lambda ld: (_kernel.LOAD_STEP, ld.t, ld.tau_after, ld.tau_before),
    ScheduleLoad: lambda ld: (_kernel.LOAD_SCHEDULE, 0.0, 0.0, 0.0),
}
#: the attributes the whole-period kernel keeps in its array while it steps (RealPlant._w):
#: out of the instance's dict then, and given back (:meth:`RealPlant._sync`) when read
_SYNCED = ('_prev', '_carry', '_next_carry', '_poles', '_end_poles', '_edges', 'V', 'E_source',
           'E_chopper', 'P_inverter', 'E_switching', 'P_switching', 'ripple', 'temps',
           '_omega_meas', '_end_current', '_currents', '_speed')
#: where a compiled period's outputs (``RealPlant._fo``, from the kernel's X0 on) hold what the
#: plant reads: the applied mean voltage, i_s at the end, the state's currents, the measurement,
#: V_dc and the resistances' temperature factors (real_plant_kernel's layout)
(_O_VAPP, _O_IEND, _O_ISTATE, _O_MEAS, _O_VDC, _O_FS, _O_FR) = (
    k - _kernel.X0 for k in (_kernel.V_APP, _kernel.I_END, _kernel.I_STATE, _kernel.MEAS,
                             _kernel.V_LINK, _kernel.F_S, _kernel.F_R))


def _sgn(x: float) -> float:
    return 1.0 if x > 0.0 else (-1.0 if x < 0.0 else 0.0)


#: the legs' pole states (a, b, c) of a switch-state bit mask
_POLES = tuple((c & 1, (c >> 1) & 1, (c >> 2) & 1) for c in range(8))
#: a leg's bit → its index in (a, b, c)
_LEG = {1: 0, 2: 1, 4: 2}


def _leg_current(i: complex, bit: int) -> float:
    """Return |i_x| of the leg ``bit`` (1: a, 2: b, 4: c) from the stator current i_sα + j i_sβ."""
    return abs(phase_values(i.real, i.imag)[_LEG[bit]])


def _edge_currents(before, after, i: complex) -> float:
    """
    Return Σ |Δs_x| |i_x| over the legs whose pole state changes from ``before`` to ``after``.

    ``i`` is the stator current at that instant; ``before`` None (no period yet): no edge.
    """
    if before is None or before == after:
        return 0.0
    ph = phase_values(i.real, i.imag)
    return (abs(after[0] - before[0]) * abs(ph[0]) + abs(after[1] - before[1]) * abs(ph[1])
            + abs(after[2] - before[2]) * abs(ph[2]))


def _typed_blocks(base, T_s: float, inverter, saturation, thermal, sensors):
    """
    Return (inverter, saturation, thermal, sensors) as their typed blocks (None: absent).

    A mapping is read into its block (the saturation curve on the motor ``base``'s L_M);
    another type is refused (TypeError); an inverter is checked against the motor and T_s.
    """
    if isinstance(saturation, Mapping):
        saturation = saturation_from_dict(saturation, base.L_M)
    if isinstance(thermal, Mapping):
        thermal = thermal_from_dict(thermal)
    if isinstance(sensors, Mapping):
        sensors = Sensors.from_block(sensors)
    for name, obj, cls in (('inverter', inverter, Inverter),
                           ('saturation', saturation, Saturation),
                           ('thermal', thermal, Thermal), ('sensors', sensors, Sensors)):
        if obj is not None and not isinstance(obj, cls):
            raise TypeError(f'{name} must be a {cls.__name__} or a mapping')
    if inverter is not None:
        check_against_motor(inverter, base.rated_voltage, T_s)
    return inverter, saturation, thermal, sensors


def _dc_link_trip(t: float, V: float, inverter: Inverter):
    """Return the DC link's over-voltage trip at ``t`` with the link at ``V`` [V]."""
    return (t, f'DC-link over-voltage: V_dc = {V:.4g} V > V_trip {inverter.trip_voltage:g} V '
               f'(regeneration the brake chopper did not absorb)')


class RealPlant:
    """The real plant's engine: its blocks, its model and its state (module doc)."""

    #: the period by the compiled kernel (:mod:`im_plant.real_plant_kernel`, numba) when it
    #: exists, else (False) by the pure-Python path of :meth:`_solve`, the reference; also
    #: False with IM_REAL_PLANT_KERNEL=0 in the environment (docs/plant.md §9)
    use_kernel = _kernel.available and os.environ.get('IM_REAL_PLANT_KERNEL') != '0'

    def __init__(self, motor, T_s: float, n_sub: int, x0, inverter=None, saturation=None,
                 thermal=None, sensors=None, iron_loss: bool = False,
                 current_trip: Optional[float] = None, speed_trip: Optional[float] = None):
        """
        Make the real plant of ``motor`` with its blocks, at the start ``x0``.

        ``motor`` (an :class:`im_common.model.MotorModel`) gives the schedule, the (live) load,
        the core-loss exponent and whether the shaft is locked; ``T_s`` the period [s],
        ``n_sub`` the sub-periods of an ideal source's period, ``x0`` the 6-element start;
        ``current_trip`` and ``speed_trip`` (None: none) the simulator's protection limits,
        which the compiled period tells it are near (:data:`im_plant.engine.CHECK`).
        """
        inverter, saturation, thermal, sensors = _typed_blocks(
            motor.schedule.base, T_s, inverter, saturation, thermal, sensors)
        self.inverter = inverter
        self.saturation = saturation
        self.thermal = thermal
        self.sensors = sensors
        self.iron_loss = bool(iron_loss)
        self.T_s = T_s
        self.n_sub = n_sub
        self._limits = (current_trip, speed_trip)
        self.model = RealMotorModel(motor.schedule, motor.load, motor.core_loss_exponent,
                                    motor.locked, saturation, iron_loss,
                                    inverter.r_on if inverter is not None else 0.0)
        self.k = 0
        self.x = augmented(x0, N_AUG_REAL)
        self.v_applied = (0.0, 0.0)
        self.reference_substeps = None          # None: exact; n: the RK4 reference
        p = self.model.params
        self._consts = (p.pole_pairs, p.J, p.b, p.k_h, p.k_e, self.model.load, saturation,
                        self.iron_loss, self.model.locked, self.model.r_on)
        self._prev = None                       # the last period's predictors (_solve)
        # the kernel's constants as floats (one compiled signature whatever their types)
        self._kfloats = (float(p.pole_pairs), float(p.k_h), float(p.k_e))
        self._ev = _kernel.events_buffer()     # the compiled events (_switching)
        if self.use_kernel:
            _kernel.warm()                      # compiled (or loaded) before the first step
        self._currents = (None, None)           # (state, state_currents()) of the last call
        self._end_current = (None, 0j)          # (state, i_s) at the end of the last _solve
        # unit switch-state vectors: clarke of the pole voltages (s_a, s_b, s_c) for V_dc = 1
        self._sv = {(a, b, c): clarke(a, b, c) for a in (0, 1) for b in (0, 1) for c in (0, 1)}
        self.temps = None
        if thermal is not None:
            self.temps = list(thermal.initial())
            self._decay = thermal.decay(T_s)
            self._set_resistances()
        self._start_inverter()
        self._start_sensors()
        # the whole period in one compiled call (real_plant_kernel.step) where it applies: the
        # array w holds the state while it steps (module doc, "one call a period")
        self._stale = False                     # w holds the state, the attributes are out
        self._packed = False                    # w holds what the attributes hold
        self._x_fast = None                     # x as the last compiled period left it
        self._fo = None                         # that period's outputs (w[X0:X0 + N_OUT])
        self.handed_back = 0                    # compiled periods the reference path took
        self._w = self._tab = None
        if _kernel.available and np is not None:
            self._whole_arrays()
        out = self.model.outputs(0.0, self.x)   # the stored energies at t_0 (truth's balance)
        self.W_mag0 = out['W_mag']
        self.E_kin0 = out['E_kin']

    @property
    def t(self) -> float:
        """Return t_k = k·T_s [s]."""
        return self.k * self.T_s

    def _start_inverter(self) -> None:
        """Set the DC link, its books and the switching losses' state at t_0."""
        inverter = self.inverter
        self.V = inverter.V_dc if inverter is not None else math.nan
        self.E_source = self.E_chopper = 0.0
        self.W_cap0 = (0.5 * inverter.C_dc * self.V ** 2) if inverter is not None else 0.0
        self.P_inverter = 0.0
        # the switching losses (module doc, step 3): ½ k per edge, the legs' pole states at the
        # last period's end, Σ|i_x| over the edges of the period being integrated
        self._k_edge = 0.5 * inverter.switching_coefficient if inverter is not None else 0.0
        self._poles = None                      # committed with the period (advance)
        self._end_poles = None                  # the last integration's end states
        # the dead bands that cross into the next period (inverter.carry_after), per leg
        self._carry = self._next_carry = (0.0, 0.0, 0.0)
        self._edges = 0.0
        self.E_switching = self.P_switching = 0.0
        self.ripple = 0.0

    def _start_sensors(self) -> None:
        """Set the encoder's speed from counts at t_0 (none: the measured speed is the true)."""
        sensors = self.sensors
        x = self.x
        self._speed = None
        self._omega_meas = x[5]
        if sensors is not None and sensors.encoder_lines > 0:
            # a shaft already turning at t_0 (a steady start) was counted before it: the window
            # holds the W periods before t_0, as at any later step (before, ω̂ read 0 at a
            # steady start of 100 rad/s, the speed task anchored its reference at rest and the
            # drive lost the run)
            th0, w0, W = x[4], x[5], sensors.speed_window
            past = [sensors.count(th0 - w0 * (W - j) * self.T_s) for j in range(W + 1)]
            self._speed = SpeedFromCounts(sensors.counts_per_rev, W, self.T_s, past)
            self._omega_meas = self._speed.value()
        self._speed_obj = self._speed           # kept while _speed is out (_unsync)

    # The whole period compiled ---------------------------------------------------------
    def _whole_arrays(self) -> None:
        """
        Make the arrays of :func:`real_plant_kernel.step` when it applies, else leave None.

        It applies to a constant parameter schedule (the temperatures aside) and the loads of
        :data:`_LOADS`; the rest steps as before (the events and intervals compiled, the
        predictions and the blocks in Python). The array's blocks are packed in turn: the
        inverter, the motor, the saturation curve, the thermal model, the sensors, the load.
        """
        mdl = self.model
        live = mdl.load
        inner = getattr(live, 'load', live)
        base = mdl.base_circuit
        if base is None or type(inner) not in _LOADS:
            return
        K = _kernel
        kind, lp0, lp1, lp2 = _LOADS[type(inner)](inner)
        sat = self.saturation
        n_sat = 0 if sat is None or sat.table is None else len(sat.table[0])
        n_load = self._whole_table(sat, n_sat, kind, inner)
        se = self.sensors
        window = se.speed_window if se is not None and se.encoder_lines > 0 else 0
        w = np.zeros(K.HIST + window + 1, dtype=np.float64)
        self._pack_inverter(w)
        self._pack_motor(w, base)
        self._pack_saturation(w, sat, n_sat)
        self._pack_thermal(w)
        self._pack_sensors(w, se, window)
        self._pack_load(w, kind, lp0, lp1, lp2, n_load)
        self._w = w
        self._live = live
        if self.use_kernel:
            _kernel.warm()

    def _whole_table(self, sat, n_sat: int, kind: float, inner) -> int:
        """Make the kernel's table (the saturation's knots, a schedule's points); return n_load."""
        cols = []
        if n_sat:
            psi, cur, slopes, energy = sat.knots()
            cols = list(psi) + list(cur) + list(slopes) + [0.0] + list(energy)
        n_load = 0
        if kind == _kernel.LOAD_SCHEDULE:
            n_load = len(inner.points)
            cols += [p[0] for p in inner.points] + [p[1] for p in inner.points]
        self._tab = np.array(cols + [0.0], dtype=np.float64)
        return n_load

    def _pack_inverter(self, w) -> None:
        """Pack the period's timing and the inverter's block (PWM, dead time, DC link)."""
        K = _kernel
        inv = self.inverter
        w[K.T_S] = self.T_s
        w[K.N_SUB] = self.n_sub
        if inv is not None:
            w[K.HAS_INV] = 1.0
            w[K.T_C] = inv.T_c
            w[K.T_D] = inv.deadtime
            w[K.V_ON] = inv.v_on
            w[K.DOUBLE] = 1.0 if inv.update == 'double' else 0.0
            w[K.V_DC] = inv.V_dc
            w[K.C_DC] = inv.C_dc
            w[K.R_SOURCE] = inv.R_source
            w[K.V_CHOP] = inv.V_chopper
            w[K.R_CHOP] = inv.R_chopper
            w[K.V_TRIP] = inv.trip_voltage

    def _pack_motor(self, w, base) -> None:
        """Pack the motor's block: r_on, the shaft, the iron loss and the base circuit."""
        K = _kernel
        mdl = self.model
        p = mdl.params
        w[K.R_ON] = mdl.r_on
        w[K.K_EDGE] = self._k_edge
        w[K.VP] = p.pole_pairs
        w[K.J_IN] = p.J
        w[K.B_F] = p.b
        w[K.K_H] = p.k_h
        w[K.K_E] = p.k_e
        w[K.IRON] = 1.0 if self.iron_loss else 0.0
        w[K.LOCKED] = 1.0 if mdl.locked else 0.0
        w[K.CORE_EXP] = mdl.core_loss_exponent
        w[K.R_S0], w[K.R_R0], w[K.TH], w[K.L_SIG], w[K.INV_LM0] = base

    @staticmethod
    def _pack_saturation(w, sat, n_sat: int) -> None:
        """Pack the saturation block (the power law's constants, the table's length)."""
        K = _kernel
        if sat is not None:
            w[K.SAT] = 2.0 if n_sat else 1.0
            w[K.BETA] = sat.beta
            w[K.S_EXP] = sat.S
            w[K.B_S] = sat.beta_S
            w[K.L_M0] = sat.L_M0
            w[K.N_SAT] = n_sat

    def _pack_thermal(self, w) -> None:
        """Pack the thermal block (the ambient, the thermal resistances and decays, α)."""
        K = _kernel
        th = self.thermal
        if th is not None:
            w[K.THERM] = 1.0
            w[K.T_AMB] = th.T_ambient
            w[K.R_TH_S] = th.R_th_s
            w[K.R_TH_R] = th.R_th_r
            w[K.DEC_S], w[K.DEC_R] = self._decay
            w[K.ALPHA_S] = th.alpha_s
            w[K.ALPHA_R] = th.alpha_r
            w[K.T_REF] = th.T_ref

    def _pack_sensors(self, w, se, window: int) -> None:
        """Pack the sensors' block (the encoder and its speed window, the ADCs)."""
        K = _kernel
        if se is not None:
            w[K.SENS] = 1.0
            w[K.ENC] = 1.0 if se.encoder_lines > 0 else 0.0
            w[K.CPR] = se.counts_per_rev
            w[K.WIN] = se.speed_window
            if window:
                w[K.SCALE] = self._speed.scale
            w[K.BITS] = se.adc_bits
            w[K.I_RANGE] = se.current_range
            w[K.G_A], w[K.G_B], w[K.G_C] = se.current_gain
            w[K.O_A], w[K.O_B], w[K.O_C] = se.current_offset
            w[K.VDC_RANGE] = se.vdc_range

    @staticmethod
    def _pack_load(w, kind: float, lp0: float, lp1: float, lp2: float, n_load: int) -> None:
        """Pack the load's block (its kind, parameters and a schedule's length)."""
        K = _kernel
        w[K.LOAD] = kind
        w[K.LP0] = lp0
        w[K.LP1] = lp1
        w[K.LP2] = lp2
        w[K.N_LOAD] = n_load

    def _pack(self) -> None:
        """Write the attributes and the state into the kernel's array."""
        if self._stale:
            self._sync()
        K = _kernel
        w = self._w
        x = self.x
        current_trip, speed_trip = self._limits
        w[K.I_TRIP] = math.nan if current_trip is None else current_trip
        w[K.W_TRIP] = math.nan if speed_trip is None else speed_trip
        prev = self._prev
        w[K.PREV] = prev is not None
        if prev is not None:
            w[K.PREV_T:K.PREV_W0BAR + 1] = prev
        w[K.CARRY_A:K.CARRY_C + 1] = self._carry
        w[K.POLES] = self._poles is not None
        if self._poles is not None:
            w[K.POLE_A:K.POLE_C + 1] = self._poles
        if self._end_poles is not None:
            w[K.END_A:K.END_C + 1] = self._end_poles
        w[K.EDGES] = self._edges
        w[K.E_SRC] = self.E_source
        w[K.E_CH] = self.E_chopper
        w[K.P_INV] = self.P_inverter
        w[K.E_SWT] = self.E_switching
        w[K.P_SWT] = self.P_switching
        w[K.RIPPLE] = self.ripple
        if self.temps is not None:
            w[K.TEMP_S], w[K.TEMP_R] = self.temps
        end = self._end_current
        w[K.END_VALID] = end[0] is x
        w[K.I_END] = end[1].real
        w[K.I_END + 1] = end[1].imag
        w[K.OMEGA_MEAS] = self._omega_meas
        w[K.X0:K.X0 + 14] = x
        w[K.V_LINK] = self.V
        w[K.F_S] = self.model.fs
        w[K.F_R] = self.model.fr
        if self._speed is not None:
            hist = self._speed.hist
            w[K.HIST_N] = len(hist)
            w[K.HIST:K.HIST + len(hist)] = hist
        self._packed = True

    def _unsync(self) -> None:
        """Take the attributes the array now holds out of the instance (read: :meth:`_sync`)."""
        d = self.__dict__
        for name in _SYNCED:
            d.pop(name, None)
        self._stale = True

    def _sync(self) -> None:
        """Set the attributes from the kernel's array (the state the compiled periods left)."""
        K = _kernel
        w = self._w
        d = self.__dict__
        d['_stale'] = False
        x = self.x
        valid = x is self._x_fast
        vals = w[:K.HIST].tolist()
        d['_prev'] = tuple(vals[K.PREV_T:K.PREV_W0BAR + 1]) if vals[K.PREV] else None
        d['_carry'] = d['_next_carry'] = tuple(vals[K.CARRY_A:K.CARRY_C + 1])
        d['_poles'] = tuple(vals[K.POLE_A:K.POLE_C + 1]) if vals[K.POLES] else None
        d['_end_poles'] = tuple(vals[K.END_A:K.END_C + 1])
        d['_edges'] = vals[K.EDGES]
        d['E_source'] = vals[K.E_SRC]
        d['E_chopper'] = vals[K.E_CH]
        d['P_inverter'] = vals[K.P_INV]
        d['E_switching'] = vals[K.E_SWT]
        d['P_switching'] = vals[K.P_SWT]
        d['ripple'] = vals[K.RIPPLE]
        d['temps'] = [vals[K.TEMP_S], vals[K.TEMP_R]] if self.thermal is not None else None
        d['_omega_meas'] = vals[K.OMEGA_MEAS]
        d['V'] = vals[K.V_LINK]
        i_end = complex(vals[K.I_END], vals[K.I_END + 1])
        d['_end_current'] = (x if valid and vals[K.END_VALID] else None, i_end)
        d['_currents'] = ((x, tuple(vals[K.I_STATE:K.I_STATE + 4])) if valid
                          else (None, None))
        speed = d['_speed_obj']
        if speed is not None:
            n = int(vals[K.HIST_N])
            speed.hist = [int(c) for c in w[K.HIST:K.HIST + n].tolist()]
        d['_speed'] = speed

    def __getattr__(self, name):
        """Give back an attribute the kernel's array holds (:meth:`_sync`), once asked."""
        d = self.__dict__
        if name in _SYNCED and d.get('_stale'):
            self._sync()
            return d[name]
        raise AttributeError(f'{type(self).__name__!r} object has no attribute {name!r}')

    def _advance_compiled(self, v_a: float, v_b: float, tripped: bool) -> Optional[Report]:
        """
        Integrate the period by :func:`real_plant_kernel.step`; None: the reference takes it.

        One call: the plan, the events, the exact intervals, the carry, the switching losses,
        the temperatures, the DC link, the encoder, the measurement and the state's currents;
        then the state, its mean voltage and the period's report (the DC link's trip, the
        protection's limits near: :data:`CHECK`, else :data:`CLEAR`), the rest left in the
        array.
        """
        if not self._packed or self.x is not self._x_fast:
            self._pack()
        status = _kernel.step(self._w, self._tab, v_a, v_b, self.k, tripped, self._live.offset)
        if status == _kernel.FALLBACK or status & _kernel.NONFINITE:    # the array untouched
            self.handed_back += 1
            return None
        if not self._stale:
            self._unsync()
        o = self._w[_kernel.X0:_kernel.X0 + _kernel.N_OUT].tolist()
        x = o[:N_AUG_REAL]
        self._fo = o
        self._x_fast = x
        self.x = x
        self.v_applied = (o[_O_VAPP], o[_O_VAPP + 1])
        self.k += 1
        mdl = self.model
        f_s, f_r = o[_O_FS], o[_O_FR]
        if self.thermal is not None and (f_s != mdl.fs or f_r != mdl.fr):
            mdl.set_temperature_factors(f_s, f_r)
        if status & _kernel.TRIP_DC:
            return Report(_dc_link_trip(self.t, o[_O_VDC], self.inverter), False)
        return CHECK if status & _kernel.PROTECT else CLEAR

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
    def use_reference(self, substeps: int) -> None:
        """
        Integrate with RK4 from now on: ``substeps`` steps per constant-voltage interval.

        The fine-step reference the exact solution is checked against (tests, docs/plant.md
        §1): the same switching instants, dead bands and drops, the model's right-hand side
        (:meth:`RealMotorModel.rhs`) with the speed, saturation and iron loss acting within
        the interval.
        """
        if isinstance(substeps, bool) or not isinstance(substeps, int) or substeps < 1:
            raise ValueError(f'substeps must be a whole number >= 1 (got {substeps!r})')
        self.reference_substeps = substeps

    def advance(self, v_a: float, v_b: float, tripped: bool) -> Report:
        """
        Integrate [t_k, t_k+1] with the admitted command (module doc); report the period.

        ``tripped``: the protection has latched (the stator shorted through the inverter). The
        report: a non-finite state (the period again at zero voltage) or the DC link's
        over-voltage as a trip, else the protection's limits to check (:mod:`im_plant.engine`).
        """
        if self._w is not None and self.use_kernel and not self.reference_substeps:
            report = self._advance_compiled(v_a, v_b, tripped)
            if report is not None:
                return report
        if self._stale:
            self._sync()
        self._packed = False
        self._x_fast = None
        x0 = self.x
        t0 = self.t
        found = None
        x, v_avg = self._integrate(x0, t0, v_a, v_b, tripped)
        if not math.isfinite(sum(x)):           # a nan or an infinity anywhere
            found = (t0 + self.T_s, NON_FINITE)
            x, v_avg = self._integrate(x0, t0, 0.0, 0.0, True)
            if not all(math.isfinite(v) for v in x):
                raise diverged(t0 + self.T_s)
        self.v_applied = v_avg
        if self._k_edge:                        # the period's switching losses (module doc)
            e_sw = self._k_edge * self.V * self._edges
            x[E_INV] += e_sw
            self.E_switching += e_sw
            self.P_switching = e_sw / self.T_s
            self._poles = self._end_poles
        self._carry = self._next_carry
        self.x = x
        self.k += 1
        dc_trip = self._after_period(x0, x, tripped or found is not None)
        if found is None:
            found = dc_trip
        return CHECK if found is None else Report(found, False)

    def _integrate(self, x, t0: float, v_a: float, v_b: float, tripped: bool):
        if self.reference_substeps:
            return self._integrate_rk4(x, t0, v_a, v_b, tripped)
        T_s = self.T_s
        inv = self.inverter
        if inv is None:                         # the command itself, held: n sub-periods
            v = 0j if tripped else complex(v_a, v_b)
            n = self.n_sub
            h = T_s / n
            table = ((v,), (v.conjugate(),), (v.real * v.real + v.imag * v.imag,))
            for j in range(n):
                x, _ = self._solve(x, t0 + j * h, h, [(h, 0)], 0, table, 1.0, 0j, None, None)
            return x, (v_a, v_b) if not tripped else (0.0, 0.0)
        V = self.V
        if tripped:                             # every lower device on: the stator shorted
            self._next_carry = (0.0, 0.0, 0.0)
            return self._solve(x, t0, T_s, None, 0, None, V, 0j, None, [(T_s, (0, 0, 0))])
        d, _ = duties(v_a, v_b, V)
        half = self.k % 2 if inv.update == 'double' else 0
        if inv.deadtime > 0.0:
            t_d = inv.deadtime
            self._next_carry = (carry_after(d[0], half, inv.T_c, T_s, t_d),
                                carry_after(d[1], half, inv.T_c, T_s, t_d),
                                carry_after(d[2], half, inv.T_c, T_s, t_d))
        if inv.deadtime > 0.0 or inv.v_on > 0.0:
            # the dead bands and drops resolved by the currents' signs at the period's start;
            # if a current has another sign at an interval boundary, the period again with
            # explicit dead bands and the drops' signs taken at each interval's start
            end = self._end_current             # the last period's, if it ended here
            if end[0] is x:
                i_sa = end[1].real
                i_sb = end[1].imag
            else:
                i_sa, i_sb = self.model.stator_current(t0, x)
            i_sb *= SQRT3
            signs = (_sgn(i_sa), _sgn(i_sb - i_sa), _sgn(-i_sb - i_sa))
            if 0.0 not in signs:
                events, code = self._switching(d, half, signs)
                return self._solve(x, t0, T_s, events, code, _UNIT, V,
                                   _CLARKE[signs] * inv.v_on, signs, (d, half))
            return self._solve(x, t0, T_s, None, 0, None, V, 0j, None, self._plan(d, half))
        events, code = self._switching(d, half, (1.0, 1.0, 1.0))
        return self._solve(x, t0, T_s, events, code, _UNIT, V, 0j, None, None)

    def _plan(self, d, half: int):
        """Return the period's plan with explicit dead bands (:func:`period_plan`)."""
        inv = self.inverter
        # with on-state drops, their signs are taken again at the carrier's valley too
        extra = (0.5 * inv.T_c,) if inv.v_on > 0.0 and inv.update == 'single' else ()
        return period_plan(d, half, inv.T_c, self.T_s, inv.deadtime, extra=extra,
                           carry=self._carry)

    def _switching(self, d, half: int, signs):
        """Return :meth:`_events`, compiled with ``use_kernel`` (the events as an array)."""
        if not self.use_kernel:
            return self._events(d, half, signs)
        inv = self.inverter
        c = self._carry
        ev = self._ev
        n, code = _kernel.events(ev, d[0], d[1], d[2], half, inv.T_c, self.T_s,
                                 inv.deadtime, c[0], c[1], c[2], signs[0], signs[1], signs[2])
        return ev[:n], code

    def _events(self, d, half: int, signs):
        """
        Return the period's switching events [(t, leg bit), ..., (T_s, 0)] and the start state.

        The dead bands resolved by the phase currents' signs (as
        :func:`im_common.inverter.period_plan` with ``signs``): leg x is on in
        [t_on + t_d, t_off) for i_x > 0 and in [t_on, t_off + t_d) for i_x < 0. The start state
        is a bit mask (a: 1, b: 2, c: 4) of the legs on just after the period's start. A leg
        with i_x < 0 whose lower device is still waiting at the start (the carry,
        :func:`im_common.inverter.carry_after`) is on until it turns on.
        """
        inv = self.inverter
        T_s = self.T_s
        T_c = inv.T_c
        t_d = inv.deadtime
        single = T_s == T_c
        code = 0
        ev = []
        carry = self._carry
        for bit, dx, sg, c in ((1, d[0], signs[0], carry[0]), (2, d[1], signs[1], carry[1]),
                               (4, d[2], signs[2], carry[2])):
            if single and 0.0 < dx < 1.0:       # edges() of a single update, inline
                on0 = 0.5 * (1.0 - dx) * T_c
                on1 = 0.5 * (1.0 + dx) * T_c
                if sg > 0.0:
                    on0 += t_d
                else:
                    on1 += t_d
            else:
                t_on, t_on_end, t_off, t_off_end = edges(dx, half, T_c, T_s, t_d)
                if sg > 0.0:
                    on0, on1 = t_on_end, t_off
                else:
                    on0, on1 = t_on, t_off_end
            if c > 0.0 and sg < 0.0 and on0 > 0.0:     # on until the lower device turns on
                code |= bit
                if on1 > on0 and on0 <= c:      # ... which it never does before the pulse
                    c = on1 if on1 > c else c
                    if c < T_s:
                        ev.append((c, bit))
                    continue
                ev.append((c, bit))
            if on1 <= on0:
                continue                        # a pulse narrower than the dead time: none
            if on0 <= 0.0 < on1:
                code |= bit
            if 0.0 < on0 < T_s:
                ev.append((on0, bit))
            if 0.0 < on1 < T_s:
                ev.append((on1, bit))
        ev.sort()
        ev.append((T_s, 0))
        return ev, code

    def _solve(self, x, t0: float, T: float, events, code: int, table, V: float, drop: complex,
               signs, plan):
        """
        Integrate [t0, t0 + T] exactly between the switching instants; return (x, mean voltage).

        The electrical model over the period is the complex-linear system of docs/plant.md §1
        (the speed held at the period's predicted mid-point speed, the magnetizing slope at the
        energy chord of the predicted flux change, the iron loss's rotation offset at its
        predicted mean), so each constant-voltage interval is two complex exponentials of its
        eigenvalues, and the energy integrals come in closed form from the same solution.
        Either ``events`` (switching instants with the dead bands resolved by ``signs``, the
        pole vectors ``V·table[0][code]``, the constant drop ``drop``; when a phase current has
        another sign at an interval boundary, the period again from its start with ``plan`` =
        (duties, half) turned into :meth:`_plan`) or ``plan``
        (:func:`im_common.inverter.period_plan`: dead bands and drops by the currents' signs at
        each interval's start).

        The stages: :meth:`_predict`, the compiled kernels (:meth:`_solve_compiled`), else the
        frozen system's modes (:meth:`_modes`), the intervals (:meth:`_resolved_intervals`,
        :meth:`_explicit_intervals`) and the closed-form integrals (:meth:`_integrals`).
        """
        pred = self._predict(x, t0, T)
        (R_s, R_R, th, L_sig, ps, pr, i_s, r0, omega, theta, tau0, w00, m, kappa, w_star,
         tl) = pred
        if self.use_kernel:                     # the same from here on, compiled
            out, events, plan = self._solve_compiled(x, t0, T, events, code, table, V, drop,
                                                     signs, plan, pred)
            if out is not None:
                return out
        modes = self._modes(R_s, R_R, L_sig, m, kappa, w_star, ps, pr)
        if modes is None:                       # (nearly) repeated eigenvalues: RK4 instead
            return self._fallback(x, t0, T, events, code, table, V, drop, plan)
        z10, z20 = modes[11:13]
        lo = hi = i_s.real
        sw = 0.0
        if events is not None:
            done, lo, hi, i, sw, w1, w2, B1, B2, SU, SU2 = self._resolved_intervals(
                events, code, table, V, drop, signs, i_s, modes)
            if done:
                plan = None
            else:                               # a current changed sign: explicit dead bands
                plan = self._plan(*plan)
                drop = 0j
        if plan is None:
            g1, g2 = modes[7:9]
            z1 = w1 * g1
            z2 = w2 * g2
            B1 *= g1
            B2 *= g2
            dc = drop.conjugate()
            U1 = V * SU - drop * T
            U2 = V * V * SU2 - 2.0 * V * (dc * SU).real + (drop * dc).real * T
            B1 = V * B1 - dc * (z1 - z10)
            B2 = V * B2 - dc * (z2 - z20)
            Dd = None
        else:
            dc = None
            z1, z2, B1, B2, U1, U2, Dd, lo, hi, i, sw = self._explicit_intervals(
                plan, V, i_s, modes)
        self._edges = sw
        ps, pr1, torque, w0bar, Is2, Ir2, e_in, e_core, e_inv = self._integrals(
            x, T, R_s, R_R, m, kappa, w_star, w00, modes, z1, z2, U1, U2, B1, B2, Dd, dc)
        return self._finish(x, t0, T, r0, tau0, w00, theta, omega, w_star, tl, th, R_s, R_R,
                            lo, hi, i, ps, pr1, torque, w0bar, Is2, Ir2, e_in, e_core, e_inv,
                            U1)

    def _predict(self, x, t0: float, T: float):
        """
        Return the period's circuit and predictions (docs/plant.md §1) for :meth:`_solve`.

        (R_s, R_R, θ, L_σ, ψ_s, ψ_R, i_s, |ψ_R| at the start, ω, the angle, τ₀, ω₀₀ at the
        start, the magnetizing slope m, the iron loss's offset κ, the held speed ω*, the load
        torque at the period's middle).
        """
        mdl = self.model
        vp, J, b_f, k_h, k_e, load, sat, iron, locked, r_on = self._consts
        R_s, R_R, th, L_sig, inv_LM0 = mdl.circuit(t0 + 0.5 * T)
        ps = complex(x[0], x[1])
        pr = complex(th * x[2], th * x[3])
        i_s = (ps - pr) / L_sig
        r0 = abs(pr)
        omega = x[5]
        theta = x[4]
        # the start: ω₀ (the flux's rotation rate without iron loss) and the torque
        # v ψ_R × i_R, i_R = i_s − i_μ − i_Fe (i_μ ∥ ψ_R, i_Fe = (ω₀ − ω) j ψ_R / R_R)
        cross = pr.real * i_s.imag - pr.imag * i_s.real
        tau0 = vp * cross                       # (the iron loss's share, ~1e-4, not needed
        w00 = 0.0                               # for the torque's change between starts)
        if r0 > 1e-9:
            w00 = R_R * cross / (r0 * r0) + vp * omega
        # the period's predictions: from the start and the previous period (docs/plant.md §1)
        prev = self._prev
        if prev is not None and abs(prev[0] - t0) <= 1e-9 * T and prev[1] == T:
            r1 = 2.0 * r0 - prev[2]
            if r1 < 0.0:
                r1 = 0.0
            w0m = prev[6] + w00 - prev[4]
            tau_hat = prev[5] + tau0 - prev[3]
        else:
            r1 = r0
            w0m = w00
            tau_hat = tau0
        m = inv_LM0 if sat is None else sat.chord(r0, r1)
        kappa = 0.0
        if iron and r0 > 1e-9:
            kappa = w0m - iron_rotation(w0m, R_R, k_h, k_e)
        if locked:
            w_star = tl = 0.0
        else:
            k2 = 0.5 * T / J
            w_star = (omega + k2 * (tau_hat - load.torque(t0, theta, omega))) / (1.0 + k2 * b_f)
            tl = load.torque(t0 + 0.5 * T, theta + 0.5 * T * w_star, w_star)
        return (R_s, R_R, th, L_sig, ps, pr, i_s, r0, omega, theta, tau0, w00, m, kappa, w_star,
                tl)

    def _solve_compiled(self, x, t0, T, events, code, table, V, drop, signs, plan, pred):
        """
        Solve the period with the compiled kernels (:meth:`_solve`'s; ``pred``: its predictions).

        Return (the finished period or None, events, plan): None when the kernels hand it back,
        with the events and plan the reference then takes (a sign change: explicit dead bands;
        repeated eigenvalues: the events as a list, for :meth:`_fallback`).
        """
        (R_s, R_R, th, L_sig, ps, pr, i_s, r0, omega, theta, tau0, w00, m, kappa, w_star,
         tl) = pred
        mdl = self.model
        iron = self._consts[7]
        r_on = self._consts[9]
        if events is not None:
            ksw = self._k_edge
            unit, unitc, norm2 = _UNIT_ARRAYS if table is _UNIT else _kernel.as_table(table)
            sa, sb, sc = (0.0, 0.0, 0.0) if signs is None else signs
            k = _kernel.period(
                ps, pr, i_s, R_s, R_R, L_sig, r_on, m, kappa, self._kfloats[0], w_star, T, V,
                drop, code, _kernel.as_events(events) if type(events) is list else events,
                unit, unitc, norm2, signs is not None, sa, sb, sc, ksw,
                _edge_currents(self._poles, _POLES[code], i_s) if ksw else 0.0,
                iron, self._kfloats[1], self._kfloats[2], w00, mdl.core_loss_exponent)
            if k[0] == _kernel.DONE:
                self._end_poles = _POLES[k[1]]
                self._edges = k[2]
                return self._finish(x, t0, T, r0, tau0, w00, theta, omega, w_star, tl, th, R_s,
                                    R_R, *k[3:16]), events, plan
            if k[0] == _kernel.SIGN_CHANGE:     # explicit dead bands, as the reference
                events = None
                plan = self._plan(*plan)
            elif type(events) is not list:      # repeated eigenvalues: _fallback's events
                events = [(t_ev, int(bit)) for t_ev, bit in events.tolist()]
        if events is None:                      # explicit dead bands, compiled
            poles = self._poles
            has = poles is not None
            p0, p1, p2 = poles if has else (0.0, 0.0, 0.0)
            k = _kernel.explicit(
                ps, pr, i_s, R_s, R_R, L_sig, r_on, m, kappa, self._kfloats[0], w_star, T, V,
                float(self.inverter.v_on), _kernel.as_plan(plan), self._k_edge, has,
                float(p0), float(p1), float(p2), iron, self._kfloats[1], self._kfloats[2], w00,
                mdl.core_loss_exponent)
            if k[0] == _kernel.DONE:
                self._end_poles = k[16:19]
                self._edges = k[2]
                return self._finish(x, t0, T, r0, tau0, w00, theta, omega, w_star, tl, th, R_s,
                                    R_R, *k[3:16]), events, plan
        return None, events, plan

    def _modes(self, R_s, R_R, L_sig, m, kappa, w_star, ps, pr):
        """
        Return the modes of the period's frozen system, or None for repeated eigenvalues.

        d/dt (ψ_s, ψ_R) = [[−a, a], [c, −c − g + jw]] (ψ_s, ψ_R) + (u, 0): (a, l1, l2, c1, c2,
        b1, b2, g1, g2, s1, s2, z10, z20) as :meth:`_solve` uses them.
        """
        vp = self._consts[0]
        r_on = self._consts[9]
        a = (R_s + r_on) / L_sig
        g = R_R * m
        w = vp * w_star - kappa
        tr = complex(-a - R_R / L_sig - g, w)
        det = a * complex(g, -w)
        disc = csqrt(tr * tr - 4.0 * det)
        if tr.real * disc.real + tr.imag * disc.imag >= 0.0:
            l1 = 0.5 * (tr + disc)              # the root of the larger magnitude
        else:
            l1 = 0.5 * (tr - disc)
        l2 = det / l1
        dl = l2 - l1
        if abs(dl) <= 1e-3 * abs(l1):           # (nearly) repeated eigenvalues: RK4 instead
            return None
        inv = 1.0 / (a * dl)
        c1 = a + l1                             # ψ_R = c1 z1 + c2 z2, ψ_s = a (z1 + z2)
        c2 = a + l2
        b1 = c2 * inv                           # the input's modal components
        b2 = -c1 * inv
        g1 = -b1 / l1                           # the modes' steady state per volt
        g2 = -b2 / l2
        s1 = -l1 / L_sig                        # i_s = s1 z1 + s2 z2
        s2 = -l2 / L_sig
        z10 = (c2 * ps - a * pr) * inv
        z20 = (a * pr - c1 * ps) * inv
        return a, l1, l2, c1, c2, b1, b2, g1, g2, s1, s2, z10, z20

    def _resolved_intervals(self, events, code, table, V, drop, signs, i_s, modes):
        """
        Integrate the intervals between ``events``, the dead bands resolved by ``signs``.

        Resolved dead bands, constant drop: Σ conj(u) a = V Σ conj(û) a − conj(d) Δz; the loop
        runs on w_i = z_i/g_i (w_i → u in steady state). Return (done: False when a current
        changed sign at a boundary, lowest and highest i_sα, i_s, the edges' Σ|i_x|, w1, w2, B1,
        B2, Σû h, Σ|û|² h); done: the end poles set.
        """
        a, l1, l2, c1, c2, b1, b2, g1, g2, s1, s2, z10, z20 = modes
        exp = cexp
        lo = hi = i_s.real
        ksw = self._k_edge
        sw = 0.0
        unit, unitc, norm2 = table
        B1 = B2 = SU = 0j
        SU2 = 0.0
        check = signs is not None
        if check:
            sa, sb, sc = signs
        sq3 = SQRT3
        w1 = z10 / g1
        w2 = z20 / g2
        t1 = s1 * g1                            # i_s = t1 w1 + t2 w2
        t2 = s2 * g2
        tp = 0.0
        i = i_s
        if ksw:                                 # a leg's state at the start against the end
            sw = _edge_currents(self._poles, _POLES[code], i_s)
        for t_ev, bit in events:
            h = t_ev - tp
            if h > 1e-15:
                u = V * unit[code] - drop
                a1 = (w1 - u) * (exp(l1 * h) - 1.0)
                a2 = (w2 - u) * (exp(l2 * h) - 1.0)
                w1 += a1
                w2 += a2
                n2 = norm2[code]
                if n2:
                    uc = unitc[code]
                    B1 += uc * a1
                    B2 += uc * a2
                    SU += unit[code] * h
                    SU2 += n2 * h
                i = t1 * w1 + t2 * w2
                ir = i.real
                if check:
                    ii = sq3 * i.imag
                    if ir * sa <= 0.0 or (ii - ir) * sb <= 0.0 or (-ii - ir) * sc <= 0.0:
                        return False, lo, hi, i, sw, w1, w2, B1, B2, SU, SU2
                if ir < lo:
                    lo = ir
                elif ir > hi:
                    hi = ir
                tp = t_ev
            if ksw and bit:                     # the edge at t_ev, with the current there
                sw += _leg_current(i, bit)
            code ^= bit
        self._end_poles = _POLES[code]
        return True, lo, hi, i, sw, w1, w2, B1, B2, SU, SU2

    def _explicit_intervals(self, plan, V, i_s, modes):
        """
        Integrate the intervals of an explicit ``plan`` from the period's start.

        Explicit dead bands: each takes its leg's current sign at the band's start, as do the
        drops at each interval's start. Return (z1, z2, B1, B2, U1, U2, Dd = ∫ conj(d) i_s,
        lowest and highest i_sα, i_s, the edges' Σ|i_x|); the end poles set.
        """
        a, l1, l2, c1, c2, b1, b2, g1, g2, s1, s2, z1, z2 = modes
        exp = cexp
        lo = hi = i_s.real
        ksw = self._k_edge
        v_on = self.inverter.v_on
        B1 = B2 = U1 = Dd = 0j
        U2 = 0.0
        i = i_s
        sw = 0.0
        poles = self._poles
        for h, states in plan:
            ir = i.real
            ii = SQRT3 * i.imag
            ib = ii - ir
            ic = -ii - ir
            sg = (1.0 if ir > 0.0 else (-1.0 if ir < 0.0 else 0.0),
                  1.0 if ib > 0.0 else (-1.0 if ib < 0.0 else 0.0),
                  1.0 if ic > 0.0 else (-1.0 if ic < 0.0 else 0.0))
            if None in states:
                states = tuple(s if s is not None else _DIODE[q] for s, q in zip(states, sg))
            if ksw:
                sw += _edge_currents(poles, states, i)
            poles = states
            dk = v_on * _CLARKE[sg] if v_on > 0.0 else 0j
            u = V * _CLARKE[states] - dk
            a1 = (z1 - g1 * u) * (exp(l1 * h) - 1.0)
            a2 = (z2 - g2 * u) * (exp(l2 * h) - 1.0)
            uc = u.conjugate()
            B1 += uc * a1
            B2 += uc * a2
            U1 += u * h
            U2 += (u * uc).real * h
            if dk:
                Dd += dk.conjugate() * (s1 * (g1 * u * h + a1 / l1)
                                        + s2 * (g2 * u * h + a2 / l2))
            z1 += a1
            z2 += a2
            i = s1 * z1 + s2 * z2
            ir = i.real
            if ir < lo:
                lo = ir
            elif ir > hi:
                hi = ir
        self._end_poles = poles
        return z1, z2, B1, B2, U1, U2, Dd, lo, hi, i, sw

    def _integrals(self, x, T, R_s, R_R, m, kappa, w_star, w00, modes, z1, z2, U1, U2, B1, B2,
                   Dd, dc):
        """
        Return the period's integrals in closed form (docs/plant.md §1) for :meth:`_solve`.

        The modes' first moments and, from d/dt (z_i conj z_j) integrated over the period,
        their second moments; ``Dd`` None: ∫ conj(d) i_s from the constant drop's ``dc``.
        Return (ψ_s, ψ_R at the end, ∫τ, the mean rotation rate, ∫|i_s|², ∫|i_R|², E_in,
        E_core, E_inv).
        """
        vp, _, _, k_h, k_e, _, _, iron, _, r_on = self._consts
        a, l1, l2, c1, c2, b1, b2, g1, g2, s1, s2, z10, z20 = modes
        X1 = g1 * U2 + B1 / l1                  # Σ conj(u) ∫ z_i
        X2 = g2 * U2 + B2 / l2
        M11 = (z1.real * z1.real + z1.imag * z1.imag - z10.real * z10.real
               - z10.imag * z10.imag - 2.0 * (b1.real * X1.real + b1.imag * X1.imag)
               ) / (2.0 * l1.real)
        M22 = (z2.real * z2.real + z2.imag * z2.imag - z20.real * z20.real
               - z20.imag * z20.imag - 2.0 * (b2.real * X2.real + b2.imag * X2.imag)
               ) / (2.0 * l2.real)
        M12 = (z1 * z2.conjugate() - z10 * z20.conjugate() - b1 * X2.conjugate()
               - b2.conjugate() * X1) / (l1 + l2.conjugate())
        M21 = M12.conjugate()
        # ∫ conj(F) G for F, G = F1 z1 + F2 z2, ...: Σ conj(F_i) G_j ∫ conj(z_i) z_j
        f1 = s1.conjugate()
        f2 = s2.conjugate()
        Is2 = ((f1 * s1).real * M11 + (f2 * s2).real * M22 + 2.0 * (s1 * f2 * M12).real)
        mu = complex(m, kappa / R_R)            # i_R = i_s − μ ψ_R
        q1 = s1 - mu * c1
        q2 = s2 - mu * c2
        Ir2 = ((q1 * q1.conjugate()).real * M11 + (q2 * q2.conjugate()).real * M22
               + 2.0 * (q1 * q2.conjugate() * M12).real)
        k1 = c1.conjugate()
        k2 = c2.conjugate()
        torque = vp * (k1 * q1 * M11 + k2 * q2 * M22 + k1 * q2 * M21 + k2 * q1 * M12).imag
        e_in = (s1 * X1 + s2 * X2).real - r_on * Is2
        ps = a * (z1 + z2)
        if Dd is None:                          # ∫ i_s = (∫ u − Δψ_s)/(R_s + r_on)
            Dd = dc * (U1 - ps + complex(x[0], x[1])) / (R_s + r_on)
        e_inv = r_on * Is2 + Dd.real            # ∫ conj(d) i_s
        e_core = 0.0
        w0bar = w00
        if iron or k_h or k_e:
            P2 = (c1 * k1).real * M11 + (c2 * k2).real * M22 + 2.0 * (c1 * k2 * M12).real
            # ∫ ψ_R × dψ_R/dt, with dψ_R/dt = R_R i_R + j v ω* ψ_R
            rot = R_R * torque / vp + vp * w_star * P2
            if P2 > 1e-18 * T:
                w0bar = rot / P2 + kappa        # the period's mean rotation rate without loss
            if iron:
                e_core = kappa * rot / R_R
            elif P2 > 1e-18 * T:                # booked: (k_h + k_e f) f |ψ_R|^n
                f = abs(rot) / (TWO_PI * P2)
                e_core = (k_h + k_e * f) * f * (
                    P2 if self.model.core_loss_exponent == 2.0 else math.sqrt(P2 * T))
        return ps, c1 * z1 + c2 * z2, torque, w0bar, Is2, Ir2, e_in, e_core, e_inv

    def _finish(self, x, t0, T, r0, tau0, w00, theta, omega, w_star, tl, th, R_s, R_R, lo, hi,
                i, ps, pr, torque, w0bar, Is2, Ir2, e_in, e_core, e_inv, U1):
        """Return :meth:`_solve`'s (x, mean voltage) from the period's solution and integrals."""
        _, J, b_f, _, _, _, _, _, locked, _ = self._consts
        # the shaft: momentum with the period's mean torque, the work at the held speed
        if locked:
            omega1 = omega
            theta1 = theta
            e_fric = w_load = 0.0
        else:
            omega1 = omega + (torque - T * (b_f * w_star + tl)) / J
            theta1 = theta + 0.5 * T * (omega + omega1)
            e_fric = T * b_f * w_star * w_star
            w_load = T * tl * w_star
        self._prev = (t0 + T, T, r0, tau0, w00, torque / T, w0bar)
        if self.inverter is not None:
            self.ripple = SQRT_2_3 * (hi - lo)
        out = [ps.real, ps.imag, pr.real / th, pr.imag / th, theta1, omega1,
               x[6] + e_in, x[7] + R_s * Is2, x[8] + R_R * Ir2, x[9] + e_core, x[10] + e_fric,
               x[11] + w_load, x[12], x[13] + e_inv]
        self._end_current = (out, i)            # i_s at the end: the next period's start
        return out, (U1.real / T, U1.imag / T)

    def _fallback(self, x, t0, T, events, code, table, V, drop, plan):
        """Integrate the period by RK4 (one step per interval): repeated eigenvalues (rare)."""
        model = self.model
        inv = self.inverter
        t = t0
        mean = 0j
        if events is not None:
            plan = []
            tp = 0.0
            for t_ev, bit in events:
                if t_ev - tp > 1e-15:
                    plan.append((t_ev - tp, table[0][code], _POLES[code]))
                    tp = t_ev
                code ^= bit
        ksw = self._k_edge
        sw = 0.0
        poles = self._poles
        for h, states, *held in plan:
            if held:                            # the events' (resolved) states, their vector
                u = V * states
                dk = drop
                states = held[0]
            else:
                i_sa, i_sb = model.stator_current(t, x)
                sg = tuple(_sgn(q) for q in phase_values(i_sa, i_sb))
                if None in states:
                    states = tuple(s if s is not None else _DIODE[q]
                                   for s, q in zip(states, sg))
                u = V * complex(*clarke(*states))
                dk = inv.v_on * complex(*clarke(*sg)) if inv is not None else 0j
            if ksw:
                sw += _edge_currents(poles, states, complex(*model.stator_current(t, x)))
            poles = states
            u -= dk
            model.drop = (dk.real, dk.imag)
            x = model.rk4(t, x, h, u.real, u.imag)
            t += h
            mean += u * h
        model.drop = (0.0, 0.0)
        self._edges = sw
        self._end_poles = poles
        return x, (mean.real / T, mean.imag / T)

    # The fine-step reference: RK4 between the same instants ------------------------------
    def _integrate_rk4(self, x, t0: float, v_a: float, v_b: float, tripped: bool):
        T_s = self.T_s
        rk4 = self.model.rk4
        inv = self.inverter
        n_ref = self.reference_substeps
        if inv is None:
            if tripped:
                v_a = v_b = 0.0
            n = self.n_sub * n_ref
            h = T_s / n
            for j in range(n):
                x = rk4(t0 + j * h, x, h, v_a, v_b)
            return x, (v_a, v_b)
        if tripped:                             # every lower device on: the stator shorted
            self._next_carry = (0.0, 0.0, 0.0)
            return self._run_plan(x, t0, [(T_s, (0, 0, 0))], None)
        d, _ = duties(v_a, v_b, self.V)
        half = self.k % 2 if inv.update == 'double' else 0
        extra = (0.5 * inv.T_c,) if inv.v_on > 0.0 and inv.update == 'single' else ()
        if inv.deadtime > 0.0:
            t_d = inv.deadtime
            self._next_carry = (carry_after(d[0], half, inv.T_c, T_s, t_d),
                                carry_after(d[1], half, inv.T_c, T_s, t_d),
                                carry_after(d[2], half, inv.T_c, T_s, t_d))
            ph = phase_values(*self.model.stator_current(t0, x))
            signs = tuple(_sgn(i) for i in ph)
            if 0.0 not in signs:
                plan = period_plan(d, half, inv.T_c, T_s, inv.deadtime, signs, extra,
                                   self._carry)
                out = self._run_plan(x, t0, plan, signs)
                if out is not None:
                    return out
        plan = period_plan(d, half, inv.T_c, T_s, inv.deadtime, extra=extra, carry=self._carry)
        return self._run_plan(x, t0, plan, None)

    def _run_plan(self, x, t0: float, plan, signs):
        """
        Integrate the period's intervals in order by RK4; return (x, mean voltage).

        With ``signs`` (the dead bands resolved by them), None when a phase current's sign at an
        interval boundary differs from its assumed sign.
        """
        T_s = self.T_s
        model = self.model
        rk4 = model.rk4
        V = self.V
        v_on = self.inverter.v_on
        sv = self._sv
        n = self.reference_substeps
        t = t0
        sa = sb = 0.0
        lo = math.inf
        hi = -math.inf
        sw = 0.0
        poles = self._poles
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
            sw += _edge_currents(poles, states, complex(i_sa, i_sb))
            poles = states
            ua, ub = sv[states] if states in sv else clarke(*states)
            va, vb = V * ua, V * ub
            if v_on > 0.0:
                da, db = clarke(_sgn(ph[0]), _sgn(ph[1]), _sgn(ph[2]))
                da *= v_on
                db *= v_on
                model.drop = (da, db)
                va -= da
                vb -= db
            h = length / n
            for _ in range(n):
                x = rk4(t, x, h, va, vb)
                t += h
            sa += va * length
            sb += vb * length
        model.drop = (0.0, 0.0)
        i_sa, i_sb = model.stator_current(t, x)
        ph = phase_values(i_sa, i_sb)
        if signs is not None and (ph[0] * signs[0] <= 0.0 or ph[1] * signs[1] <= 0.0
                                  or ph[2] * signs[2] <= 0.0):
            return None
        self.ripple = max(hi, ph[0]) - min(lo, ph[0])
        self._edges = sw
        self._end_poles = poles
        return x, (sa / T_s, sb / T_s)

    def _after_period(self, x0, x, tripped: bool):
        """
        Step the temperatures, the DC link and the encoder over the period from x0 to x.

        Return the DC link's over-voltage trip (None: none, or ``tripped`` already).
        """
        T_s = self.T_s
        dc_trip = None
        th = self.thermal
        if th is not None:
            p_s = x[E_CU_S] - x0[E_CU_S]
            if self.iron_loss:
                p_s += x[E_CORE] - x0[E_CORE]
            p_r = (x[E_CU_R] - x0[E_CU_R]) / T_s
            ds, dr = self._decay
            T_st = first_order(self.temps[0], th.T_ambient, th.R_th_s, p_s / T_s, ds)
            T_rt = first_order(self.temps[1], th.T_ambient, th.R_th_r, p_r, dr)
            self.temps = [T_st, T_rt]
            self.model.set_temperature_factors(*th.resistance_factors(T_st, T_rt))
        inv = self.inverter
        if inv is not None:
            e_inv = x[E_INV] - x0[E_INV]
            self.P_inverter = e_inv / T_s
            e_dc = x[E_IN] - x0[E_IN] + e_inv
            C_dc = inv.C_dc
            if C_dc > 0:
                V = self.V
                e_src = (inv.V_dc - V) / inv.R_source * V * T_s if V < inv.V_dc else 0.0
                e_ch = (V * V / inv.R_chopper * T_s
                        if inv.V_chopper > 0 and V > inv.V_chopper else 0.0)
                self.E_source += e_src
                self.E_chopper += e_ch
                w = 0.5 * C_dc * V * V + e_src - e_ch - e_dc
                self.V = math.sqrt(2.0 * w / C_dc) if w > 0.0 else 0.0
                if not tripped and self.V > inv.trip_voltage:
                    dc_trip = _dc_link_trip(self.t, self.V, inv)
            else:
                self.E_source += e_dc
        if self._speed is not None:
            self._omega_meas = self._speed.update(self.sensors.count(x[4]))
        return dc_trip

    # Outputs -----------------------------------------------------------------------------
    def stator_currents(self):
        """Return (i_sα, i_sβ) at t_k (the last period's solution gives it)."""
        x = self.x
        if x is self._x_fast:                   # a compiled period's
            o = self._fo
            return o[_O_IEND], o[_O_IEND + 1]
        if self._stale:
            self._sync()
        end = self._end_current
        if end[0] is x:
            return end[1].real, end[1].imag
        return self.model.stator_current(self.t, x)

    def state_currents(self):
        """Return (i_sα, i_sβ, i_rα, i_rβ) at t_k (the rotor current in the model's gauge)."""
        x = self.x
        if x is self._x_fast:                   # a compiled period's
            o = self._fo
            return tuple(o[_O_ISTATE:_O_ISTATE + 4])
        if self._stale:
            self._sync()
        cached = self._currents
        if cached[0] is x:                      # the same state: computed once a period
            return cached[1]
        t = self.t
        i_sa, i_sb, i_Ra, i_Rb = self.model.currents(t, x)
        th = self.model.circuit(t)[2]
        out = (i_sa, i_sb, -th * i_Ra, -th * i_Rb)
        self._currents = (x, out)
        return out

    def measure(self) -> Measurement:
        """
        Return what the sensors give at t_k, the carrier's peak (im_plant.sensors).

        Without the measurement noise: the simulator adds it (PlantSimulator.measure).
        """
        x = self.x
        if x is self._x_fast:                   # a compiled period's
            o = self._fo
            m = _O_MEAS                         # i_sα, i_sβ, θ, ω, V_dc
            return Measurement(self.t, o[m], o[m + 1], o[m + 2], o[m + 3], o[m + 4])
        if self._stale:
            self._sync()
        i_sa, i_sb = self.stator_currents()
        theta = x[4]
        omega = x[5]
        se = self.sensors
        v_dc = self.V
        if se is not None:
            i_sa, i_sb = clarke(*se.phase_currents(*phase_values(i_sa, i_sb)))
            if se.encoder_lines > 0:
                theta = se.count(theta) * TWO_PI / se.counts_per_rev
                omega = self._omega_meas
            if self.inverter is not None:
                v_dc = se.adc(v_dc, 0.0, se.vdc_range)
        return Measurement(self.t, i_sa, i_sb, theta, omega, v_dc)

    def truth(self, trip) -> dict:
        """Return the ground truth with the latched ``trip``: the ideal keys and the blocks'."""
        if self._stale:
            self._sync()
        t = self.t
        x = self.x
        v_a, v_b = self.v_applied
        out = self.model.outputs(t, x)
        d = self.model.rhs(t, x, v_a, v_b)
        out.update({
            'v_alpha': v_a, 'v_beta': v_b,
            'P_in': d[E_IN], 'P_cu_s': d[E_CU_S], 'P_cu_r': d[E_CU_R], 'P_core': d[E_CORE],
            'P_friction': d[10], 'P_load': d[11], 'P_param': d[12],
            'E_in': x[E_IN], 'E_cu_s': x[E_CU_S], 'E_cu_r': x[E_CU_R], 'E_core': x[E_CORE],
            'E_friction': x[10], 'W_load': x[11], 'E_param': x[12], 'E_inv': x[E_INV],
        })
        if self.inverter is not None:
            out['E_switching'] = self.E_switching
        add_trip(out, trip)
        out['dW_mag'] = out['W_mag'] - self.W_mag0
        out['dE_kin'] = out['E_kin'] - self.E_kin0
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
                        'P_switching': self.P_switching,
                        'E_source': self.E_source, 'E_chopper': self.E_chopper,
                        'dW_cap': w_cap - self.W_cap0})
            out['balance_residual_dc'] = (self.E_source - self.E_chopper - out['dW_cap']
                                          - out['E_in'] - out['E_inv'])
        return out
