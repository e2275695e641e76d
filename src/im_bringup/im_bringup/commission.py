"""
``ros2 run im_bringup commission --out MOTOR.yaml``: measure a motor, write its motor file.

It measures the motor's parameters through the graph's own topics (docs/commissioning.md).

    commission --out MOTOR.yaml --nameplate PLATE.yaml [--locked-rotor --J J --b B]
    commission --out MOTOR.yaml --plant-motor TRUE.yaml --nameplate PLATE.yaml   # in simulation
    commission RUN.yaml --out MOTOR.yaml --nameplate PLATE.yaml          # the run file's plant

The tool joins the lock-step graph as the node ``commission``: at each step it takes the plant's
``/im/measured/current`` and ``/im/measured/shaft``, and publishes the test voltage on
``/im/command/voltage`` (signed with the graph's key like every lock-step message). The test
sequence and the estimators are :mod:`im_adapt.commissioning`. With ``--plant-motor`` it starts the
simulated plant as a process of its own with that motor file as a ``--params-file`` (the tool never
opens it: the plant node reads it), the drive's limits as the plant's protection (``current_trip``,
``v_limit``) and waits for the tool. With a run file (docs/running.md) instead it starts the
plant ``scenario`` would start for that file — its motor, its inverter and sensors blocks, the
motor file's saturation and thermal blocks and the iron loss only where the file asks for them,
its noise, its load — at rest, with the same protection and waiting; the file's ``T_s`` is the
tests' period. Without either, a plant (the real drive) must run with ``wait_for:
commission``, ``allowed_publishers: /im/command/voltage=commission`` and an ``input_timeout`` long
enough for the fit between the tests (:data:`FIT_WAIT_S`).

Exit codes: 0 written, 1 the tests could not determine the motor (one line why), 2 bad input.
"""
from __future__ import annotations

import argparse
import math
import os
import shutil
import sys
import tempfile
import time
from typing import Optional

from im_adapt.commissioning import Commissioning, nameplate_from_dict, NotInformative, rated_flux
from im_adapt.magnetizing import curve_table
from im_common import auth
from im_common.auth import Signer
from im_common.cli import error as cli_error, logger, parse_args, ros_domain_id, status_line
from im_common.params import InvalidParameter, read_yaml_file
from im_common.yamlio import parameters_yaml

from .processes import graph_key_file, GraphProcesses, NodeProcess
from .run_file import RunFileError, Scenario

_log = logger('commission')


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog='commission', description=__doc__.split('\n\n')[0])
    p.add_argument('run_file', nargs='?',
                   help='simulation: start the plant this run file describes, as scenario does '
                   '(its motor, inverter, sensors and the blocks it asks for)')
    p.add_argument('--out', required=True, help='motor file to write (ROS 2 parameters YAML)')
    p.add_argument('--force', action='store_true', help='overwrite --out if it exists')
    p.add_argument('--nameplate', help='YAML with voltage [V line RMS], current [A line RMS], '
                   'frequency [Hz], speed [rpm], power [W]')
    p.add_argument('--current-limit', type=float,
                   help="drive current-vector limit [A] (default: the nameplate's, sqrt(3) x "
                   'the line current)')
    p.add_argument('--voltage-limit', type=float,
                   help="drive voltage-vector limit [V] (default: the nameplate's line voltage)")
    p.add_argument('--test-speed', type=float,
                   help='rated speed for the speed test [rad/s]; the test runs to half of it '
                   "(default: the nameplate's)")
    p.add_argument('--locked-rotor', action='store_true',
                   help='the rotor is locked: standstill tests only; give --J and --b')
    p.add_argument('--J', type=float, help='inertia [kg m^2] to write with --locked-rotor')
    p.add_argument('--b', type=float, help='viscous friction [N m s] to write with --locked-rotor')
    p.add_argument('--T-s', type=float, default=None,
                   help="control period [s] (default 1e-4, or the run file's T_s)")
    p.add_argument('--plant-motor', help='simulation: start the plant with this motor file')
    p.add_argument('--current-noise', type=float, default=0.0,
                   help='simulation: current measurement noise std of the plant [A]')
    p.add_argument('--speed-noise', type=float, default=0.0,
                   help='simulation: speed measurement noise std of the plant [rad/s]')
    p.add_argument('--domain-id', type=int, help='ROS domain (default: $ROS_DOMAIN_ID, 0 when '
                   'unset, as every ROS 2 tool)')
    p.add_argument('--timeout', type=float, default=30.0,
                   help='wall seconds to wait for the plant (default 30)')
    p.add_argument('--no-progress', action='store_true',
                   help='no in-place progress line (for logs)')
    return p


