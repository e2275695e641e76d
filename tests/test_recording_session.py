"""
The recording session without ROS: what it counts, the records it closes with, what reports read.

:class:`im_recording.session.RecordingSession` is fed here as the graph's tap and the recorder node
feed it: serialized messages with their stamps, the time master's events, the nodes' parameters.
"""
from im_common import cdr
from im_common import topics as T
from im_recording.bag import BagWriter, info
from im_recording.session import RecordingSession
import pytest

P = 100_000                     # ns per step
LOCKSTEP = (T.MEAS_CURRENT, T.MEAS_SHAFT, T.CMD_VOLTAGE, T.OBS_FLUX)


def _feed(session, steps, skip=()):
    for k in range(steps + 1):
        if k in skip:
            continue
        t = k * P
        for topic in (T.MEAS_CURRENT, T.OBS_FLUX) + ((T.CMD_VOLTAGE,) if k < steps else ()):
            session.write(topic, cdr.pack_vector3_stamped(*divmod(t, 10**9), 1.0, 0.0, 0.0), t)
        session.write(T.MEAS_SHAFT,
                      cdr.pack_joint_state(*divmod(t, 10**9), ('rotor',), (0.0,), (1.0,)), t)


def _session(path):
    writer = BagWriter(path, log_time_offset_ns=0)
    return RecordingSession(writer, T.RECORDED_TOPICS, recorder='test', always=LOCKSTEP)


def test_a_finished_run_with_a_gap_is_counted_step_by_step(tmp_path):
    s = _session(tmp_path / 'run.mcap')
    s.master_event('running', {'T_s_ns': str(P), 'step': '0', 'time_master': 'true'})
    s.add_parameters('plant', {'T_s': 1e-4, 'gains': (1.0, 2.0)})
    s.expect_parameters('controller')           # asked for, never given
    _feed(s, 20, skip={5, 6})
    s.master_event('finished', {'T_s_ns': str(P), 'step': '20', 'reason': 'duration reached'})
    s.close()
    md = info(tmp_path / 'run.mcap').metadata
    rec = md['recording']
    assert rec['run_end'] == 'finished (duration reached)' and rec['interrupted'] == ''
    assert rec['counted_from_step'] == '0' and rec['counted_to_step'] == '20'
    for t in LOCKSTEP:                          # steps 5 and 6: 2 on every lock-step topic
        assert rec[f'missing_steps{t}'] == '2', t
        assert rec[f'missing_ranges{t}'] == f'{5 * P}-{6 * P}', t
    assert rec['missing_steps'] == '8'
    assert rec['messages'] == str(19 * 4 - 1)
    assert rec['parameters_not_received'] == 'controller'
    assert md['parameters/plant'] == {'T_s': '0.0001', 'gains': '[1.0, 2.0]'}
    assert md['recorder']['node'] == 'test'
    assert md['recorder']['topics'].split() == list(T.RECORDED_TOPICS)


def test_an_interrupted_run_is_reported_interrupted_and_partial(tmp_path):
    from im_recording.report import write_report
    s = _session(tmp_path / 'cut.mcap')
    s.master_event('running', {'T_s_ns': str(P), 'step': '0'})
    _feed(s, 30)
    s.close('SIGINT')                           # no final event: counted to the last step seen
    rec = info(tmp_path / 'cut.mcap').metadata['recording']
    assert rec['interrupted'] == 'SIGINT' and rec['run_end'] == 'not seen'
    assert rec['counted_to_step'] == '30'
    st = write_report([tmp_path / 'cut.mcap'], tmp_path / 'rep', plots=False)['runs'][0]['status']
    assert st['interrupted'] == 'SIGINT' and st['partial'] is True
    assert 'interrupted by SIGINT at step 30' in st['notes']


def test_a_closed_session_refuses_writes_and_closes_once(tmp_path):
    from im_recording.bag import BagError
    s = _session(tmp_path / 'x.mcap')
    s.close()
    s.close()                                   # idempotent: one recording record
    with pytest.raises(BagError, match='closed'):
        s.write(T.MEAS_CURRENT, cdr.pack_vector3_stamped(0, 0, 1.0, 0.0, 0.0), 0)
    assert 'recording' in info(tmp_path / 'x.mcap').metadata
