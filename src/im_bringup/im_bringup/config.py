"""Scenario → node parameters: the one mapping used by the scenario runner, the launch YAML,
the benchmarks and the tests (seed 000 §3.4: motor, tasks, loads, gains).

``node_parameters(...)`` returns ``{node: {parameter: value}}``, the structure of a ROS 2
parameters YAML (``ros__parameters`` added by :func:`to_yaml`).
"""
from __future__ import annotations

import math
from typing import Dict, Optional, Sequence

TASKS = ('position', 'speed')
STRATEGIES = ('min_energy', 'constant_flux', 'min_loss')
CONTROLLERS = ('nominal', 'adaptive_thesis', 'adaptive', 'robust')
VARIATIONS = ('none', 'chapter4')

# Seed 000 §3.4.4-3.4.5: each task's load, initial shaft state and length.
# The position task starts at rest, demagnetized, pendulum hanging (τ_L = 0). The speed task's
# reference starts at 135 rad/s with 2.49 N·m of load that a demagnetized motor cannot carry, so
# it starts in the controller's own steady state there ('steady', see im_bringup.offline).
TASK_PRESETS = {
    'position': {'load': 'pendulum', 'load_mgl': 10.0, 'theta0': -math.pi / 2, 'omega0': 0.0,
                 'start': 'rest', 'duration': 2.0},
    'speed': {'load': 'linear', 'load_c1': 1.0, 'load_c2': 0.001, 'theta0': 0.0, 'omega0': 135.0,
              'start': 'steady', 'duration': 1.5},
}


def node_parameters(task: str = 'position', strategy: str = 'min_energy',
                    controller: str = 'nominal', variation: str = 'none', T_s: float = 1e-4,
                    duration: Optional[float] = None, v_limit: float = 0.0,
                    current_gain: Optional[Sequence[float]] = None,
                    injection_gain: Optional[Sequence[float]] = None,
                    truth_decimation: int = 10, reference_decimation: int = 10,
                    input_timeout: float = 5.0) -> Dict[str, Dict[str, object]]:
    """Parameters of the four nodes for one scenario (validated names, no ROS import)."""
    if task not in TASKS:
        raise ValueError(f"invalid task {task!r}: one of {', '.join(TASKS)}")
    if strategy not in STRATEGIES:
        raise ValueError(f"invalid strategy {strategy!r}: one of {', '.join(STRATEGIES)}")
    if controller not in CONTROLLERS:
        raise ValueError(f"invalid controller {controller!r}: one of {', '.join(CONTROLLERS)}")
    if variation not in VARIATIONS:
        raise ValueError(f"invalid variation {variation!r}: one of {', '.join(VARIATIONS)}")
    from im_bringup.offline import Scenario
    from im_common.params import CHAPTER4_ESTIMATES
    preset = dict(TASK_PRESETS[task])
    if duration is None:
        duration = preset['duration']
    common = {'T_s': float(T_s), 'duration': float(duration), 'input_timeout': float(input_timeout)}
    plant = dict(common, variation=variation, v_limit=float(v_limit),
                 truth_decimation=int(truth_decimation),
                 **{k: v for k, v in preset.items() if k not in ('duration', 'start')})
    estimates = ({k: getattr(CHAPTER4_ESTIMATES, k) for k in ('R_s', 'R_r', 'L_s', 'L_r', 'L_sr')}
                 if variation == 'chapter4' else {})
    x0, obs_x0 = Scenario(task=task, strategy=strategy, T_s=T_s, duration=duration,
                          variation=variation).initial_state()
    adaptive = controller in ('adaptive_thesis', 'adaptive')
    ctl = dict(common, mode=task, strategy=strategy, use_adapter=adaptive,
               v_limit=float(v_limit), reference_decimation=int(reference_decimation),
               load_known=True, load=preset['load'],
               **{k: preset[k] for k in ('load_mgl', 'load_c1', 'load_c2') if k in preset},
               **estimates)
    if current_gain is not None:
        ctl['current_gain'] = [float(g) for g in current_gain]
        ctl['gain_period'] = float(T_s)
    if x0 is not None:          # plant and observer start in the controller's steady state
        plant['initial_current'] = [float(obs_x0[0]), float(obs_x0[1])]
        plant['initial_flux'] = [float(x0[2]), float(x0[3])]
    obs = dict(common, use_adapter=adaptive, **estimates)
    if x0 is not None:
        obs['initial_state'] = [float(v) for v in obs_x0]
    if injection_gain is not None:
        obs['injection_gain'] = [float(g) for g in injection_gain]
        obs['gain_period'] = float(T_s)
    adapter = dict(common, enable=adaptive, **estimates)
    if adaptive:
        adapter['law'] = 'thesis' if controller == 'adaptive_thesis' else 'improved'
    return {'plant': plant, 'controller': ctl, 'observer': obs, 'adapter': adapter}


def to_yaml(parameters: Dict[str, Dict[str, object]], use_sim_time: bool = True) -> str:
    """A ROS 2 parameters file (``--params-file``) for the given node parameters."""
    import yaml
    doc = {}
    for node, values in parameters.items():
        vals = dict(values)
        if use_sim_time and node != 'plant':
            vals['use_sim_time'] = True
        doc[node] = {'ros__parameters': vals}
    return yaml.safe_dump(doc, sort_keys=False, default_flow_style=False)