class Refused(ValueError):
    """Bad input: one line."""


def run_plant_parameters(args) -> Optional[dict]:
    """
    Return the plant parameters of ``args.run_file`` (None without one), at rest; set ``T_s``.

    The parameters ``scenario`` gives the plant of that file (``Scenario.node_parameters``):
    its motor, blocks, noise and load; the steady start's state is dropped (the tests start the
    motor at rest). Refused, in one line, with ``--plant-motor`` or another ``--T-s``.
    """
    if not args.run_file:
        if args.T_s is None:
            args.T_s = 1e-4
        return None
    if args.plant_motor:
        raise Refused('give the plant as a run file or as --plant-motor, not both')
    try:
        sc = Scenario.from_file(args.run_file)
        plant = sc.node_parameters()['plant']
    except (RunFileError, OSError) as exc:
        raise Refused(str(exc)) from None
    if args.T_s is not None and abs(args.T_s - sc.T_s) > 1e-12 * sc.T_s:
        raise Refused(f'--T-s {args.T_s:g}: the run file {args.run_file} runs at T_s = '
                      f'{sc.T_s:g} s (the tests take its period)')
    args.T_s = sc.T_s
    for key in ('initial_current', 'initial_flux'):
        plant.pop(key, None)
    plant.update(theta0=0.0, omega0=0.0)
    return plant


def settings(args) -> dict:
    """Limits, nameplate and test speed from the arguments (Refused naming what is missing)."""
    plate = None
    if args.nameplate:
        plate = nameplate_from_dict(read_yaml_file(args.nameplate, 'nameplate'),
                                    source=args.nameplate)
    ratings = plate.ratings() if plate else {}
    i_max = args.current_limit or ratings.get('rated_current')
    v_max = args.voltage_limit or ratings.get('rated_voltage')
    if not i_max:
        raise Refused('no current limit: give --nameplate or --current-limit')
    if not v_max:
        raise Refused('no voltage limit: give --nameplate or --voltage-limit')
    speed = args.test_speed or ratings.get('rated_speed')
    if args.locked_rotor:
        if args.J is None or args.b is None:
            raise Refused('--locked-rotor measures no inertia or friction: give --J and --b '
                          '(they are written as given)')
        if (not (args.J > 0 and math.isfinite(args.J))
                or not (args.b >= 0 and math.isfinite(args.b))):
            raise Refused(f'--J {args.J} must be > 0 and --b {args.b} >= 0')
    elif not speed:
        raise Refused('no speed for the speed test: give --nameplate or --test-speed '
                      '(or --locked-rotor)')
    for name, val in (('--current-limit', i_max), ('--voltage-limit', v_max),
                      ('--T-s', args.T_s)):
        if not (val > 0 and math.isfinite(val)):
            raise Refused(f'{name} = {val} must be a positive number')
    return {'plate': plate, 'ratings': ratings, 'i_max': float(i_max), 'v_max': float(v_max),
            'speed': speed}


