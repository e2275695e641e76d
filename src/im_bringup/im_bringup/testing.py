"""
A pytest fixture that spins the whole drive graph in-process, for your own integration tests.

Use it from a ``conftest.py``::

    pytest_plugins = ['im_bringup.testing']

    def test_my_change(drive_graph):
        result = drive_graph(task='speed', strategy='min_loss', duration=0.2)
        assert result.summary['speed_err_max_rad_s'] < 1.0

Each call builds a fresh :class:`im_bringup.graph.DriveGraph` on its own ``Context`` and a random
DDS domain of :data:`TEST_DOMAINS` (isolation is the fixture's job: the graph itself, like
every ROS 2 tool, runs on ``ROS_DOMAIN_ID``), runs it to the end in lock-step, tears it down, and
returns the summary (figures of merit) with the traces. Extra node parameters go in
``parameters={'plant': {...}, ...}``. A run file (docs/running.md) is given as ``scenario=``
(a path or an :class:`im_bringup.run_file.Scenario`)::

    result = drive_graph(scenario='runs/drift.yaml')
"""
from __future__ import annotations

from dataclasses import dataclass
import os
import random
import time
from typing import Callable, Dict, Optional, Tuple, TypeVar

from im_bringup.config import node_parameters
from im_bringup.graph import DriveGraph
from im_bringup.run_file import Scenario
from im_bringup.scenario import held_estimates, plant_variation, run_metadata, summarize
from im_common.conversions import s_to_ns_array
from im_common.host import PRIVATE_DOMAINS
from im_recording.bag import BagWriter, log_time_offset_for
from im_recording.recorded_run import load_step_time
from im_recording.traces import Tap
import numpy as np
import pytest

#: DDS domains the fixtures draw from (clear of the default 0 and of the domains users pick)
TEST_DOMAINS = PRIVATE_DOMAINS


def worker_domains() -> Tuple[int, int]:
    """
    Return the range of :data:`TEST_DOMAINS` this test process draws from.

    Under pytest-xdist (``make test`` runs ``-n 2``) each worker gets a disjoint share, so two
    tests running at once never meet on one domain; otherwise the whole range.
    """
    worker, count = os.environ.get('PYTEST_XDIST_WORKER'), os.environ.get(
        'PYTEST_XDIST_WORKER_COUNT')
    if not worker or not count:
        return TEST_DOMAINS
    lo, hi = TEST_DOMAINS
    width = (hi - lo + 1) // int(count)
    start = lo + int(worker.lstrip('gw')) * width
    return start, start + width - 1


def random_domain() -> int:
    """Return a random domain of :func:`worker_domains` (a test's graph, context or processes)."""
    return random.randint(*worker_domains())


_T = TypeVar('_T')


def wait_until(condition: Callable[[], _T], timeout: float = 60.0,
               interval: float = 0.05) -> Optional[_T]:
    """
    Return ``condition()``'s first true value, polled every ``interval`` [s] (None: timed out).

    A bounded wait on an event (a log line, what a file holds, a process's state) where a fixed
    sleep would guess how long it takes: as quick as the event on an idle machine, as patient as
    ``timeout`` on a loaded one. The condition is checked once more at the deadline.
    """
    deadline = time.monotonic() + timeout
    while True:
        value = condition()
        if value or time.monotonic() >= deadline:
            return value or None
        time.sleep(interval)


def wait_for_log(graph, name: str, needle: str, timeout: float = 60.0) -> bool:
    """
    Return True once process ``name`` of ``graph`` has logged ``needle``; False after ``timeout``.

    ``graph``: an :class:`im_bringup.processes.GraphProcesses` (its ``log(name)``).
    """
    return bool(wait_until(lambda: needle in graph.log(name), timeout))


def assert_all_ended(graph, codes) -> None:
    """
    Assert that every process of ``graph`` ended with exit code 0.

    Else one message: the codes, then each other process with its log's end; one still running
    first writes its threads' stacks there
    (:meth:`im_bringup.processes.GraphProcesses.ended_text`), so a hang says where it is.
    """
    if any(c != 0 for c in codes.values()):
        raise AssertionError(f'exit codes {codes}\n{graph.ended_text(codes)}')


@dataclass
class GraphResult:
    summary: dict
    trace: Dict[str, np.ndarray]
    parameters: dict


def run_graph(task: str = 'position', strategy: str = 'min_energy', controller: str = 'nominal',
              variation: str = 'none', T_s: float = 1e-4, duration: Optional[float] = None,
              parameters: Optional[dict] = None, nodes=None, record: Optional[str] = None,
              beside=None, scenario=None, log_time: str = 'wall', **config) -> GraphResult:
    """
    Run one scenario in-process and return its summary and traces.

    ``scenario``: a run file path or :class:`~im_bringup.run_file.Scenario` (then task ...
    config are not given). ``log_time``: the recording's log times (``scenario --log-time``).
    ``beside(domain_id)``: a context manager entered while the graph
    runs (e.g. your own node, or a foreign one, on the graph's ROS domain).
    """
    if isinstance(scenario, str):
        scenario = Scenario.from_file(scenario)
    if scenario is not None:
        params = scenario.node_parameters(**config)
        task, strategy, controller = scenario.task, scenario.strategy, scenario.controller
        variation = scenario.variation_label
    else:
        params = node_parameters(task, strategy, controller, variation, T_s, duration, **config)
    for node, values in (parameters or {}).items():
        params.setdefault(node, {}).update(values)
    variation = plant_variation(params)
    writer = None
    if record:
        writer = BagWriter(record, force=True, metadata=run_metadata(
            task, strategy, controller, variation, scenario=scenario),
            log_time_offset_ns=log_time_offset_for(log_time))
    sink = Tap(writer, load_step=load_step_time(parameters=params), held=held_estimates(params))
    graph = DriveGraph(params, nodes=nodes, recorder=sink,
                       domain_id=random_domain())
    try:
        if beside is None:
            stats = graph.run()
        else:
            with beside(graph.domain_id):
                stats = graph.run()
    finally:
        graph.close()
        sink.close()            # the recording's 'recording' record, then its file
    summary = summarize(params, stats, sink, task=task, strategy=strategy,
                        controller=controller, variation=variation)
    run = summary.pop('_run')
    return GraphResult(summary, run.trace, params)


def assert_samples_match(graph_trace: Dict[str, np.ndarray], offline_trace: Dict[str, np.ndarray],
                         keys, min_shared: int, rtol: float = 1e-9, atol: float = 1e-12) -> None:
    """
    Assert the graph's samples at t_k equal the ROS-free loop's per-step trace at those instants.

    Stamps are matched in integer ns; NaN samples of decimated topics are skipped.
    """
    t_off = s_to_ns_array(np.asarray(offline_trace['t']))
    idx = {ns: i for i, ns in enumerate(t_off)}
    stamps = s_to_ns_array(np.asarray(graph_trace['t']))
    shared = [(i, idx[ns]) for i, ns in enumerate(stamps) if ns in idx]
    assert len(shared) >= min_shared, f'only {len(shared)} shared instants'
    for key in keys:
        a = np.array([graph_trace[key][i] for i, _ in shared])
        b = np.array([offline_trace[key][j] for _, j in shared])
        ok = np.isfinite(a)
        np.testing.assert_allclose(a[ok], b[ok], rtol=rtol, atol=atol, err_msg=key)


@pytest.fixture
def drive_graph():
    """Return :func:`run_graph`, a callable fixture (task=..., strategy=..., duration=..., ...)."""
    return run_graph
