"""
Every benchmark runs and writes well-formed JSON.

Every benchmark runs (quick mode, seconds) and writes well-formed JSON with its figures, so a
benchmark can never break unseen (issue 25: ``make bench`` failed on a stand-in that drifted from
the adapter's estimate names). No timing is asserted here: speed targets live in the benchmarks'
own output (``benchmarks/results/summary.json``).
"""
from __future__ import annotations

import importlib.util
import json
import os

import pytest

BENCH = os.path.join(os.path.dirname(os.path.abspath(__file__)), '..', 'benchmarks')


def _load(name: str):
    """Import ``benchmarks/<name>.py`` (the benchmarks' folder is not a package)."""
    spec = importlib.util.spec_from_file_location(name, os.path.join(BENCH, f'{name}.py'))
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _run_all():
    return _load('run_all')


def _not_json(constant):
    raise AssertionError(f'{constant} is not standard JSON')


def _ray_installed() -> bool:
    return importlib.util.find_spec('ray') is not None


#: figures each benchmark must report (a renamed or lost figure fails here, not in the README)
EXPECTED = {
    'auth': ['auth_pack_us', 'auth_sign_us', 'auth_verify_us', 'auth_per_step_us'],
    'bag': ['us_per_msg_write_msg_zstd', 'us_per_msg_write_serialized_zstd',
            'us_per_msg_own_writer_zstd', 'us_per_msg_mcap_Writer_zstd',
            'us_per_msg_own_reader_iter_raw', 'us_rclpy_serialize_message_v3',
            'recover_cpu_us_per_msg_16000_steps', 'recover_peak_rss_mb_16000_steps',
            'us_per_msg_decode_v3_batch', 'us_per_msg_decode_v3_each',
            'us_per_msg_decode_js_batch', 'us_per_msg_decode_js_each'],
    'campaign': ['engine_process_pool_startup_s', 'engine_dask_startup_s',
                 'engine_dask_per_task_ms', 'campaign_4_runs_1_workers_wall_s'],
    'graph': ['kernel_steps_per_s', 'bare_loop_adapter_off_path_steps_per_s',
              'bare_loop_tagged_adapter_off_path_steps_per_s', 'graph_in_process_steps_per_s',
              'graph_in_process_adaptive_steps_per_s', 'graph_in_process_recording_steps_per_s',
              'graph_in_process_start_s', 'inprocess_over_bare', 'inprocess_over_kernel',
              'recording_slowdown', 'computation_us_per_step', 'inprocess_ceiling_over_bare',
              'inprocess_tagged_ceiling_over_bare'],
    'kernel': ['kernel_steps_per_s', 'kernel_chapter4_steps_per_s', 'rel_err_vs_solve_ivp_max'],
    'processes': ['ping_pong_two_processes_round_trips_per_s', 'lockstep_processes_steps_per_s',
                  'lockstep_processes_recorded_steps_per_s', 'lockstep_processes_vs_ping_pong',
                  'free_run_1kHz_missed_fraction', 'free_run_1kHz_latency_p99_le_us',
                  'lockstep_processes_cpu_us_per_step',
                  'ping_pong_two_processes_cpu_us_per_round_trip',
                  'lockstep_processes_cpu_per_step_in_deliveries',
                  'lockstep_processes_cpu_ceiling_vs_ping_pong',
                  'lockstep_processes_cpu_us_per_step_plant',
                  'lockstep_processes_cpu_us_per_step_controller',
                  'lockstep_processes_cpu_us_per_step_observer',
                  'lockstep_processes_serial_us_per_step',
                  'lockstep_processes_serial_rate_vs_ping_pong',
                  'lockstep_processes_other_load_cores',
                  'four_processes_delay0_steps_per_s', 'four_processes_delay1_steps_per_s',
                  'four_processes_delay1_serial_steps_per_s',
                  'four_processes_delay1_cpu_us_per_step_plant',
                  'four_processes_delay1_over_delay0',
                  'four_processes_delay1_over_delay0_ceiling',
                  'four_processes_delay1_over_ceiling',
                  'four_processes_delay1_serial_over_delay0'],
    'profile': ['steps_per_s_unprofiled', 'us_per_step_decode', 'us_per_step_tags',
                'us_per_step_protocol', 'us_per_step_compute', 'us_per_step_publish',
                'us_per_step_executor', 'us_per_step_plant_ready',
                'us_per_step_controller_ready'],
    'real_plant': ['offline_ideal_steps_per_s', 'offline_real_steps_per_s',
                   'graph_ideal_steps_per_s', 'graph_real_steps_per_s', 'offline_real_over_ideal',
                   'graph_real_over_ideal', 'real_plant_over_ideal',
                   'offline_real_reference_steps_per_s', 'offline_real_compiled_over_reference'],
    'rclpy': ['ping_pong_events_rt_per_s', 'bare_loop_adapter_on_path_steps_per_s',
              'bare_loop_adapter_off_path_steps_per_s',
              'bare_loop_tagged_adapter_off_path_steps_per_s'],
    'soak': ['max_rss_2k_steps_mb', 'max_rss_6k_steps_mb', 'max_rss_6k_minus_2k_mb',
             'rss_growth_after_warmup_6k_steps_mb'],
}
#: summary.json ratios each benchmark contributes
SUMMARY = {'graph': ['inprocess_over_bare', 'inprocess_ceiling_over_bare',
                     'inprocess_tagged_ceiling_over_bare', 'inprocess_over_tagged_bare',
                     'inprocess_over_kernel', 'inprocess_over_ceiling'],
           'processes': ['four_processes_over_pingpong',
                         'four_processes_cpu_ceiling_over_pingpong',
                         'four_processes_over_cpu_ceiling',
                         'four_processes_serial_rate_over_pingpong',
                         'four_processes_serial_over_cpu_ceiling',
                         'four_processes_over_serial_rate',
                         'four_processes_delay1_over_delay0',
                         'four_processes_delay1_over_delay0_ceiling',
                         'four_processes_delay1_over_ceiling'],
           'real_plant': ['real_plant_over_ideal', 'real_plant_compiled_over_reference']}