def make_node(com, T_s: float, **kwargs):
    """Build the ``commission`` lock-step node around ``com`` (a ``Commissioning``)."""
    # heavy: rclpy and the ROS message packages only for the node (lockstep, qos, topics)
    from geometry_msgs.msg import Vector3Stamped
    from im_common import topics as T
    from im_common.conversions import Vector3Out, period_ns, shaft_in, xy_in
    from im_common.lockstep import FINISHED, LockstepNode, StepGate
    from im_common.qos import writer
    from rclpy.parameter import Parameter

    class CommissionNode(LockstepNode):
        """Commissioning tests: test voltages in, measured current and shaft out."""

        def __init__(self):
            super().__init__('commission', parameter_overrides=[Parameter('T_s', value=T_s)],
                             **kwargs)
            self.T_s = self.param('T_s', 1e-4, 'control period [s]', 1e-6, 0.1)
            self.period = period_ns(self.T_s)
            self.com = com
            self.pub_cmd = self.create_publisher(Vector3Stamped, T.CMD_VOLTAGE,
                                                 writer(T.CMD_VOLTAGE))
            self.out_cmd = Vector3Out(Signer.frame('alphabeta'))
            self.gate = StepGate([T.MEAS_CURRENT, T.MEAS_SHAFT], self.period)
            self.gate_input(T.MEAS_CURRENT, xy_in)
            self.gate_input(T.MEAS_SHAFT, shaft_in)
            self.start_protocol(5.0, 30.0)

        def step(self, inputs) -> None:
            ns = self.gate.expected
            i_a, i_b = inputs[T.MEAS_CURRENT]
            _theta, omega = inputs[T.MEAS_SHAFT]
            cmd = self.com.step(i_a, i_b, omega)
            if cmd is None:           # over: zero volts for this step, then end the run
                self.pub_cmd.publish(self.sign(T.CMD_VOLTAGE, self.out_cmd.fill(ns, 0.0, 0.0)))
                self.status(FINISHED, reason='commissioning tests done')
                self.finish()
                return
            self.pub_cmd.publish(self.sign(T.CMD_VOLTAGE, self.out_cmd.fill(ns, *cmd)))

    return CommissionNode()


#: How long the plant waits for the tool's command [wall s]: between the standstill and the speed
#: test the tool fits the standstill record (seconds on a loaded machine) before it answers.
FIT_WAIT_S = 300.0


def plant_parameters(s: dict, args) -> dict:
    """
    Return the simulated plant's parameters besides its motor file (the plant process reads it).

    The drive's limits as its protection, waiting for the tool, no end of its own; the noise of
    --current-noise, --speed-noise (a run file's own noise when they are not given).
    """
    out = {'T_s': args.T_s, 'duration': 0.0, 'wait_for': 'commission',
           'allowed_publishers': '/im/command/voltage=commission',
           'current_trip': s['i_max'], 'v_limit': s['v_max'],
           'locked_rotor': bool(args.locked_rotor),
           'truth_decimation': 0, 'input_timeout': FIT_WAIT_S}
    if not args.run_file or args.current_noise or args.speed_noise:
        out.update(current_noise_std=args.current_noise, speed_noise_std=args.speed_noise)
    return out


def start_plant(motor_file: Optional[str], s: dict, args, domain: int, key_file: str,
                workdir: str, run_plant: Optional[dict] = None):
    """
    Start the simulated plant as a process of its own (processes.GraphProcesses).

    ``ros2 run im_plant plant --ros-args --params-file <ours> --params-file MOTOR``: the tool
    never opens the motor file. With ``run_plant`` (a run file's plant parameters, motor
    included) no motor file: ours holds them, the tests' settings over them.
    """

    class PlantProcess(GraphProcesses):

        def command(self, p):
            extra = ['--params-file', os.path.abspath(motor_file)] if motor_file else []
            return super().command(p) + extra

    if motor_file and not os.path.isfile(motor_file):
        raise Refused(f'--plant-motor {motor_file}: no such file')
    params = dict(run_plant or {}, **plant_parameters(s, args), graph_key_file=key_file)
    g = PlantProcess([NodeProcess('plant', 'im_plant', 'plant', parameters=params)], workdir,
                     env={'ROS_DOMAIN_ID': str(domain)})
    return g.start()


