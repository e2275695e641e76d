"""
``ros2 run im_plant plant``: the simulated motor, load and inverter; the time master.

A thin shell around :class:`im_plant.plant_sim.PlantSimulator`: parameters in, voltage commands
in, measurements and ground truth out. It is the time master of the run protocol
(:mod:`im_common.lockstep`): it publishes step 0 only when every node of ``wait_for`` is ready, and
``finished`` after the last step.

``lockstep`` (default): it advances from t_k to t_k+1 only when the command stamped t_k has
arrived, and stays within ``follower_window`` steps of every lossless follower (the recorder).
``free_run``: it advances on a wall clock at T_s (a thread of its own). The command stamped t_k
must arrive before the tick that ends step k (its deadline); otherwise the previous command is held
for that step and the step counts as *missed* (a command that arrives after its deadline is *late*
and dropped). Latencies (measurement k published → command k received) go into a histogram reported
at the end. A plant that falls behind the wall clock catches up tick after tick; more than
``max_lag`` behind (the machine cannot integrate in real time) it stops the run and says so.

Before step 0 of a ``free_run`` the plant probes the loop: it sends :data:`PROBES` probes at the
run's period to every critical node it waits for, which echo them at once through their executors,
and times the round trips plus its own step (:func:`im_common.timing.assess_probe`). A rate whose
probed latency does not fit the budget is refused with one line naming the measured latency, the
period and the rate this machine holds (``force_rate`` starts anyway). During the run a
:class:`im_common.timing.DeadlineWatchdog` stops the run with zero voltage (a protection trip) when
more than ``deadline_miss_limit`` of the last ``deadline_window`` steps missed their deadline.

``load_offset`` is live (``ros2 param set /plant load_offset 6.0``): added to the load's torque
from the next step boundary on — step k, integrated over [t_k, t_k+1] after the call — and
announced on ``/im/status`` as a ``parameters`` event stamped t_k (docs/running.md, "Loads").
"""
from __future__ import annotations

import copy
import math
import os
import sys
import threading
import time

from geometry_msgs.msg import Vector3Stamped
from im_common import topics as T
from im_common.auth import progress_payload, Signer, split_frame
from im_common.conversions import (clock_bytes, JointStateOut, NS_PER_S, period_ns, Vector3Out,
                                   xy_in)
from im_common.lockstep import LockstepNode, node_main, stamp_text, StepGate
from im_common.lockstep_protocol import (DRAINING, FINISHED, JOINED, LEFT, MASTER_STEPPING,
                                         PARAMETERS, RUNNING, STOP, STOPPED, TimeMaster, WAITING,
                                         YIELD)
from im_common.node_params import declare_overlap, declare_run
from im_common.params import describe_defaults
from im_common.qos import reader, writer
from im_common.step_gate import LOCKSTEP_DEPTH
from im_common.timing import assess_probe, DeadlineWatchdog, LatencyHistogram
from im_plant.parameters import declare_plant, simulator_from_parameters
from rosgraph_msgs.msg import Clock as ClockMsg
from sensor_msgs.msg import JointState
from std_msgs.msg import Header