def test_every_benchmark_is_covered():
    assert sorted(_run_all().benchmark_names()) == sorted(EXPECTED)


@pytest.mark.processes
@pytest.mark.slow
@pytest.mark.parametrize('name', sorted(EXPECTED))
def test_benchmark_quick_run_writes_its_figures(name, tmp_path):
    run_all = _run_all()
    assert run_all.main(['--quick', '--only', name, '--out', str(tmp_path)]) == 0
    with open(tmp_path / f'{name}.json') as f:
        doc = json.load(f, parse_constant=_not_json)
    assert doc['benchmark'] == name and doc['quick'] is True
    res = doc['results']
    expected = list(EXPECTED[name])
    if name == 'campaign':
        expected += (['engine_ray_startup_s', 'engine_ray_per_task_ms'] if _ray_installed()
                     else ['engine_ray_skipped'])
    missing = [k for k in expected if k not in res]
    assert not missing, f'{name}: figures missing: {missing} (have {sorted(res)})'
    for k in expected:
        if k.endswith('_skipped'):
            assert isinstance(res[k], str) and res[k], k
        elif k.endswith('_le_us'):      # a quantile beyond the latency histogram's last bin
            assert isinstance(res[k], (int, float)) or res[k] == 'inf', f'{name}: {k} = {res[k]!r}'
        else:
            assert isinstance(res[k], (int, float)), f'{name}: {k} = {res[k]!r}'
    with open(tmp_path / 'summary.json') as f:
        summary = json.load(f, parse_constant=_not_json)
    assert summary['quick'] is True and summary['benchmarks'] == [name]
    for k in SUMMARY.get(name, []):
        assert summary[k] > 0, k
    # a ratio no benchmark of this run measured is absent, never a placeholder
    others = {k for n, ks in SUMMARY.items() if n != name for k in ks}
    assert not others & set(summary), sorted(others & set(summary))
    if name != 'processes':
        assert 'free_run_missed_fraction_busy' not in summary


def test_the_opening_table_holds_each_run_to_its_targets(tmp_path):
    """``benchmarks/today.py``: one row a target, each run's value, a miss in bold and said."""
    today, targets = _load('today'), _run_all().TARGETS
    runs = []
    for i, scale in enumerate((1.0, 0.5)):
        s = {'quick': False, 'date': f'2026-12-0{i + 1}T10:00:00',
             'machine': {'cpu_model': 'Test CPU', 'cpus': 2, 'python': '3.11.7',
                         'load_1min_at_start': 0.1 * i}}
        for key, (op, bound, _) in targets.items():
            s[key] = bound * (1.1 if op == '>=' else 0.9) * (scale if op == '>=' else 1 / scale)
        p = tmp_path / f's{i}.json'
        p.write_text(json.dumps(s))
        runs.append(str(p))
    doc = tmp_path / 'b.md'
    doc.write_text('# B\n\n<!-- today:begin -->\nold\n<!-- today:end -->\n\nhistory\n')
    assert today.main(runs + ['--doc', str(doc)]) == 0
    text = doc.read_text()
    assert 'old' not in text and text.endswith('<!-- today:end -->\n\nhistory\n')
    rows = [line for line in text.splitlines() if line.startswith('| `')]
    assert len(rows) == len(targets)
    for row in rows:        # the first run meets every target, the second none
        assert row.count('(not met)') == 1 and row.endswith('| **no** |'), row
    assert '2 `make bench` runs' in text and 'Test CPU, 2 CPUs' in text
    quick = tmp_path / 'q.json'
    quick.write_text(json.dumps({'quick': True}))
    assert today.main([str(quick)]) == 2