def run(args) -> int:
    # heavy: rclpy (im_common.host) and the ROS messages (lockstep_protocol) only for a run
    import rclpy
    from rclpy.context import Context
    from im_common.host import flush, make_executor
    from im_common.lockstep_protocol import WAITING
    run_plant = run_plant_parameters(args)
    s = settings(args)
    plate = s['plate']
    com = Commissioning(args.T_s, s['i_max'], s['v_max'],
                        pole_pairs=plate.pole_pairs if plate else None,
                        test_speed=s['speed'], locked=args.locked_rotor)
    if os.path.exists(args.out) and not args.force:
        raise Refused(f'{args.out} exists: give --force to overwrite it')
    ctx = Context()
    try:
        domain = ros_domain_id(args.domain_id)
    except ValueError as exc:
        raise Refused(str(exc)) from None
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    nodes, plant, key = [], None, None
    workdir = tempfile.mkdtemp(prefix='commission_')
    if args.plant_motor or run_plant is not None:
        key_file = graph_key_file()
        key = auth.read_key_file(key_file)
        plant = start_plant(args.plant_motor, s, args, domain, key_file, workdir, run_plant)
    rclpy.init(context=ctx, domain_id=domain)
    try:
        node = make_node(com, args.T_s, context=ctx, graph_key=key)
        nodes.append(node)
        ex = make_executor(ctx)
        for n in nodes:
            ex.add_node(n)
        t0 = time.perf_counter()
        last = 0.0
        while not node.done and rclpy.ok(context=ctx):
            ex.spin_once(timeout_sec=0.05)
            now = time.perf_counter()
            if now - last > 0.5 and not args.no_progress:
                last = now
                status_line(f'  t = {com.k * args.T_s:7.3f} s  {com.progress:60s}')
            if any(n.exit_code for n in nodes):
                break
            if plant is not None and plant.returncodes()['plant'] is not None:
                break
            if node.state == WAITING and now - t0 > args.timeout:
                break
        if not args.no_progress:
            status_line('', done=True)
        failed = [n for n in nodes if n.exit_code]
        if failed and not com.failure:
            raise NotInformative(f'{failed[0].get_name()}: {failed[0].failure}')
        if plant is not None and not com.done:
            log = [ln for ln in plant.log('plant').splitlines() if 'ERROR' in ln or 'error' in ln]
            raise NotInformative('the plant ended before the tests did'
                                 + (f': {log[-1].strip()}' if log else ''))
        if not com.done:
            raise NotInformative(f'no plant answered within {args.timeout:g} s '
                                 f'(ROS_DOMAIN_ID={ctx.get_domain_id()})')
        flush(node, 1.0)
    finally:
        for n in nodes:
            n.destroy_node()
        rclpy.try_shutdown(context=ctx)
        if plant is not None:
            codes = plant.wait(5.0)
            if codes.get('plant') is None:
                plant.stop(grace=5.0)
        shutil.rmtree(workdir, ignore_errors=True)
    _write_result(args, com, s)
    return 0


def _write_result(args, com, s: dict) -> None:
    """Write the motor ``com`` identified to ``args.out`` (J, b given with the rotor locked)."""
    plate = s['plate']
    ident = com.result()
    if args.locked_rotor:
        ident.values.update(J=args.J, b=args.b,
                            pole_pairs=plate.pole_pairs if plate else 1)
        ident.notes['J'] = ident.notes['b'] = 'given (--J, --b), not measured: locked rotor'
        if not plate:
            ident.notes['pole_pairs'] = 'not measured (locked rotor, no nameplate): 1'
        else:
            ident.notes['pole_pairs'] = 'nameplate'
    motor = ident.motor(s['ratings'])
    flux = rated_flux(ident.values, plate, motor.theta) if plate else None
    write_motor_file(args.out, motor, ident, com, flux, args)
    _log(f'wrote {args.out}: ' + ', '.join(
        f'{n} = {ident.values[n]:.5g} ± {ident.std.get(n, 0.0):.2g}'
        for n in ('R_s', 'L_sigma', 'L_M', 'R_R', 'J', 'b') if n in ident.values))


