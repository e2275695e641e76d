"""Report on synthetic recordings: the numbers are the plant's, the files exist."""
import json
import math

from im_recording.bag import BagWriter
from im_recording.recorded_run import load_run
from im_recording.report import main as report_main, write_report
from im_recording.synth import make_synthetic_bag
import numpy as np
import pytest


@pytest.fixture(scope='module')
def two_bags(tmp_path_factory):
    d = tmp_path_factory.mktemp('bags')
    a, b = d / 'slow.mcap', d / 'fast.mcap'
    truth_a = make_synthetic_bag(a, steps=300, V=50.0, f=15.0)
    truth_b = make_synthetic_bag(b, steps=300, V=80.0, f=25.0)
    return (a, truth_a), (b, truth_b)


def test_load_run_energy_books_match_the_plant(two_bags):
    (a, truth), _ = two_bags
    run = load_run(a)
    for k in ('E_in', 'E_cu_s', 'E_cu_r', 'E_core', 'E_friction', 'W_load', 'E_param',
              'W_mag', 'E_kin', 'dW_mag', 'dE_kin', 'balance_residual', 'R_r', 'L_sr'):
        assert run.truth_final[k] == pytest.approx(truth[k], rel=1e-12, abs=1e-12), k
    assert run.task == 'speed'
    assert len(run.trace['t']) == 301


def test_report_numbers_files_and_cli(two_bags, tmp_path, capsys):
    (a, ta), (b, tb) = two_bags
    out = tmp_path / 'rep'
    res = write_report([a], out)
    fig = res['runs'][0]['figures']
    e_loss = ta['E_cu_s'] + ta['E_cu_r'] + ta['E_core']
    assert fig['E_in_J'] == pytest.approx(ta['E_in'], rel=1e-12)
    assert fig['E_loss_J'] == pytest.approx(e_loss, rel=1e-12)
    assert fig['E_core_J'] == pytest.approx(ta['E_core'], rel=1e-12)
    assert fig['W_load_J'] == pytest.approx(ta['W_load'], rel=1e-12)
    # the books close: the plant integrates them with the state
    assert abs(fig['balance_residual_J']) < 1e-4 * fig['E_in_J']
    # peaks from the trace: the voltage magnitude is the commanded constant amplitude
    assert fig['V_max_V'] == pytest.approx(50.0, rel=1e-12)
    run = load_run(a)
    assert fig['i_max_A'] == pytest.approx(np.nanmax(np.hypot(run.trace['i_alpha'],
                                                              run.trace['i_beta'])))
    e = run.trace['omega_r'] - run.trace['omega_ref']
    assert fig['speed_err_rms_rad_s'] == pytest.approx(math.sqrt(np.mean(e ** 2)))
    md = (out / 'report.md').read_text()
    assert f"{ta['E_in']:.2f}" in md and 'energy drawn E_in' in md
    js = json.loads((out / 'report.json').read_text())
    assert js['runs'][0]['figures']['E_in_J'] == pytest.approx(ta['E_in'])
    pngs = list(res['figures'])
    names = {p.split('/')[-1] for p in pngs}
    assert {'speed.png', 'energy.png', 'currents_dq.png', 'flux_dq.png'} <= names
    for p in pngs:
        with open(p, 'rb') as f:
            assert f.read(8) == b'\x89PNG\r\n\x1a\n'

    # comparison of two runs: one column each, overlaid plots
    out2 = tmp_path / 'cmp'
    assert report_main([str(a), str(b), '--out', str(out2), '--no-plots']) == 0
    printed = capsys.readouterr().out
    assert 'slow' in printed and 'fast' in printed and str(out2 / 'report.md') in printed
    js2 = json.loads((out2 / 'report.json').read_text())
    assert [r['figures']['E_in_J'] for r in js2['runs']] == pytest.approx([ta['E_in'],
                                                                           tb['E_in']])
    header = (out2 / 'report.md').read_text().split('\n')[4]
    assert header.count('|') == 5                       # label, unit, two runs


