"""The four drive nodes spun in one process, on a context of their own, in lock-step.

:class:`DriveGraph` is what the scenario runner, the benchmarks and the integration tests use; it is
also the reusable piece for users' own integration tests (see :mod:`im_bringup.testing` for the
pytest fixture). Each graph owns its ``Context`` and a DDS domain id of its own (by default a
random one in 150-229), so several graphs — or several test runs on one machine — never cross-talk.

Recording in-process taps the nodes' publishers: every message a node publishes is also handed to
the :class:`im_bringup.bag.BagWriter` with its stamp, without an extra subscription on the hot path.
"""
from __future__ import annotations

import random
import sys
import time
from typing import Dict, Mapping, Optional

import rclpy
from rclpy.context import Context
from rclpy.parameter import Parameter

from im_common.conversions import NS_PER_S


def _overrides(values: Mapping[str, object]):
    return [Parameter(k, value=v) for k, v in values.items()]


def _stamp_of(msg) -> Optional[int]:
    h = getattr(msg, 'header', None)
    st = h.stamp if h is not None else getattr(msg, 'clock', None)
    if st is None:
        return None
    return st.sec * NS_PER_S + st.nanosec


class DriveGraph:
    """Plant, controller, observer and adapter nodes in one process.

    Parameters
    ----------
    parameters : mapping node name -> {parameter: value}
        The same structure as a ROS 2 parameters YAML (``plant``, ``controller``, ``observer``,
        ``adapter``); see :func:`im_bringup.config.node_parameters`.
    nodes : which nodes to start (default: all four). Leaving one out exercises the
        missing-input path: the others report what they waited for and stop.
    recorder : optional BagWriter; every published message is written to it.
    domain_id : DDS domain (default random in 150-229).
    """

    NODE_NAMES = ('plant', 'controller', 'observer', 'adapter')

    def __init__(self, parameters: Mapping[str, Mapping[str, object]],
                 nodes=NODE_NAMES, recorder=None, domain_id: Optional[int] = None):
        from im_adapt.adapter_node import AdapterNode
        from im_controller.controller_node import ControllerNode
        from im_observer.observer_node import ObserverNode
        from im_plant.plant_node import PlantNode
        factories = {'plant': PlantNode, 'controller': ControllerNode, 'observer': ObserverNode,
                     'adapter': AdapterNode}
        self.context = Context()
        self.domain_id = random.randint(150, 229) if domain_id is None else int(domain_id)
        rclpy.init(context=self.context, domain_id=self.domain_id)
        self.nodes: Dict[str, object] = {}
        self.recorder = recorder
        try:
            for name in nodes:
                self.nodes[name] = factories[name](
                    context=self.context,
                    parameter_overrides=_overrides(parameters.get(name, {})))
            from im_common.lockstep import make_executor
            self.executor = make_executor(self.context)
            for n in self.nodes.values():
                self.executor.add_node(n)
            if recorder is not None:
                self._tap_publishers()
        except BaseException:
            self.close()
            raise
        self.wall_s = 0.0

    @property
    def plant(self):
        return self.nodes['plant']

    def _tap_publishers(self) -> None:
        rec = self.recorder
        for node in self.nodes.values():
            for pub in list(node.publishers):
                topic = pub.topic_name
                if topic.startswith('/rosout') or topic.startswith('/parameter_events'):
                    continue
                original = pub.publish

                def tapped(msg, _orig=original, _topic=topic):
                    _orig(msg)
                    ns = _stamp_of(msg)
                    if ns is not None:
                        rec.write(_topic, msg, ns)
                pub.publish = tapped
        # Messages the nodes published while being built (initial estimates, step 0), again for
        # the tap (a repeated stamp is ignored by the receiving gates).
        for name in ('observer', 'adapter'):
            if name in self.nodes:
                self.nodes[name].publish_estimate(0)
        if 'plant' in self.nodes:
            self.nodes['plant'].publish_step()

    def run(self, progress: bool = False, wall_limit: Optional[float] = None) -> dict:
        """Spin until the plant reached its duration or a node failed; return run statistics."""
        nodes = list(self.nodes.values())
        plant = self.nodes.get('plant')
        t0 = time.perf_counter()
        last = t0
        k0 = plant.sim.k if plant is not None else 0
        total = plant.last_step if plant is not None else None
        first_failure = None
        while rclpy.ok(context=self.context):
            if first_failure is None and any(n.exit_code for n in nodes):
                first_failure = time.perf_counter()
            if first_failure is not None and (
                    all(n.done for n in nodes) or time.perf_counter() - first_failure > 1.0):
                break       # after a failure, give the others a moment to report theirs
            if plant is not None and plant.done and first_failure is None:
                break
            if plant is None and all(n.done for n in nodes):
                break
            self.executor.spin_once(timeout_sec=0.05)
            now = time.perf_counter()
            if progress and now - last > 0.5 and plant is not None:
                last = now
                k = plant.sim.k
                rate = (k - k0) / (now - t0)
                frac = f'{100.0 * k / total:5.1f} %' if total else ''
                print(f'\r  t = {plant.sim.t:8.4f} s  step {k}  {frac}  {rate:8.0f} steps/s',
                      end='', file=sys.stderr, flush=True)
            if wall_limit is not None and now - t0 > wall_limit:
                raise TimeoutError(f'run exceeded {wall_limit} s of wall time')
        self.wall_s = time.perf_counter() - t0
        if progress:
            print(file=sys.stderr)
        steps = (plant.sim.k - k0) if plant is not None else 0
        failures = {name: getattr(n, 'failure', None) for name, n in self.nodes.items()
                    if n.exit_code}
        return {'steps': steps, 'wall_s': self.wall_s,
                'steps_per_s': steps / self.wall_s if self.wall_s > 0 else float('nan'),
                'failures': failures, 'ok': not failures}

    def close(self) -> None:
        for n in getattr(self, 'nodes', {}).values():
            try:
                n.destroy_node()
            except Exception:  # noqa: BLE001 - teardown must go on
                pass
        ex = getattr(self, 'executor', None)
        if ex is not None:
            ex.shutdown()
        rclpy.try_shutdown(context=self.context)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
