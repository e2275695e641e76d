"""
Scenario → node parameters.

The one mapping used by the scenario runner, the launch YAML, the benchmarks and the tests (seed
000 §3.4: motor, tasks, loads, gains).

``node_parameters(...)`` returns ``{node: {parameter: value}}``, the structure of a ROS 2
parameters YAML (``ros__parameters`` added by :func:`to_yaml`).
"""
from __future__ import annotations

from typing import Dict, List, Optional, Sequence

from im_common.yamlio import parameters_yaml
from im_controller.flux import STRATEGIES  # noqa: F401 (re-exported; the one home of the names)

# The task presets and the controller vocabulary live with the run description
# (im_bringup.run_file), which reads them; imported here under their familiar names.
from .run_file import (ADAPTATION, CONTROLLER_LIMITS, CONTROLLERS,  # noqa: F401
                       motor_parameters, PLANT_PROTECTION, Scenario, TASK_PRESETS, TASKS,
                       TORQUE_NEEDS_PROFILE)


def node_parameters(task: str = 'position', strategy: str = 'min_energy',
                    controller: str = 'nominal', variation='none', T_s: float = 1e-4,
                    duration: Optional[float] = None, v_limit: float = 0.0,
                    current_gain: Optional[Sequence[float]] = None,
                    injection_gain: Optional[Sequence[float]] = None,
                    truth_decimation: int = 10, reference_decimation: int = 10,
                    input_timeout: float = 5.0, *, motor=None, estimates=None, profile=None,
                    load=None, limits: Optional[dict] = None,
                    protection: Optional[dict] = None,
                    sensorless: bool = False) -> Dict[str, Dict[str, object]]:
    """
    Return the parameters of the four nodes for one scenario, by keywords.

    The :class:`im_bringup.run_file.Scenario` of them and its
    :meth:`~im_bringup.run_file.Scenario.node_parameters` (the one mapping).

    ``motor``/``estimates``/``profile``/``load``: file path or object; ``limits``: controller
    limits (:data:`CONTROLLER_LIMITS`), ``protection``: plant inverter rating and trips
    (:data:`PLANT_PROTECTION`). A bad value is one ValueError naming it.
    """
    limits = dict(limits or {})
    protection = dict(protection or {})
    for key in limits:
        if key not in CONTROLLER_LIMITS:
            raise ValueError(f"invalid limit {key!r}: one of {', '.join(CONTROLLER_LIMITS)}")
    for key in protection:
        if key not in PLANT_PROTECTION:
            raise ValueError(f"invalid protection {key!r}: one of {', '.join(PLANT_PROTECTION)}")
    direct = {k: v for k, v in limits.items()
              if k in ('torque_limit', 'current_limit', 'speed_limit') and v}
    options = {k: v for k, v in limits.items() if k not in direct and v is not None}
    sc = Scenario(task=task, strategy=strategy, controller=controller, variation=variation,
                  T_s=T_s, duration=duration, v_limit=v_limit or None,
                  current_gain=None if current_gain is None else list(current_gain),
                  observer_gain=None if injection_gain is None else list(injection_gain),
                  motor=motor, estimates=estimates, profile=profile, load_model=load,
                  sensorless=sensorless, controller_options=options,
                  **direct, **{k: v for k, v in protection.items() if v})
    return sc.node_parameters(truth_decimation, reference_decimation, input_timeout)


def to_yaml(parameters: Dict[str, Dict[str, object]], use_sim_time: bool = True) -> str:
    """Return a ROS 2 parameters file (``--params-file``) for the given node parameters."""
    doc = {}
    for node, values in parameters.items():
        vals = dict(values)
        if use_sim_time and node != 'plant':
            vals['use_sim_time'] = True
        doc[node] = vals
    return parameters_yaml(doc)


def run_nodes(parameters: Dict[str, Dict[str, object]]) -> List[str]:
    """
    Return the drive nodes of a run with these parameters, the plant first.

    The adapter is one only when the controller uses its estimates (``use_adapter``): the
    processes of a run start no other, and a recording holds the parameters of these alone.
    """
    adaptive = bool(parameters.get('controller', {}).get('use_adapter', False))
    return ['plant', 'controller', 'observer'] + (['adapter'] if adaptive else [])