def test_report_with_observer_and_estimates(tmp_path):
    path = tmp_path / 'obs.mcap'
    with BagWriter(path, metadata={'scenario': {'task': 'position'}}) as w:
        for k in range(200):
            t = k * 1_000_000
            th = 0.01 * k
            w.write_vector3('/im/measured/current', t, math.cos(th), math.sin(th))
            w.write_vector3('/im/truth/flux', t, 0.8 * math.cos(th), 0.8 * math.sin(th))
            w.write_vector3('/im/observer/flux', t, 0.7 * math.cos(th), 0.7 * math.sin(th))
            w.write_vector3('/im/reference/flux', t, 0.8 * math.cos(th), 0.8 * math.sin(th), 0.8)
            w.write_joint_state('/im/measured/shaft', t, ('rotor',), (th,), (10.0,))
            w.write_joint_state('/im/reference/shaft', t, ('rotor',), (th + 0.01,), (10.0,),
                                (1.0,))
            w.write_vector3('/im/truth/torque', t, 1.5, 0.0, 0.0)
            w.write_joint_state('/im/adapter/estimate', t, ('R_r', 'theta'), (1.0, 0.95))
            w.write_joint_state('/im/truth/parameters', t, ('R_r', 'theta'), (0.8, 0.95))
    res = write_report([path], tmp_path / 'r')
    f = res['runs'][0]['figures']
    assert f['flux_est_err_max_Wb'] == pytest.approx(0.1)
    assert f['flux_err_max_Wb'] == pytest.approx(0.0, abs=1e-12)
    assert f['pos_err_max_rad'] == pytest.approx(0.01)
    assert f['torque_err_rms_Nm'] == pytest.approx(0.5)
    assert f['R_r_est_err_max'] == pytest.approx(0.2)
    assert f['R_r_est_err_final_rel'] == pytest.approx(0.25)
    assert f['theta_est_err_max'] == pytest.approx(0.0)
    names = {p.split('/')[-1] for p in res['figures']}
    assert {'position.png', 'observer.png', 'estimates.png', 'flux_dq.png'} <= names


def test_report_cli_bad_bag_is_one_line_exit_2(tmp_path, capsys):
    bad = tmp_path / 'bad.mcap'
    bad.write_bytes(b'\x89MCAP0\r\n' + b'\x00' * 40)
    assert report_main([str(bad), '--out', str(tmp_path / 'o')]) == 2
    err = capsys.readouterr().err
    assert err.count('\n') == 1 and 'bad.mcap' in err and 'Traceback' not in err
    assert report_main([str(tmp_path / 'nope.mcap')]) == 2
    assert 'no such file' in capsys.readouterr().err


def test_plots_draw_decimated_topics_through_their_gaps():
    """
    Topics published every N steps are NaN between samples on the per-step time base.

    A plot must draw them from the samples that exist (else matplotlib draws nothing at all).
    """
    import numpy as np

    from im_recording.plots import _dec

    class R:
        trace = {'t': np.arange(100) * 1e-4, 'tau_ref': np.full(100, np.nan)}
    R.trace['tau_ref'][::10] = np.arange(10.0)
    t, y = _dec(R, 'tau_ref')
    assert len(t) == 10 and np.all(np.isfinite(y))
    np.testing.assert_array_equal(y, np.arange(10.0))


