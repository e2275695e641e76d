"""
The plant's engine: what integrates the motor over one control period (docs/architecture.md).

:class:`im_plant.plant_sim.PlantSimulator` is built from parts: it keeps the command's way to
the motor (the delay line, the checks of a command, the inverter's rating, ``v_limit``), the
protection's latch ``trip`` and its limits, the load's live offset and the measurement noise, and
hands each period's applied voltage to its *engine*, the one object that owns the motor model,
the state vector ``x`` and the period index ``k`` (the state is at t_k = k·T_s). Two engines
have the interface :class:`PlantEngine`:

- :class:`IdealPlant` (here): :class:`im_common.model.MotorModel` integrated by fixed-step RK4
  sub-steps, the energy integrals with it;
- :class:`im_plant.real_plant.RealPlant`: the real plant's blocks (inverter, saturation,
  thermal, sensors, iron loss) around :class:`im_common.model.RealMotorModel`.

An engine never sees the simulator: it is given what it needs when it is made (the model's
configuration, T_s, the sub-steps, the initial state; the real plant the protection's limits
too) and reports back by :meth:`PlantEngine.advance`'s :class:`Report` (a trip its physics
latched: a non-finite state, the DC link; whether the protection's limits must be checked),
which the simulator latches.
"""
from __future__ import annotations

import math
from typing import List, NamedTuple, Optional, Protocol, Sequence, Tuple

from im_common.model import (currents, E_CORE, E_CU_R, E_CU_S, E_FRICTION, E_IN, E_PARAM,
                             MotorModel, N_AUG, rk4_step, W_LOAD)

from .sensors import Measurement

#: a latched trip: (t [s], reason)
Trip = Tuple[float, str]
#: the reason of the trip an engine latches when a period leaves the state non-finite
NON_FINITE = 'non-finite state'


class Report(NamedTuple):
    """What an engine's period reports to the simulator (:meth:`PlantEngine.advance`)."""

    trip: Optional[Trip]    # a trip the period's physics latched (None: none)
    check: bool             # the protection's limits may be crossed: the simulator checks them


#: no trip; the simulator checks its limits (overcurrent, overspeed) at the new t_k
CHECK = Report(None, True)
#: no trip, and the limits are known not to be crossed (the compiled real plant's period)
CLEAR = Report(None, False)


class PlantEngine(Protocol):
    """
    What integrates the motor over a period: the state at t_k and the period's step.

    ``model`` the motor model it integrates, ``x`` its state at t_k (the model's augmented
    vector), ``k`` the period index, ``T_s`` the period [s], ``n_sub`` the RK4 sub-steps of a
    period, ``v_applied`` the (mean) voltage applied over the last period, ``W_mag0`` and
    ``E_kin0`` the stored energies at t_0 (the truth's energy balance).
    """

    model: object
    x: List[float]
    k: int
    T_s: float
    n_sub: int
    v_applied: Tuple[float, float]
    W_mag0: float
    E_kin0: float

    @property
    def t(self) -> float:
        """Return t_k = k·T_s [s]."""

    def advance(self, v_a: float, v_b: float, tripped: bool) -> Report:
        """
        Integrate [t_k, t_k+1] with the admitted voltage (v_a, v_b); then k += 1.

        ``tripped``: the protection has latched (the inverter in its safe state). Raises
        FloatingPointError when the state is non-finite even at zero voltage.
        """

    def state_currents(self) -> Tuple[float, float, float, float]:
        """Return (i_sα, i_sβ, i_rα, i_rβ) at t_k."""

    def stator_currents(self) -> Tuple[float, float]:
        """Return (i_sα, i_sβ) at t_k: the currents the protection watches."""

    def measure(self) -> Measurement:
        """Return what the sensors give at t_k, without the simulator's measurement noise."""

    def truth(self, trip: Optional[Trip]) -> dict:
        """Return the ground truth at t_k with the simulator's latched ``trip``."""


def augmented(x0: Sequence[float], n: int) -> List[float]:
    """Return the n-element augmented state of the start ``x0`` (its energy integrals zero)."""
    return [float(v) for v in x0] + [0.0] * (n - len(x0))


def diverged(t: float) -> FloatingPointError:
    """Return the error of a state non-finite at ``t`` even at zero voltage."""
    return FloatingPointError(f'plant state became non-finite at t = {t:.9f} s '
                              'even at zero voltage')