class PlantNode(LockstepNode):
    """Simulated induction motor, load and inverter; owns simulated time."""

    time_master = True

    def __init__(self, **kwargs):
        """Declare the parameters, build the simulator, the time master and the topics."""
        super().__init__('plant', **kwargs)
        self.T_s, self.duration, timeout, startup = declare_run(self)
        values = declare_plant(self)
        self._setup_modes(values)
        self._setup_simulator(values)
        self._setup_master(timeout)
        self._setup_free_run()
        self._setup_publishers()
        self._setup_truth_outputs(values)
        self._setup_inputs()
        self.start_protocol(timeout, startup)

    def _setup_modes(self, values: dict) -> None:
        """Take the run's mode, pacing, deadline and decimation parameters."""
        self.mode = values['mode']
        self.max_lag = values['max_lag']
        self.force_rate = values['force_rate']
        self.deadlines = DeadlineWatchdog(values['deadline_window'], values['deadline_miss_limit'])
        self.probe = None                       # free_run's pre-flight (_LoopProbe)
        self.event_context = {'mode': self.mode}    # a free_run follower goes real-time early
        self.clock_every = values['clock_decimation']
        self.truth_every = values['truth_decimation']

    def _setup_simulator(self, values: dict) -> None:
        """Build the simulator from the parameters; the period, the last step, the overlap."""
        self.sim = simulator_from_parameters(values, self.T_s, self.duration)
        if self.sim.from_ratings:
            self.get_logger().info(describe_defaults(self.sim.from_ratings))
        self.period = period_ns(self.T_s)
        self.last_step = (round(self.duration / self.T_s) if self.duration > 0 else None)
        # a delayed step overlapped (lock-step, delay >= 1): step k integrated once the command of
        # step k - delay has come, beside the controller computing the command of step k
        self.overlap = (declare_overlap(self) and self.sim.delay.d > 0
                        and self.mode == 'lockstep')
        self._last_entered = -1     # overlapped: the step of the last command entered
        self._final_wait = False    # overlapped: the last step published, its commands not all in

    def _setup_master(self, timeout) -> None:
        """Declare the lock-step partners' parameters and make the time master."""
        self.wait_for = self.param(
            'wait_for', 'controller observer',
            'names of the nodes that must be ready before step 0, separated by spaces (add '
            'adapter, recorder to wait for them; empty: start at once)').split()
        self.window = self.param('follower_window', 50,
                                 'lock-step: how many steps the plant may run ahead of the last '
                                 'step a lossless follower (the recorder) acknowledged', 1,
                                 LOCKSTEP_DEPTH // 2)
        self.run_id = os.urandom(4).hex()       # tells this run's events from another graph's
        self.signer.set_run(self.run_id)        # ... and its lock-step messages (their tags)
        # the time master's decisions: step 0, lossless followers, the end, another plant
        self.master = TimeMaster(self.run_id, self.period, self.wait_for, self.window,
                                 timeout, self.context.get_domain_id())
        self.master.on_dropped = self._follower_dropped
        self.truth_sink = None      # in-process recorder hook: f(ns, truth_dict)
        self.wall_start = None      # wall time of the first step (for the steps/s report)

    def _setup_free_run(self) -> None:
        """Zero the free_run deadline accounting."""
        self.missed = 0             # steps whose command had not arrived by the deadline
        self.late = 0               # commands that arrived after their deadline (dropped)
        self.overruns = 0           # ticks the plant itself was late for (caught up)
        self.latency = LatencyHistogram()
        self._published_at: dict = {}
        self._free_cmd: dict = {}
        self._tick_lock = threading.Lock()
        self._ok_since = None
        self._after_end_said = False

    def _setup_publishers(self) -> None:
        """Create the measurements', the clock's and the truth's publishers."""
        self.pub_current = self.create_publisher(Vector3Stamped, T.MEAS_CURRENT,
                                                 writer(T.MEAS_CURRENT))
        self.pub_shaft = self.create_publisher(*_js(), T.MEAS_SHAFT, writer(T.MEAS_SHAFT))
        self.pub_clock = self.create_publisher(ClockMsg, T.CLOCK, writer(T.CLOCK))
        v3, js = Vector3Stamped, _js()[0]
        self.pub_truth = {key: self.create_publisher(cls, t, writer(t)) for key, cls, t in (
            ('voltage', v3, T.TRUTH_VOLTAGE), ('flux', v3, T.TRUTH_FLUX),
            ('torque', v3, T.TRUTH_TORQUE), ('params', js, T.TRUTH_PARAMS),
            ('power', js, T.TRUTH_POWER), ('energy', js, T.TRUTH_ENERGY),
            ('shaft', js, T.TRUTH_SHAFT), ('peaks', js, T.TRUTH_PEAKS),
            # published when the motor has a thermal block / the run an inverter block
            ('temperature', js, T.TRUTH_TEMPERATURE), ('inverter', js, T.TRUTH_INVERTER))}

    def _setup_truth_outputs(self, values: dict) -> None:
        """Make the measurement and truth messages (the real plant's blocks' only with them)."""
        # the real plant's truth (docs/plant.md): published only with the blocks that make it (the
        # publishers exist on every plant: the SROS2 policy is read off a default node)
        real = self.sim.real
        self.out_temp = self.out_inv = None
        if real is not None and real.thermal is not None:
            self.out_temp = JointStateOut(T.TEMPERATURE_NAMES, Signer.frame(''))
        if real is not None and real.inverter is not None:
            self.out_inv = JointStateOut(T.INVERTER_NAMES, Signer.frame(''))
        # the truth is signed as the measurements are (T.SIGNED_TOPICS): a recorder beside another
        # graph keeps that graph's truth apart (its frame: the tag's placeholder, filled by sign)
        self.out_tshaft = JointStateOut([T.SHAFT_JOINT], Signer.frame(''))
        self.out_peaks = JointStateOut(T.PEAK_NAMES, Signer.frame(''))
        self._peak_v = self._peak_i = 0.0       # since the last truth sample, every step
        self.out_current = Vector3Out(Signer.frame('alphabeta'))
        self.out_shaft = JointStateOut([T.SHAFT_JOINT], Signer.frame(''))
        self.out_tv, self.out_tf, self.out_tt = (Vector3Out(Signer.frame('alphabeta'))
                                                 for _ in range(3))
        self.out_par = JointStateOut(T.PARAM_NAMES, Signer.frame(''))
        self.out_pow = JointStateOut(T.POWER_NAMES, Signer.frame(''))
        self.energy_names = (T.ENERGY_NAMES + ((T.IRON_LOSS_NAME,) if values['iron_loss'] else ())
                             + ((T.INVERTER_LOSS_NAME, T.SWITCHING_LOSS_NAME)
                                if self.out_inv is not None else ()))
        self.out_en = JointStateOut(self.energy_names, Signer.frame(''))

    def _setup_inputs(self) -> None:
        """Gate the voltage command; subscribe the progress and probe echoes, live parameters."""
        self.gate = StepGate([T.CMD_VOLTAGE], self.period)
        self.last_cmd = (0.0, 0.0)
        # the command input: verified, decoded, finite (else the previous command is held; before
        # any, zero volts) as every lock-step input; then on_command takes it
        self.gate_input(T.CMD_VOLTAGE, xy_in, take=self.on_command, hold=self.last_cmd)
        self.create_subscription(Header, T.PROGRESS, self.on_progress, reader(T.PROGRESS))
        self.pub_probe = self.create_publisher(Header, T.PROBE, writer(T.PROBE))
        self.create_subscription(Header, T.PROBE_ECHO, self.on_probe_echo,
                                 reader(T.PROBE_ECHO))
        self._load_offset_next = None       # a live load_offset staged for the next step
        # load_offset's descriptor refuses a value of another type or out of range, one line
        self.add_post_set_parameters_callback(self._after_set_parameters)

    # Live parameters -------------------------------------------------------------------
    def _after_set_parameters(self, parameters) -> None:
        """Stage an accepted ``load_offset`` for the next step boundary."""
        for prm in parameters:
            if prm.name == 'load_offset':
                self._load_offset_next = float(prm.value)

    def _apply_load_offset(self) -> None:
        """
        Put a staged ``load_offset`` in force for the step about to be integrated.

        Step k integrates [t_k, t_k+1]: the offset acts from t_k on. Announced on
        ``/im/status`` (a ``parameters`` event stamped t_k, with the step), so a recording holds
        it.
        """
        tau, self._load_offset_next = self._load_offset_next, None
        k = self.sim.k
        self.sim.set_load_offset(tau)
        self.get_logger().info(f'parameters applied at step {k} (t = {k * self.T_s:.9f} s): '
                               f'load_offset = {tau!r} N m')
        self.status(PARAMETERS, stamp_ns=k * self.period, load_offset=repr(tau), step=k)

    # Startup -----------------------------------------------------------------------------
    #: How long the start condition must hold before step 0: discovery is asynchronous, and a
    #: second graph on the domain is seen a moment after the nodes of one's own.
    SETTLE_S = 0.3

    @property
    def followers(self) -> dict:
        """Return the lossless followers: name -> [acked stamp ns, monotonic time of the ack]."""
        return self.master.followers

    @property
    def started_at(self):
        """Return the wall time of step 0 (None before)."""
        return self.master.started_at

    def ready_to_start(self) -> bool:
        ok = self._start_condition()
        now = time.monotonic()
        if not ok:
            self._ok_since = None
            return False
        if self._ok_since is None:
            self._ok_since = now
        if now - self._ok_since < self.SETTLE_S:
            return False
        return self.mode != 'free_run' or self._probe_passed()

    # Pre-flight probe (free_run) -------------------------------------------------------
    #: Probes of the pre-flight, sent one a period (0.3 s at 1 kHz).
    PROBES = 300

    def _probe_passed(self) -> bool:
        """
        Probe the loop once before step 0 (free_run); tell whether the run may start.

        False while the probe runs; then True, or the run fails with the probe's one line.
        """
        pr = self.probe
        if pr is None:
            nodes = [n for n in self.wait_for
                     if self.peers.get(n, ('', {}))[1].get('role') == 'critical']
            self.go_realtime()              # probed as the run will run
            self.probe = _LoopProbe(self, nodes, self.PROBES, self._step_cost())
            self.get_logger().info(f'free_run: probing the loop through {", ".join(nodes)} '
                                   f'({self.PROBES} probes at T_s = {self.T_s:g} s)')
            return False
        if not pr.over():
            return False
        if pr.verdict is None:
            pr.verdict = v = pr.assess(self.period)
            if v.holds:
                self.get_logger().info(v.text())
            elif self.force_rate:
                self.get_logger().warning(v.text() + '; started anyway (force_rate); the '
                                          'deadline watchdog stops a loop that misses')
            else:
                self.fail(v.text() + '; refusing to start (the plant parameter force_rate: true '
                                     'starts anyway)', **pr.values())
                return False
        return not self.done

    def _step_cost(self) -> float:
        """Return the plant's own step [s] (median of a few on a copy: the run is untouched)."""
        sim = copy.deepcopy(self.sim)
        times = []
        for _ in range(21):
            t0 = time.perf_counter()
            sim.step(0.0, 0.0)
            sim.measure()
            times.append(time.perf_counter() - t0)
        return sorted(times)[len(times) // 2]

    def on_probe_echo(self, msg) -> None:
        if self.probe is not None:
            self.probe.echo(msg.frame_id, msg.stamp.nanosec, time.perf_counter())

    def _start_condition(self) -> bool:
        ok, fault = self.master.start_condition(self.peers)
        if fault is not None:
            self.fail(fault)
        return ok

    def status(self, state: str, level: int = 0, stamp_ns=None, **values) -> None:
        if self.started_at is not None:     # every event after step 0 says when it was taken
            values.setdefault('started_at', f'{self.started_at:.6f}')
        super().status(state, level, stamp_ns, **values)

    def waiting_text(self, missing) -> str:
        nodes = self.master.not_ready(self.peers)
        parts = []
        if missing:
            parts.append('no publisher yet of ' + ', '.join(missing))
        if nodes:
            parts.append('not ready: ' + ', '.join(_peer_text(n, self.peers.get(n))
                                                   for n in nodes))
        return '; '.join(parts) or 'waiting'

    def on_ready(self) -> None:
        """Publish step 0, everyone being there (and start the wall clock in free_run)."""
        self.master.started_at = time.time()
        self.gate.since = time.monotonic()   # step 0's command is due from now, not from startup
        self.status(RUNNING, mode=self.mode, followers=' '.join(self.followers),
                    **(self.probe.values() if self.probe is not None else {}))
        self.get_logger().info(
            f"starting: {', '.join(self.wait_for)} ready; {self.mode}, T_s = {self.T_s:g} s"
            + (f', lossless followers: {", ".join(self.followers)}' if self.followers else ''))
        if self.mode == 'free_run':
            self.gate.follow = True
            self.go_realtime()
            self._t0 = time.perf_counter()
            self.wall_start = self._t0
            self.publish_step()
            sys.setswitchinterval(1e-4)     # hand the GIL over quickly between the two threads
            self._ticker = threading.Thread(target=self._tick_loop, name='plant-ticks',
                                            daemon=True)
            self._ticker.start()
            return
        self.publish_step()

    def _tick_loop(self) -> None:
        """
        Run free_run's clock: a thread of its own that sleeps until t0 + (k+1)·T_s.

        A thread of its own, so the ticks do not queue behind the executor's callbacks. Commands
        are still received by the executor thread (a dict insert under a lock). No busy-waiting: a
        spinning thread would hold the GIL for up to the interpreter's switch interval and starve
        the executor thread.
        """
        T_s, t0 = self.T_s, self._t0
        while not self.done and self.state == RUNNING:
            deadline = t0 + (self.sim.k + 1) * T_s
            left = deadline - time.perf_counter()
            if left > 0:        # sleeping releases the GIL: the executor thread takes commands
                time.sleep(left)
            if self.done or self.state != RUNNING:
                return
            lag = time.perf_counter() - deadline
            if lag > 0.5 * T_s:
                self.overruns += 1          # this tick itself is late (the plant lags)
                if 0.0 < self.max_lag < lag:
                    # catching up would run flat out (at real-time priority) for as long as the
                    # machine is too slow: stop instead, and say so
                    with self._tick_lock:
                        self.fail(f'free_run: the plant is {lag:.3f} s behind the wall clock at '
                                  f't = {self.sim.k * T_s:.6f} s (max_lag = {self.max_lag:g} s): '
                                  f'it cannot integrate T_s = {T_s:g} s in real time here')
                    return
            with self._tick_lock:
                self.on_wall_tick()

    def current_ns(self) -> int:
        return self.sim.k * self.period

    # Peers -------------------------------------------------------------------------------
    def on_peer_status(self, name: str, state: str, values: dict) -> None:
        """Act on the time master's decision about a peer's event (:meth:`TimeMaster.on_peer`)."""
        running = self.state == RUNNING
        what, text = self.master.on_peer(name, state, values, time.monotonic(),
                                         self.current_ns(), running, self.providers)
        if what == YIELD:
            if not self.done:
                self.fail(text)
        elif what == JOINED:
            self.get_logger().info(f"lossless follower '{name}' joined at step {self.sim.k}; "
                                   f'keeping within {self.window} steps of it')
        elif what == LEFT:
            self.get_logger().info(text)
            self._resume()
        elif what == STOP and not self.done:
            self.get_logger().warning(f'run stopped at step {self.sim.k}: {text}')
            self.status(STOPPED, level=1, reason=text)
            self.finish()

    def on_progress(self, msg) -> None:
        name, tag = split_frame(msg.frame_id)
        if name not in self.master.followers:
            return
        ns = msg.stamp.sec * NS_PER_S + msg.stamp.nanosec
        if not self.signer.check_bytes(T.PROGRESS, progress_payload(name, ns), tag):
            self.refuse_unsigned(T.PROGRESS, b'')
            return
        self.master.ack(name, ns, time.monotonic())
        self._resume()

    def _follower_dropped(self, name: str, acked: int) -> None:
        self.get_logger().warning(
            f"follower '{name}' acknowledged nothing after {stamp_text(acked)} for "
            f'{self.input_timeout:.1f} s; continuing without it (its recording will miss '
            f'steps from there on)')

    def _resume(self) -> None:
        parked = self.master.resume()
        if parked is not None and not self.done:
            self.ready(parked)
        elif self.state == DRAINING:
            self._try_finish()

    def check_inputs(self) -> None:
        if self.master.parked is not None or self.state == DRAINING:
            self._resume()
            return
        super().check_inputs()

    # Lock-step ---------------------------------------------------------------------------
    def on_command(self, ns: int, value) -> bool:
        """
        Take a verified, finite command stamped ``ns``; tell whether it goes to the step gate.

        Not before step 0 nor after the run; in free_run it waits for its step's tick instead.
        """
        if self.state not in MASTER_STEPPING:
            if self.started_at is None:         # before step 0: not a command of this run
                self.refuse(T.CMD_VOLTAGE, ns, 'arrived before the run started (no step '
                                               'published)')
            elif not self._after_end_said:      # free_run: the controller was still busy
                self._after_end_said = True
                self.get_logger().info(f'{T.CMD_VOLTAGE} stamped {stamp_text(ns)} arrived '
                                       f'after the run ended ({self.state}); not used')
            return False
        if self.mode == 'free_run':
            self._free_command(ns, *value)
            return False
        return True

    def hold_step(self, inputs) -> bool:
        """
        Park the step while a lossless follower is more than ``follower_window`` steps behind.

        The step resumes when the follower acknowledges (:meth:`_resume`).
        """
        m = self.master
        return bool(m.followers) and m.hold(inputs, (self.sim.k + 1) * self.period,
                                            time.monotonic())

    def step(self, inputs: dict) -> None:
        if self.wall_start is None:
            self.wall_start = time.perf_counter()
        # the command of step j enters the delay line; serially one step is integrated a
        # command (the one whose command acts over it: j - delay), overlapped every step whose
        # acting command is in the line (after the first command steps 0..d, then one a
        # command), so the controller computes the command of step k + 1 while this node
        # integrates step k. Overlapped, the run ends once the last command came too.
        sim, last = self.sim, self.last_step
        self._last_entered = self.gate.expected // self.period
        if not self.enter(inputs[T.CMD_VOLTAGE]):
            return
        steps = sim.delay.ready if self.overlap else 1
        while steps and (last is None or sim.k < last) and self.state == RUNNING:
            self.advance()
            steps -= 1
        if self._final_wait and self._last_entered + 1 >= last and self.state == RUNNING:
            self._drain()

    # Free run ----------------------------------------------------------------------------
    def _free_command(self, ns: int, vx: float, vy: float) -> None:
        with self._tick_lock:
            k = ns // self.period
            t_pub = self._published_at.pop(k, None)
            if t_pub is not None:           # latency of every command, on time or late
                self.latency.add(time.perf_counter() - t_pub)
            if k < self.sim.k:              # its step has already been integrated
                self.late += 1
                return
            self._free_cmd[k] = (vx, vy)

    def on_wall_tick(self) -> None:
        """
        Integrate step k with the command stamped t_k if it arrived by now (its deadline).

        Otherwise hold the previous command and count the step as missed.
        """
        if self.done or self.state != RUNNING:
            return
        k = self.sim.k
        cmd = self._free_cmd.pop(k, None)
        missed = cmd is None
        if missed:
            self.missed += 1
            cmd = self.last_cmd
        for old in [j for j in self._published_at if j < k - 1000]:   # never answered
            del self._published_at[old]
        why = self.deadlines.add(missed)
        if why is not None:         # a protection trip: this step and every later one at 0 V
            self.sim.trip = (self.sim.t, f'{why}: this machine does not hold '
                                         f'{1.0 / self.T_s:g} Hz here; zero voltage')
        if self.enter(cmd):
            self.advance()

    def free_run_stats(self) -> dict:
        return dict(missed=self.missed, late=self.late, overruns=self.overruns,
                    scheduling=self.scheduling, **self.latency.as_values())

    def free_run_text(self) -> str:
        k = self.sim.k
        return (f'free_run ({self.scheduling} scheduling): {self.missed} of {k} steps without a '
                f'command by their deadline ({100.0 * self.missed / max(k, 1):.2f} %), '
                f'{self.late} late, {self.overruns} plant overruns; latency '
                f'{self.latency.describe()}')

    def fail(self, reason: str, **values) -> None:
        if self.mode == 'free_run' and self.state == RUNNING:
            reason += f' ({self.free_run_text()})'
            values.update(self.free_run_stats(), steps=self.sim.k)
        super().fail(reason, **values)

    # Stepping ----------------------------------------------------------------------------
    def enter(self, cmd) -> bool:
        """Enter the command (v_a, v_b) of the next step into the plant's delay line."""
        self.last_cmd = cmd
        try:
            self.sim.enter(*cmd)
        except ValueError as exc:
            self.fail(f'plant step failed: {exc}')
            return False
        return True

    def advance(self) -> None:
        """Integrate step k with the command that acts over it (the delay line's next)."""
        if self._load_offset_next is not None:
            self._apply_load_offset()
        try:
            self.sim.step_entered()
        except (ValueError, FloatingPointError) as exc:
            self.fail(f'plant step failed: {exc}')
            return
        if self.sim.trip is not None:       # the protection is in its safe state: end the run
            self.publish_step(truth=True)   # the truth (and peaks) up to the trip, recorded
            t, reason = self.sim.trip
            self.fail(f'protection trip at t = {t:.9f} s: {reason}')
            return
        self.publish_step()

    def publish_step(self, truth: bool = False) -> None:
        sim = self.sim
        k = sim.k
        ns = k * self.period
        final = self.last_step is not None and k >= self.last_step
        truth = truth or final
        m = sim.measure()
        self.pub_current.publish(self.sign(T.MEAS_CURRENT,
                                           self.out_current.fill(ns, m.i_alpha, m.i_beta)))
        self.pub_shaft.publish(self.sign(T.MEAS_SHAFT,
                                         self.out_shaft.fill(ns, (m.theta_r,), (m.omega_r,))))
        if self.mode == 'free_run':
            self._published_at[k] = time.perf_counter()
        if k % self.clock_every == 0 or final:
            self.pub_clock.publish(clock_bytes(ns))
        i_a, i_b, _, _ = sim.state_currents()
        self._peak_v = max(self._peak_v, math.hypot(*sim.v_applied))
        self._peak_i = max(self._peak_i, math.hypot(i_a, i_b))
        if (self.truth_every and k % self.truth_every == 0) or truth or self.truth_sink:
            tr = sim.truth()
            if self.truth_sink is not None:
                self.truth_sink(ns, tr)
            if (self.truth_every and k % self.truth_every == 0) or truth:
                self.publish_truth(ns, tr)
        if final:
            if self.overlap and self._last_entered + 1 < self.last_step:
                self._final_wait = True     # the commands of the last steps are still due
                return
            self._drain()

    def _drain(self) -> None:
        """After the last step: wait for the lossless followers, then finish."""
        self.state = DRAINING
        self.watchdog.since = time.monotonic()
        self._try_finish()

    def _try_finish(self) -> None:
        """Wait after the last step for lossless followers to acknowledge it, then finish."""
        if self.done:
            return
        if not self.master.drained(self.sim.k * self.period, time.monotonic()):
            return
        wall = time.perf_counter() - (self.wall_start or time.perf_counter())
        k = self.sim.k
        rate = k / wall if wall > 0 else 0.0
        stats = {'steps': k, 'steps_per_s': f'{rate:.1f}', 'rejected': self.rejected,
                 'reason': 'duration reached'}
        text = (f'reached duration {self.duration} s at step {k} ({rate:.0f} steps/s); '
                f'rejected commands: {self.rejected}')
        unsigned = self.refused_by_topic.get(T.CMD_VOLTAGE, 0)
        if unsigned:
            foreign = sorted(self.foreign.get(T.CMD_VOLTAGE, ()))
            stats.update(unsigned_commands=unsigned, foreign_publishers=' '.join(foreign))
            text += (f'; refused {unsigned} commands not signed by this graph (foreign '
                     f'publishers: {", ".join(foreign) or "none named"})')
        if self.mode == 'free_run':
            stats.update(self.free_run_stats())
            text += '; ' + self.free_run_text()
        if self.sim.delay.d:
            stats['overlap'] = 'true' if self.overlap else 'false'
            text += (f'; delay {self.sim.delay.d}, '
                     + ('steps overlapped with the commands' if self.overlap else 'serial order'))
        self.get_logger().info(text)
        self.status(FINISHED, **stats)
        self.finish()

    def publish_truth(self, ns: int, tr: dict) -> None:
        pt, sign = self.pub_truth, self.sign
        pt['voltage'].publish(sign(T.TRUTH_VOLTAGE, self.out_tv.fill(ns, tr['v_alpha'],
                                                                     tr['v_beta'])))
        pt['flux'].publish(sign(T.TRUTH_FLUX, self.out_tf.fill(ns, tr['phi_r_alpha'],
                                                               tr['phi_r_beta'])))
        pt['torque'].publish(sign(T.TRUTH_TORQUE, self.out_tt.fill(
            ns, tr['tau_m'], tr['tau_L'], self.sim.params.b * tr['omega_r'])))
        pt['params'].publish(sign(T.TRUTH_PARAMS, self.out_par.fill(ns, truth_params(tr))))
        pt['power'].publish(sign(T.TRUTH_POWER, self.out_pow.fill(
            ns, [tr[n] for n in T.POWER_NAMES])))
        pt['energy'].publish(sign(T.TRUTH_ENERGY, self.out_en.fill(
            ns, [tr[n] for n in self.energy_names])))
        pt['shaft'].publish(sign(T.TRUTH_SHAFT, self.out_tshaft.fill(
            ns, (tr['theta_r'],), (tr['omega_r'],))))
        pt['peaks'].publish(sign(T.TRUTH_PEAKS, self.out_peaks.fill(
            ns, [self._peak_v, self._peak_i])))
        self._peak_v = self._peak_i = 0.0
        if self.out_temp is not None:
            pt['temperature'].publish(sign(T.TRUTH_TEMPERATURE, self.out_temp.fill(
                ns, [tr[n] for n in T.TEMPERATURE_NAMES])))
        if self.out_inv is not None:
            pt['inverter'].publish(sign(T.TRUTH_INVERTER, self.out_inv.fill(
                ns, [tr[n] for n in T.INVERTER_NAMES])))


class _LoopProbe:
    """
    The free_run pre-flight: probes sent one a period from a thread, their echoes timed.

    A probe's latency is its slowest node's round trip; a probe some node never echoed within
    the grace time after the last one was sent is lost (``assess_probe`` counts it infinitely
    late).
    """

    #: How long the warm-up may take [s] (then the timed probes go out anyway).
    WARMUP_S = 3.0

    def __init__(self, plant: PlantNode, nodes, count: int, compute: float):
        self.nodes = frozenset(nodes)
        self.count, self.compute = count, compute
        self.sent: dict = {}                # probe -> wall time sent
        self.echoes: dict = {}              # probe -> nodes that echoed it
        self.latencies: list = []
        self.verdict = None
        self.run = plant.run_id
        self._done_at = None
        self._grace = 0.5 + 10 * plant.T_s
        self._warm = threading.Event()
        pub, period = plant.pub_probe, plant.T_s

        def send():
            # warm-up: the first samples of a connection took 40-60 ms more in one process (the
            # first deliveries, not the loop): one probe a 10 ms until one comes back from every
            # node (at most WARMUP_S), then the timed ones
            t_end = time.monotonic() + self.WARMUP_S
            w = count
            while not self._warm.wait(0.01) and time.monotonic() < t_end:
                msg = Header(frame_id=self.run)
                msg.stamp.nanosec = w
                self.sent[w] = time.perf_counter()
                pub.publish(msg)
                w += 1
            t0 = time.perf_counter()
            for i in range(count):
                left = t0 + i * period - time.perf_counter()
                if left > 0:
                    time.sleep(left)
                msg = Header(frame_id=self.run)
                msg.stamp.nanosec = i
                self.sent[i] = time.perf_counter()
                pub.publish(msg)
            self._done_at = time.monotonic()
        self._thread = threading.Thread(target=send, name='plant-probe', daemon=True)
        self._thread.start()

    def echo(self, frame: str, i: int, now: float) -> None:
        run, _, name = frame.partition(' ')
        t = self.sent.get(i)
        if run != self.run or name not in self.nodes or t is None:
            return
        got = self.echoes.setdefault(i, set())
        if name in got:
            return
        got.add(name)
        if got == self.nodes:
            if i >= self.count:
                self._warm.set()
            else:
                self.latencies.append(now - t)

    def over(self) -> bool:
        if self._done_at is None:
            return False
        return (len(self.latencies) == self.count
                or time.monotonic() - self._done_at > self._grace)

    def assess(self, period_ns: int):
        return assess_probe(self.latencies, self.count, period_ns / NS_PER_S, self.compute)

    def values(self) -> dict:
        """Return the probe's figures for an event (``/im/status``)."""
        v = self.verdict
        if v is None:
            return {}
        return {'probe_latency_p50_s': f'{v.p50:.6g}', 'probe_latency_p99_s': f'{v.p99:.6g}',
                'probe_lost': v.lost, 'rate_held_hz': v.rate_held or 0}


def _peer_text(name: str, peer) -> str:
    if peer is None:
        return f'{name} (not seen on this ROS domain)'
    state, values = peer
    if state == WAITING and values.get('waiting_for'):
        return f"{name} (waiting for a publisher of {values['waiting_for']})"
    return f'{name} ({state})'


def truth_params(tr: dict) -> list:
    """Return the true parameter vector in the order of ``topics.PARAM_NAMES``."""
    th = tr['L_sr'] / tr['L_r']
    return [tr['R_s'], tr['R_r'], tr['L_s'], tr['L_r'], tr['L_sr'], th, tr['L_sr'] * th,
            tr['R_r'] * th * th]


def _js():
    return (JointState,)


def main(argv=None) -> None:
    sys.exit(node_main(PlantNode, argv))


if __name__ == '__main__':
    main()