def _varied_bag(path, steps=2000, refused=0):
    """
    Every trace kind.

    Per-step and decimated topics, estimates drifting, a gap in one lock-step topic (steps
    1000-1009) and a NaN sample; ``refused`` commands of a rogue (50 V) kept apart as the
    recorder keeps them.
    """
    from im_common import topics as T
    with BagWriter(path, metadata={'scenario': {'task': 'position'}}) as w:
        if refused:
            w.add_topic(T.REFUSED_PREFIX + T.CMD_VOLTAGE, T.TOPIC_TYPES[T.CMD_VOLTAGE])
        for k in range(refused):
            w.write_vector3(T.REFUSED_PREFIX + T.CMD_VOLTAGE, k * 100_000, 50.0, 0.0)
        for k in range(steps):
            t = k * 100_000
            th = 0.003 * k
            w.write_vector3('/im/measured/current', t, 3 * math.cos(th), 2 * math.sin(3 * th))
            w.write_vector3('/im/truth/voltage', t, 40 * math.sin(th), 40 * math.cos(2 * th))
            if not 1000 <= k < 1010:
                w.write_vector3('/im/command/voltage', t, 41 * math.sin(th), 39 * math.cos(th))
            w.write_vector3('/im/truth/flux', t, 0.8 * math.cos(th), 0.8 * math.sin(th))
            w.write_vector3('/im/observer/flux', t + 100_000, 0.7 * math.cos(th),
                            0.75 * math.sin(th) if k != 7 else float('nan'))
            w.write_joint_state('/im/measured/shaft', t, ('rotor',), (th,), (10.0 + math.sin(th),))
            if k % 10 == 0:
                w.write_joint_state('/im/reference/shaft', t, ('rotor',), (th + 1e-3 * k,),
                                    (10.0,), (1.0,))
                w.write_vector3('/im/reference/flux', t, 0.8 * math.cos(th),
                                0.81 * math.sin(th), 0.8)
            w.write_vector3('/im/truth/torque', t, 1.5 + math.sin(th), 0.1, 0.0)
            w.write_joint_state('/im/adapter/estimate', t, ('R_r', 'theta'),
                                (1.0 - 1e-4 * k, 0.95 + 1e-5 * k))
            w.write_joint_state('/im/truth/parameters', t, ('R_r', 'theta'), (0.8, 0.95))


def test_streamed_figures_equal_the_full_trace_definitions(tmp_path, monkeypatch):
    """
    Check the running figures against the definitions on the whole trace.

    The running figures, folded batch by batch, are im_common.metrics' definitions on the whole
    trace (and the estimate errors computed directly), to rounding.
    """
    from im_common.metrics import tracking_figures

    from im_recording import recorded_run as R
    from im_recording.report import figures_of_merit
    path = tmp_path / 'v.mcap'
    _varied_bag(path)
    full = load_run(path)
    ref = tracking_figures(full.trace, 'position')
    monkeypatch.setattr(R.TraceStream.__init__, '__defaults__', ((), 997, 13))   # many batches
    streamed = load_run(path, trace='decimated', limit=200)
    fig = figures_of_merit(streamed)
    assert set(ref) <= set(fig)
    for k, v in ref.items():
        assert fig[k] == pytest.approx(v, rel=1e-12, nan_ok=True), k
    e = full.trace['R_r_hat'] - full.trace['R_r']
    assert fig['R_r_est_err_max'] == pytest.approx(np.nanmax(np.abs(e)), rel=1e-12)
    assert fig['R_r_est_err_rms'] == pytest.approx(np.sqrt(np.nanmean(e ** 2)), rel=1e-12)
    last = full.trace['t'] > full.trace['t'][-1] - 1.0
    assert fig['R_r_err_ptp_rel_last1s'] == pytest.approx(np.ptp(e[last]) / 0.8, rel=1e-12)
    assert fig['steps'] == 1999 and streamed.late == 0     # 2000 instants: 1999 steps between
    assert len(streamed.trace['t']) <= 400                         # decimated ...
    assert np.isfinite(streamed.trace['theta_ref']).sum() > 0       # ... keeping decimated topics
    assert figures_of_merit(full) == pytest.approx(fig, rel=1e-12, nan_ok=True)
    # the 10 missing commands are a gap at their stamps
    gaps = streamed.running.gaps()
    assert gaps == {'/im/command/voltage': {'missing': 10, 'ranges': [(0.1, 0.1009)]},
                    '/im/observer/flux': {'missing': 1, 'ranges': [(0.0, 0.0)]}}


