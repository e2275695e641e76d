"""A pytest fixture that spins the whole drive graph in-process, for your own integration tests.

Use it from a ``conftest.py``::

    pytest_plugins = ['im_bringup.testing']

    def test_my_change(drive_graph):
        result = drive_graph(task='speed', strategy='min_loss', duration=0.2)
        assert result.summary['speed_err_max_rad_s'] < 1.0

Each call builds a fresh :class:`im_bringup.graph.DriveGraph` on its own ``Context`` and DDS
domain, runs it to the end in lock-step, tears it down, and returns the summary (figures of merit)
with the traces. Extra node parameters go in ``parameters={'plant': {...}, ...}``.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Dict, Optional

import numpy as np
import pytest


@dataclass
class GraphResult:
    summary: dict
    trace: Dict[str, np.ndarray]
    parameters: dict


def run_graph(task: str = 'position', strategy: str = 'min_energy', controller: str = 'nominal',
              variation: str = 'none', T_s: float = 1e-4, duration: Optional[float] = None,
              parameters: Optional[dict] = None, nodes=None, record: Optional[str] = None,
              **config) -> GraphResult:
    """Run one scenario in-process and return its summary and traces."""
    from im_bringup.config import node_parameters
    from im_bringup.graph import DriveGraph
    from im_bringup.scenario import summarize
    from im_bringup.traces import Tap
    params = node_parameters(task, strategy, controller, variation, T_s, duration, **config)
    for node, values in (parameters or {}).items():
        params.setdefault(node, {}).update(values)
    writer = None
    if record:
        from im_bringup.bag import BagWriter
        writer = BagWriter(record, force=True)
    sink = Tap(writer)
    graph = DriveGraph(params, nodes=nodes or DriveGraph.NODE_NAMES, recorder=sink)
    try:
        stats = graph.run()
    finally:
        graph.close()
        if writer is not None:
            writer.close()
    summary = summarize(params, stats, sink, task=task, strategy=strategy,
                        controller=controller, variation=variation)
    run = summary.pop('_run')
    return GraphResult(summary, run.trace, params)


@pytest.fixture
def drive_graph():
    """Callable fixture: ``drive_graph(task=..., strategy=..., duration=..., parameters=...)``."""
    return run_graph