def write_motor_file(path: str, motor, ident, com, flux: Optional[float], args) -> None:
    """Write the motor file in the shipped layout with a comment: uncertainties, gauge, tests."""
    v, sd = ident.values, ident.std
    lines = [
        'Measured by `commission` (docs/commissioning.md) '
        + ('with the rotor locked' if args.locked_rotor else 'with the rotor free') + '.',
        'Identified (inverse-Gamma set, value +- standard deviation from the residuals):',
    ]
    for n, unit in (('R_s', 'ohm'), ('L_sigma', 'H'), ('L_M', 'H'), ('R_R', 'ohm'),
                    ('J', 'kg m^2'), ('b', 'N m s')):
        if n in sd:
            lines.append(f'  {n} = {v[n]:.6g} +- {sd[n]:.2g} {unit}')
        elif n in v:
            lines.append(f'  {n} = {v[n]:.6g} {unit} ({ident.notes.get(n, "given")})')
    lines += [f'  pole_pairs = {int(v["pole_pairs"])} ({ident.notes.get("pole_pairs", "")})',
              'Gauge: L_s = L_r (equal stator and rotor leakage): L_s = L_r = L_sigma + L_M, '
              'L_sr = sqrt(L_M L_s), R_r = R_R L_s / L_M;',
              'the terminals fix only the inverse-Gamma set, any gauge is terminal-equivalent.',
              'k_e = k_h = 0: the core loss does not act on the terminals and is not measured.',
              f'Tests: T_s = {args.T_s:g} s, limits {com.i_max:g} A / {com.v_max:g} V; peaks '
              f'{com.peak_i:.4g} A / {com.peak_v:.4g} V; RMS residuals '
              + ', '.join(f'{k} {x:.3g}' for k, x in ident.rms_residual.items()) + '.']
    inv = ident.inverter
    if inv:
        how = '' if inv['compensated'] else ' (negligible: not compensated in the tests)'
        lines.append(f'Inverter voltage error (dead time + device drop, per phase): v_dead = '
                     f"{inv['v_dead']:.4g} +- {inv['v_dead_std']:.2g} V{how}; the drive "
                     'compensates it with the run-file key compensation: '
                     f"{{v_dead: {inv['v_dead']:.4g}, current_band: {inv['current_band']:.3g}}} "
                     "(docs/compensation.md). R_s includes the devices' on-state resistance.")
    values = motor.as_dict()
    if ident.magnetizing:
        lines.append('Magnetizing curve (no-load test, inverse-Gamma psi_R [Wb], i_M [A], value '
                     '+- standard deviation; the saturation block below is these points):')
        lines += [f"  psi_R = {p['psi']:.5g} +- {p['psi_std']:.2g} Wb, i_M = {p['i_M']:.5g} "
                  f"+- {p['i_M_std']:.2g} A (L_M = {p['psi'] / p['i_M']:.5g} H, omega_e = "
                  f"{p['w_e']:.4g} rad/s)" for p in ident.magnetizing]
        points = curve_table(ident.magnetizing)     # ROS takes no list of lists: two columns
        values['saturation'] = {'table_psi': [float(psi) for psi, _ in points],
                                'table_i_M': [float(i) for _, i in points]}
    if flux is not None:
        lines.append(f'Rated rotor flux (nameplate voltage, frequency, speed; this gauge): '
                     f"{flux:.4g} Wb (the controller's phi_d for constant flux).")
    text = parameters_yaml({'/**': values}, header='\n'.join(lines))
    tmp = path + '.tmp'
    with open(tmp, 'w') as f:
        f.write(text)
    os.replace(tmp, path)


def main(argv=None) -> None:
    parser = build_parser()
    args = parse_args(parser, argv)
    try:
        code = run(args)
    except (Refused, InvalidParameter) as exc:
        code = cli_error('commission', exc)
    except NotInformative as exc:
        print(f'commission: not informative: {exc}', file=sys.stderr)
        code = 1
    except KeyboardInterrupt:
        print('commission: stopped (nothing written)', file=sys.stderr)
        code = 1
    sys.exit(code)


if __name__ == '__main__':
    main()