def _status(node: str, state: str, t_ns: int, **values) -> bytes:
    """Return a run-protocol event as the nodes publish it on /im/status."""
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
    from rclpy.serialization import serialize_message
    msg = DiagnosticArray()
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(t_ns, 1_000_000_000)
    msg.status = [DiagnosticStatus(name=node, message=state, values=[
        KeyValue(key=k, value=str(v)) for k, v in values.items()])]
    return serialize_message(msg)


def _recorder_bag(path, end_state: str, reason: str, steps: int = 76, T_s: float = 0.01):
    """
    Return what the recorder node writes for a multi-process run.

    The lock-step topics, the nodes' events on /im/status and its ``recording`` metadata — no
    scenario parameters (so no duration to count steps against).
    """
    from im_common import topics as T
    w = BagWriter(path)
    dt = int(round(T_s * 1e9))
    w.write_serialized(T.STATUS, _status('plant', 'running', 0, time_master='true'), 0)
    for k in range(steps + 1):
        w.write_vector3(T.MEAS_CURRENT, k * dt, 1.0, 0.0)
        w.write_joint_state(T.MEAS_SHAFT, k * dt, ('rotor',), (0.0,), (1.0,))
        w.write_vector3(T.CMD_VOLTAGE, k * dt, 10.0, 0.0)
    w.write_serialized(T.STATUS, _status('plant', end_state, steps * dt, time_master='true',
                                         reason=reason), steps * dt)
    w.add_metadata('recording', {'run_end': f'{end_state} ({reason})', 'interrupted': '',
                                 'missing_steps': '0'})
    w.close()


@pytest.mark.parametrize('state', ['failed', 'stopped'])
def test_a_run_that_ended_before_its_duration_is_partial_with_the_reason(tmp_path, state):
    """
    Check that a run with a failed or stopped end is reported partial.

    Issue 23: a multi-process run whose plant exited 1 at 0.76 s of 10 s was reported `partial:
    false` with no incomplete-runs section. A failed or stopped end (the nodes' own /im/status
    events, the recorder's run_end) makes it partial, and the report says why.
    """
    reason = 'protection trip at t = 0.760000000 s: |i_s| = 61.2 A above current_trip 60 A'
    bag = tmp_path / 'failed.mcap'
    _recorder_bag(bag, state, reason)
    res = write_report([bag], tmp_path / 'rep', plots=False)
    st = res['runs'][0]['status']
    assert st['partial'] is True
    assert st['ended'][0]['node'] == 'plant' and st['ended'][0]['t'] == pytest.approx(0.76)
    md = (tmp_path / 'rep' / 'report.md').read_text()
    assert '## Incomplete runs' in md and f'plant {state} at t = 0.760000 s: {reason}' in md
    # a finished run of the same shape is whole
    ok = tmp_path / 'ok.mcap'
    _recorder_bag(ok, 'finished', 'duration reached')
    st = write_report([ok], tmp_path / 'rep_ok', plots=False)['runs'][0]['status']
    assert st['partial'] is False and st['notes'] == []


def test_refused_messages_are_counted_in_the_report_not_in_the_figures(tmp_path):
    """
    A rogue's commands, kept by the recorder on /im/refused<topic>.

    The report counts them per topic in their own section, and no figure changes.
    """
    from im_common import topics as T
    from im_recording.report import write_report
    clean, attacked = tmp_path / 'clean.mcap', tmp_path / 'attacked.mcap'
    _varied_bag(clean, steps=300)
    _varied_bag(attacked, steps=300, refused=7)
    rep = write_report([clean, attacked], tmp_path / 'rep', plots=False)
    a, b = rep['runs']
    assert a['status']['refused'] == {}
    assert b['status']['refused'] == {T.CMD_VOLTAGE: 7}
    assert b['figures'] == pytest.approx(a['figures'], rel=1e-12, nan_ok=True)
    with open(rep['markdown']) as f:
        section = f.read().split('## Refused messages')[1]
    assert f'7 on `{T.CMD_VOLTAGE}`' in section and 'clean' not in section


