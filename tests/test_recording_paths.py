"""
One recording, two paths: the in-process graph's tap and the recorder node across processes.

Both feed :class:`im_recording.session.RecordingSession`, so a run recorded either way carries
the same metadata records with the same keys (the values of a pid, a wall time or a graph key
differ), and only the parameters of the run's own nodes.
"""

from im_bringup.processes import graph_processes, GraphProcesses
from im_bringup.scenario import run_metadata
from im_bringup.testing import assert_all_ended, random_domain, run_graph
from im_common import topics as T
from im_recording.bag import info
import pytest

DURATION = 0.02
LOCKSTEP = (T.MEAS_CURRENT, T.MEAS_SHAFT, T.CMD_VOLTAGE, T.OBS_FLUX)


def record_both(tmp_path, controller):
    """Record the same short run in one process and as processes; return both bags' metadata."""
    inproc = tmp_path / 'in_process.mcap'
    run_graph('position', 'min_energy', controller, duration=DURATION, record=str(inproc))
    procs = tmp_path / 'processes.mcap'
    meta = run_metadata('position', 'min_energy', controller, 'none')
    domain = {'ROS_DOMAIN_ID': str(random_domain())}
    with GraphProcesses(graph_processes('position', 'min_energy', controller,
                                        duration=DURATION, record=procs,
                                        record_metadata=meta), str(tmp_path / 'logs'),
                        domain) as g:
        codes = g.start().wait(120)
        assert_all_ended(g, codes)
    return info(inproc).metadata, info(procs).metadata


@pytest.mark.processes
@pytest.mark.slow
@pytest.mark.parametrize('controller', ['adaptive', 'nominal'])
def test_both_paths_write_the_same_metadata_records_and_keys(tmp_path, controller):
    a, b = record_both(tmp_path, controller)
    assert sorted(a) == sorted(b)
    for name in a:
        if name.startswith('parameters/'):      # the nodes' own: compared in test_rosbag2_compat
            continue
        assert sorted(a[name]) == sorted(b[name]), name
    nodes = {'plant', 'controller', 'observer'} | ({'adapter'} if controller == 'adaptive'
                                                   else set())
    assert {n.split('/', 1)[1] for n in a if n.startswith('parameters/')} == nodes
    for rec in (a['recording'], b['recording']):
        # the whole run, nothing missing, its end seen, not interrupted, every parameter
        assert rec['run_end'].startswith('finished'), rec
        assert rec['interrupted'] == '' and rec['parameters_not_received'] == ''
        assert rec['missing_steps'] == '0'
        assert rec['counted_from_step'] == '0'
        assert rec['counted_to_step'] == str(round(DURATION / 1e-4))
        assert rec['period_ns'] == '100000'
        for t in LOCKSTEP:
            assert rec[f'missing_steps{t}'] == '0'
    assert a['recorder']['node'] != b['recorder']['node']       # who recorded, by name
    assert a['recorder']['topics'] == b['recorder']['topics']
