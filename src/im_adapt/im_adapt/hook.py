"""
The adapter as a hook of the offline closed loop (``im_bringup.offline.simulate(adapter=...)``).

ROS-free. :class:`LockstepAdapter` gives a :class:`~im_adapt.adaptation.ParameterAdapter` the
``step(T_s, t, v_alpha, v_beta, meas, x_hat) -> dict`` interface of the offline loop and records
the estimates for analysis.

Lock-step order (docs/architecture.md, "Lock-step protocol"): at step k the adapter uses V_k, i_k,
ω_k and the observer's x̂_k and produces p̂_k+1, used by the controller and the observer at step
k+1 — what the adapter node does with the topics stamped t_k. The offline loop hands the hook x̂_k
(the observer's state before its own step k).
"""
from __future__ import annotations

from dataclasses import fields
from typing import Mapping, Optional

from im_common.node_params import block_from_parameters
from im_common.thermal import Thermal

from .adaptation import AdaptationGains, ParameterAdapter


class LockstepAdapter:
    """
    Offline-loop hook around :class:`ParameterAdapter`.

    Parameters
    ----------
    adapter : ParameterAdapter
    record_every : int
        Keep one estimate sample every this many steps (0: keep none): (R_r, θ, L_M, R_R, L_σ,
        R_s) at ``t``.

    """

    def __init__(self, adapter: ParameterAdapter, record_every: int = 10):
        self.adapter = adapter
        self.record_every = int(record_every)
        self.k = 0
        self.t = []
        self.samples = []

    @classmethod
    def build(cls, params, gains: Optional[AdaptationGains] = None, R_r0: Optional[float] = None,
              theta0: Optional[float] = None, record_every: int = 10, sensorless: bool = False,
              thermal=None):
        """
        Adapter with the given gains (default: :class:`AdaptationGains`) from ``params``.

        ``sensorless``: the speed it is given is the observer's ω̂ (R̂_R held; with the motor's
        ``thermal`` block, at the cage's estimated temperature).
        """
        gains = gains if gains is not None else AdaptationGains()
        ad = ParameterAdapter(params, gains, params.R_r if R_r0 is None else R_r0,
                              params.theta if theta0 is None else theta0, sensorless=sensorless,
                              thermal=thermal)
        return cls(ad, record_every)

    @classmethod
    def from_node_parameters(cls, params, values: Mapping, record_every: int = 10):
        """
        Return the adapter the adapter node builds from its parameters ``values``.

        ``params``: its model (the drive's estimates). The gains' fields, ``R_r_initial``,
        ``theta_initial``, ``sensorless`` and ``thermal_tracking`` with the motor file's
        ``thermal`` block, as the node reads them (``im_adapt.adapter_node``); what is not in
        ``values`` is the node's default. Compensation and delay are the loop's (the voltage it
        hands :meth:`step` is the one the motor got).
        """
        names = {f.name for f in fields(AdaptationGains)}
        gains = AdaptationGains(**{k: v for k, v in values.items() if k in names})
        thermal = None
        if values.get('thermal_tracking'):
            thermal = block_from_parameters(Thermal, values, 'thermal')     # thermal.*
        return cls.build(params, gains, R_r0=values.get('R_r_initial'),
                         theta0=values.get('theta_initial'), record_every=record_every,
                         sensorless=bool(values.get('sensorless')), thermal=thermal)

    def step(self, T_s, t, v_alpha, v_beta, meas, x_hat) -> dict:
        """Update the adapter with the data of step k (and the observer's x̂_k); return p̂_k+1."""
        self.adapter.update(T_s, v_alpha, v_beta, meas.i_alpha, meas.i_beta, meas.omega_r,
                            x_hat[2], x_hat[3])
        est = self.adapter.estimates()
        self.k += 1
        if self.record_every and self.k % self.record_every == 0:
            self.t.append(t + T_s)
            self.samples.append((est['R_r'], est['theta'], est['L_M'], est['R_R'],
                                 est.get('L_sigma', float('nan')), self.adapter.R_s))
        return est