def test_the_plants_refused_commands_and_the_foreign_publishers_are_in_the_report(tmp_path):
    """
    The issue's rogue: the plant refused 44,244 commands, the recorder named ``/rogue``.

    The plant's count (its ``finished`` event) and every foreign publisher named (the
    recorder's ``recording`` metadata) are in the report's refusal figures and section, per node
    and topic, beside the messages the recorder kept.
    """
    from im_common import topics as T
    from im_recording.report import refusals, write_report
    path = tmp_path / 'rogue.mcap'
    w = BagWriter(path)
    w.write_serialized(T.STATUS, _status('plant', 'running', 0, time_master='true'), 0)
    for k in range(11):
        w.write_vector3(T.MEAS_CURRENT, k * 100_000, 1.0, 0.0)
        w.write_vector3(T.CMD_VOLTAGE, k * 100_000, 10.0, 0.0)
    w.add_topic(T.REFUSED_PREFIX + T.CMD_VOLTAGE, T.TOPIC_TYPES[T.CMD_VOLTAGE])
    for k in range(3):
        w.write_vector3(T.REFUSED_PREFIX + T.CMD_VOLTAGE, k * 100_000, 50.0, 0.0)
    w.write_serialized(T.STATUS, _status('plant', 'finished', 1_000_000, time_master='true',
                                         reason='duration reached', unsigned_commands='44244',
                                         foreign_publishers='/rogue'), 1_000_000)
    w.add_metadata('recording', {'run_end': 'finished (duration reached)', 'interrupted': '',
                                 'missing_steps': '0', 'refused_unsigned': '3',
                                 'foreign_publishers': '/rogue@/im/command/voltage'})
    w.close()
    rep = write_report([path], tmp_path / 'rep', plots=False)
    got = rep['runs'][0]['status']['refusals']
    assert got == {'refused_unsigned': {'plant': {T.CMD_VOLTAGE: 44244},
                                        'recorder': {T.CMD_VOLTAGE: 3}},
                   'foreign_publishers': {'plant': {T.CMD_VOLTAGE: ['/rogue']},
                                          'recorder': {T.CMD_VOLTAGE: ['/rogue']}}}
    from im_recording.recorded_run import load_run
    assert refusals(load_run(path)) == got
    with open(rep['markdown']) as f:
        section = f.read().split('## Refused messages')[1]
    assert (f'refused by plant: 44244 on `{T.CMD_VOLTAGE}` (foreign publishers: /rogue)'
            in section), section


def test_the_in_process_nodes_refusals_reach_the_bag_and_the_report(tmp_path):
    """The in-process scenario writes its nodes' refusals; the report reads them back."""
    from types import SimpleNamespace

    from im_bringup.scenario import _record_refusals
    from im_common import topics as T
    from im_recording.report import refusals
    from im_recording.recorded_run import load_run
    path = tmp_path / 'inproc.mcap'
    graph = SimpleNamespace(nodes={
        'plant': SimpleNamespace(refused_by_topic={T.CMD_VOLTAGE: 120},
                                 foreign={T.CMD_VOLTAGE: {'/rogue', '/other'}}),
        'controller': SimpleNamespace(refused_by_topic={T.MEAS_CURRENT: 7}, foreign={})})
    with BagWriter(path) as w:
        w.write_vector3(T.MEAS_CURRENT, 0, 1.0, 0.0)
        _record_refusals(w, graph)
    assert refusals(load_run(path)) == {
        'refused_unsigned': {'plant': {T.CMD_VOLTAGE: 120}, 'controller': {T.MEAS_CURRENT: 7}},
        'foreign_publishers': {'plant': {T.CMD_VOLTAGE: ['/other', '/rogue']}}}