def add_trip(out: dict, trip: Optional[Trip]) -> None:
    """Add the latched ``trip``'s keys (``tripped``, ``trip_t``, ``trip_reason``) to a truth."""
    out['tripped'] = 0.0 if trip is None else 1.0
    out['trip_t'] = math.nan if trip is None else trip[0]
    out['trip_reason'] = '' if trip is None else trip[1]


class IdealPlant:
    """
    The ideal plant's engine: :class:`MotorModel` by fixed-step RK4 (module doc).

    Each period is ``n_sub`` equal RK4 sub-steps with the voltage held; a non-finite state is
    not kept: the period is integrated again from the last finite state at zero voltage (and
    reported as a trip).
    """

    def __init__(self, model: MotorModel, T_s: float, n_sub: int, x0: Sequence[float]):
        self.model = model
        self.T_s = T_s
        self.n_sub = n_sub
        self.h = T_s / n_sub
        self.k = 0
        self.x = augmented(x0, N_AUG)
        self.v_applied = (0.0, 0.0)
        out = model.outputs(0.0, self.x)
        self.W_mag0 = out['W_mag']
        self.E_kin0 = out['E_kin']

    @property
    def t(self) -> float:
        """Return t_k = k·T_s [s] (an exact multiple, no accumulated round-off)."""
        return self.k * self.T_s

    def advance(self, v_a: float, v_b: float, tripped: bool) -> Report:
        """Integrate [t_k, t_k+1] with (v_a, v_b) held (zero already when ``tripped``)."""
        x0 = self.x
        t0 = self.t
        x = self._integrate(x0, t0, v_a, v_b)
        report = CHECK
        if not all(map(math.isfinite, x)):
            report = Report((t0 + self.T_s, NON_FINITE), False)
            v_a = v_b = 0.0
            x = self._integrate(x0, t0, 0.0, 0.0)
            if not all(math.isfinite(v) for v in x):
                raise diverged(t0 + self.T_s)
        self.v_applied = (v_a, v_b)
        self.x = x
        self.k += 1
        return report

    def _integrate(self, x, t0: float, v_a: float, v_b: float):
        f = self.model.rhs
        h = self.h
        for j in range(self.n_sub):
            x = rk4_step(f, t0 + j * h, x, h, v_a, v_b)
        return x

    def stator_currents(self):
        """Return (i_sα, i_sβ) at t_k."""
        i_sa, i_sb, _, _ = self.state_currents()
        return i_sa, i_sb

    def state_currents(self):
        """Return (i_sα, i_sβ, i_rα, i_rβ) at t_k."""
        R_s, R_r, L_s, L_r, L_sr = self.model.schedule.values(self.t)
        return currents(self.x[0], self.x[1], self.x[2], self.x[3], L_s, L_r, L_sr)

    def measure(self) -> Measurement:
        """Return the stator currents and the shaft's position and speed at t_k, exact."""
        i_sa, i_sb, _, _ = self.state_currents()
        return Measurement(self.t, i_sa, i_sb, self.x[4], self.x[5])

    def truth(self, trip: Optional[Trip]) -> dict:
        """Return the true state, torques, parameters, power and energy books at t_k."""
        t = self.t
        x = self.x
        out = self.model.outputs(t, x)
        d = self.model.rhs(t, x, self.v_applied[0], self.v_applied[1])
        out.update({
            'v_alpha': self.v_applied[0], 'v_beta': self.v_applied[1],
            'P_in': d[E_IN], 'P_cu_s': d[E_CU_S], 'P_cu_r': d[E_CU_R], 'P_core': d[E_CORE],
            'P_friction': d[E_FRICTION], 'P_load': d[W_LOAD], 'P_param': d[E_PARAM],
            'E_in': x[E_IN], 'E_cu_s': x[E_CU_S], 'E_cu_r': x[E_CU_R], 'E_core': x[E_CORE],
            'E_friction': x[E_FRICTION], 'W_load': x[W_LOAD], 'E_param': x[E_PARAM],
        })
        add_trip(out, trip)
        out['dW_mag'] = out['W_mag'] - self.W_mag0
        out['dE_kin'] = out['E_kin'] - self.E_kin0
        out['balance_residual'] = (out['E_in'] - out['E_cu_s'] - out['E_cu_r'] - out['E_friction']
                                   - out['W_load'] - out['E_param'] - out['dW_mag']
                                   - out['dE_kin'])
        return out
