"""
Topic names, message types and field layouts of the stack: the one table every node uses.

αβ pairs travel as ``geometry_msgs/Vector3Stamped`` (x = α, y = β, z as noted). Named vectors of
scalars (shaft state, parameter sets, powers, energies) travel as ``sensor_msgs/JointState`` with
the names below in ``name`` and the values in ``position`` (shaft topics use position/velocity/
effort as ROS does). Every stamp is simulated time t_k = k·T_s, exact in integer nanoseconds.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Dict, Tuple

from .step_gate import LOCKSTEP_DEPTH


@dataclass(frozen=True)
class Qos:
    """
    How a topic is delivered: reliability, durability and the histories of its endpoints.

    ROS-free parameters of a QoS profile (:func:`im_common.qos.profile` builds the rclpy one):
    ``history`` is its writers' keep-last depth, ``reader_history`` a node's reader's (a gate, the
    run protocol), ``record_history`` the recorder's.
    """

    reliable: bool = True
    latched: bool = False           # transient-local: a late-joining reader gets the backlog
    history: int = 10
    reader_history: int = 10
    record_history: int = 1000


#: The lock-step topics. History: deeper is not safer: a reliable writer resends its whole backlog
#: to a reader that lags, from the loop's real-time threads in free_run. Tried with 1000: two
#: free_run graphs on one domain under heavy machine load froze in 2 of 3 runs (a middleware thread
#: of a plant at SCHED_FIFO 50 at 90 % of a core for minutes; its clock thread never ran again). In
#: lock-step the follower window keeps every reader within ``LOCKSTEP_DEPTH // 2`` steps.
#: A node's *readers* keep ten writer histories: the samples of every writer on a topic share it,
#: so another graph on the domain (or a rogue) that delivers more than a history's worth between
#: two takes of a busy node — its writers' transient-local backlog replayed at a late discovery,
#: or its own run while this node is starved — pushed this graph's untaken sample out, and a
#: lock-step run stalled (docs/security.md). The recorder's reader is deeper still: a few seconds
#: of a run that had not yet seen the recorder (joining late, or slow to start), ≈ 100 bytes each.
LOCKSTEP_QOS = Qos(latched=True, history=LOCKSTEP_DEPTH, reader_history=10 * LOCKSTEP_DEPTH,
                   record_history=50 * LOCKSTEP_DEPTH)
#: The report topics (ground truth, references, the observer's current): transient-local, so a
#: recorder matched with a report writer after its first samples still records them (matching is
#: per writer: with another graph on the domain a recorder ready for the run's lock-step writers
#: may not have matched every report writer yet; a volatile report of the first steps was lost —
#: the bag lacked the references of steps 0, 10 and 20 in one of two runs of two launches on one
#: domain). ``LOCKSTEP_DEPTH`` reports: more than the plant may run ahead of a lossless follower.
REPORT_QOS = Qos(latched=True, history=LOCKSTEP_DEPTH, reader_history=LOCKSTEP_DEPTH)
#: The run-protocol events: transient-local, so a node that starts late sees them. Readers keep
#: a deeper history: while a node is still starting, the events of every node on the domain
#: (another graph's too) queue up, and the time master's one ``waiting`` must not be pushed out.
STATUS_QOS = Qos(latched=True, history=20, reader_history=1000)
#: What any publisher must match (setpoints from ``ros2 topic pub``): reliable, volatile.
DATA_QOS = Qos(history=10, reader_history=10)
#: free_run's pre-flight probes and their echoes (``im_common.timing``): one pre-flight and more.
PROBE_QOS = Qos(history=500, reader_history=500)


@dataclass(frozen=True)
class TopicSpec:
    name: str
    type: str  # noqa: A003 - ROS type name, e.g. 'geometry_msgs/msg/Vector3Stamped'
    publisher: str      # node that publishes it
    layout: str         # how the fields are used
    critical: bool = False   # on the lock-step critical path
    recorded: bool = True    # part of a default recording
    signed: bool = False     # a report its graph node tags (lock-step topics are tagged too)
    #: its delivery (None: by its kind: lock-step, report, else reliable volatile keep-last 10)
    delivery: Qos = None
    #: a lossless follower acknowledges its progress on it, which holds the plant back (every
    #: graph has it; the adapter's estimates are recorded as they come but hold nothing back)
    acked: bool = False

    @property
    def qos(self) -> Qos:
        """Return how this topic is delivered (:class:`Qos`)."""
        if self.delivery is not None:
            return self.delivery
        return LOCKSTEP_QOS if self.critical else REPORT_QOS if self.signed else DATA_QOS


CLOCK = '/clock'
MEAS_CURRENT = '/im/measured/current'
MEAS_SHAFT = '/im/measured/shaft'
CMD_VOLTAGE = '/im/command/voltage'
OBS_FLUX = '/im/observer/flux'
OBS_CURRENT = '/im/observer/current'
OBS_SPEED = '/im/observer/speed'
ADAPT_ESTIMATE = '/im/adapter/estimate'
REF_SHAFT = '/im/reference/shaft'
REF_CURRENT = '/im/reference/current'
REF_FLUX = '/im/reference/flux'
SETPOINT = '/im/setpoint'
TRUTH_VOLTAGE = '/im/truth/voltage'
TRUTH_FLUX = '/im/truth/flux'
TRUTH_TORQUE = '/im/truth/torque'
TRUTH_PARAMS = '/im/truth/parameters'
TRUTH_POWER = '/im/truth/power'
TRUTH_ENERGY = '/im/truth/energy'
TRUTH_SHAFT = '/im/truth/shaft'
TRUTH_PEAKS = '/im/truth/peaks'
TRUTH_TEMPERATURE = '/im/truth/temperature'
TRUTH_INVERTER = '/im/truth/inverter'
REEST_FLUX = '/im/reestimate/observer/flux'          # replay --reestimate (not a graph topic)
REEST_CURRENT = '/im/reestimate/observer/current'
STATUS = '/im/status'
PROGRESS = '/im/progress'
PROBE = '/im/probe'
PROBE_ECHO = '/im/probe/echo'
#: Where a recorder keeps the messages not signed by the graph it records, under their topic's
#: name (``/im/refused/im/command/voltage``): evidence, never replayed, counted by ``report``.
REFUSED_PREFIX = '/im/refused'

V3 = 'geometry_msgs/msg/Vector3Stamped'
JS = 'sensor_msgs/msg/JointState'
CLK = 'rosgraph_msgs/msg/Clock'
DIAG = 'diagnostic_msgs/msg/DiagnosticArray'
HEADER = 'std_msgs/msg/Header'

SHAFT_JOINT = 'rotor'
# the adapter's estimate message: the first four, and L_sigma with the adapter's feed
# 'inverse_gamma' (then the controller and observer take the inverse-Γ set, docs/adaptation.md §7),
# and R_s when that adapter runs sensorless (it estimates R_s then, docs/sensorless.md §3)
ESTIMATE_NAMES = ('R_r', 'theta', 'L_M', 'R_R', 'L_sigma', 'R_s')
PARAM_NAMES = ('R_s', 'R_r', 'L_s', 'L_r', 'L_sr', 'theta', 'L_M', 'R_R')
POWER_NAMES = ('P_in', 'P_cu_s', 'P_cu_r', 'P_core', 'P_friction', 'P_load', 'P_param')
ENERGY_NAMES = ('E_in', 'E_cu_s', 'E_cu_r', 'E_core', 'E_friction', 'W_load', 'E_param',
                'W_mag', 'E_kin')
# appended to /im/truth/energy when the core loss acts (docs/plant.md §3): the iron loss the plant
# dissipated [J] (= E_core), inside the energy balance then
IRON_LOSS_NAME = 'E_iron'
# appended to /im/truth/energy behind an inverter (docs/plant.md §1): the inverter's losses [J]
# (conduction and switching), outside the motor's balance (E_in + E_inv is what the DC link gave),
# then its switching losses alone [J] (a share of E_inv; 0 without e_sw)
INVERTER_LOSS_NAME = 'E_inv'
SWITCHING_LOSS_NAME = 'E_switching'
# /im/truth/peaks: the largest |V_s| applied and true |i_s| over every step since the previous
# sample (the figures of merit take their peaks from every step, not from the samples)
PEAK_NAMES = ('V_max', 'i_max')
# /im/truth/temperature (a motor with a ``thermal:`` block): winding temperatures [°C]
TEMPERATURE_NAMES = ('T_stator', 'T_rotor')
# /im/truth/inverter (a run with an ``inverter:`` block): the DC link [V], the true phase currents
# at the period's end [A], the peak-to-peak phase-current ripple within the period [A], the
# inverter's own losses over the last period (dead time, on-state drops, switching) [W] and their
# switching share [W]
INVERTER_NAMES = ('V_dc', 'i_a', 'i_b', 'i_c', 'i_ripple_pp', 'P_inverter', 'P_switching')


def _lockstep(name: str, type_: str, publisher: str, layout: str,
              acked: bool = False) -> TopicSpec:
    """Return the spec of a lock-step topic (critical path, signed, ``LOCKSTEP_QOS``)."""
    return TopicSpec(name, type_, publisher, layout, critical=True, acked=acked)


def _report(name: str, type_: str, publisher: str, layout: str) -> TopicSpec:
    """Return the spec of a report topic: not lock-step, but signed by its graph node."""
    return TopicSpec(name, type_, publisher, layout, signed=True)


TOPICS: Tuple[TopicSpec, ...] = (
    TopicSpec(CLOCK, CLK, 'plant', 'simulated time (every clock_decimation steps, and the last)'),
    _lockstep(MEAS_CURRENT, V3, 'plant', 'measured stator current i_alpha, i_beta [A]', True),
    _lockstep(MEAS_SHAFT, JS, 'plant',
              "measured shaft: name ['rotor'], position theta_r [rad], velocity omega_r [rad/s]",
              True),
    _lockstep(CMD_VOLTAGE, V3, 'controller', 'stator voltage command V_alpha, V_beta [V]', True),
    _lockstep(OBS_FLUX, V3, 'observer', 'rotor-flux estimate phi_r_alpha, phi_r_beta [Wb]',
              True),
    _report(OBS_CURRENT, V3, 'observer', 'stator-current estimate i_alpha, i_beta [A]'),
    _lockstep(OBS_SPEED, JS, 'observer',
              "sensorless runs: speed estimate in place of the measured shaft: name ['rotor'], "
              'position theta_hat = integral of omega_hat [rad] (relative), velocity omega_hat '
              '[rad/s]'),
    _lockstep(ADAPT_ESTIMATE, JS, 'adapter',
              "parameter estimates: name ['R_r', 'theta', 'L_M', 'R_R'(, 'L_sigma'(, 'R_s'))] "
              'in position [SI]'),
    _report(REF_SHAFT, JS, 'controller',
            'reference: position theta* [rad], velocity omega* [rad/s], effort tau* [N m]'),
    _report(REF_CURRENT, V3, 'controller', 'stator-current reference i*_alpha, i*_beta [A]'),
    _report(REF_FLUX, V3, 'controller',
            'rotor-flux reference phi*_alpha, phi*_beta [Wb]; z = flux magnitude phi_d* [Wb]'),
    TopicSpec(SETPOINT, JS, 'user',
              'setpoint: position [rad] or velocity [rad/s] or effort [N m] (one field set)'),
    _report(TRUTH_VOLTAGE, V3, 'plant', 'voltage applied by the inverter (after its limit) [V]'),
    _report(TRUTH_FLUX, V3, 'plant', 'true rotor flux phi_r_alpha, phi_r_beta [Wb]'),
    _report(TRUTH_TORQUE, V3, 'plant',
            'x = electromagnetic torque tau_m, y = load torque tau_L, '
            'z = friction b*omega [N m]'),
    _report(TRUTH_PARAMS, JS, 'plant', f'true parameters {list(PARAM_NAMES)} in position'),
    _report(TRUTH_POWER, JS, 'plant', f'power rates {list(POWER_NAMES)} [W] in position'),
    _report(TRUTH_ENERGY, JS, 'plant', f'energy integrals {list(ENERGY_NAMES)} [J] in position '
            f'(+ {IRON_LOSS_NAME!r} when the core loss acts, + {INVERTER_LOSS_NAME!r} and '
            f'{SWITCHING_LOSS_NAME!r} behind an inverter)'),
    _report(TRUTH_SHAFT, JS, 'plant',
            "true shaft: name ['rotor'], position theta_r [rad], velocity omega_r [rad/s] "
            '(without measurement noise)'),
    _report(TRUTH_PEAKS, JS, 'plant',
            f'peaks {list(PEAK_NAMES)} [V, A] in position: the largest applied voltage and true '
            'current magnitudes over every step since the previous sample'),
    _report(TRUTH_TEMPERATURE, JS, 'plant',
            f'winding temperatures {list(TEMPERATURE_NAMES)} [°C] in position (motors with a '
            'thermal block)'),
    _report(TRUTH_INVERTER, JS, 'plant',
            f'inverter {list(INVERTER_NAMES)} [V, A, A, A, A, W] in position (runs with an '
            'inverter block)'),
    TopicSpec(STATUS, DIAG, 'every node',
              'run protocol: one status per event (waiting, ready, running, parameters, finished, '
              'stopping, stopped, failed); name = node, message = state, values = details; '
              'stamp = simulated time of the event', delivery=STATUS_QOS),
    TopicSpec(PROGRESS, HEADER, 'lossless followers (recorder)',
              'flow control: stamp = last step received completely, frame_id = node; the plant '
              'stays within follower_window steps of it', recorded=False),
    TopicSpec(PROBE, HEADER, 'plant',
              "free_run's pre-flight latency probe, before step 0: stamp = the probe's number, "
              "frame_id = the run's id", recorded=False, delivery=PROBE_QOS),
    TopicSpec(PROBE_ECHO, HEADER, 'every node that follows the run',
              "the probe's echo, sent back at once: the probe's stamp, frame_id = run id and node",
              recorded=False, delivery=PROBE_QOS),
)

SPECS: Dict[str, TopicSpec] = {t.name: t for t in TOPICS}
TOPIC_TYPES: Dict[str, str] = {t.name: t.type for t in TOPICS}
LOCKSTEP_TOPICS: Tuple[str, ...] = tuple(t.name for t in TOPICS if t.critical)
#: Every topic whose messages carry the graph's tag in ``header.frame_id`` (``im_common.auth``):
#: the lock-step ones and the reports of the graph's nodes (truth, references, observer current).
#: Receivers and the recorder refuse a message of these without their graph's tag for the run.
#: ``/clock`` has no header to carry one; ``/im/status`` and ``/im/progress`` are tagged apart.
SIGNED_TOPICS: Tuple[str, ...] = tuple(t.name for t in TOPICS if t.critical or t.signed)
RECORDED_TOPICS: Tuple[str, ...] = tuple(t.name for t in TOPICS if t.recorded)
#: The lock-step topics whose progress a lossless follower acknowledges (``TopicSpec.acked``).
ACKED_TOPICS: Tuple[str, ...] = tuple(t.name for t in TOPICS if t.acked)


def qos_of(topic: str) -> Qos:
    """Return the delivery of ``topic`` (a topic outside the table: reliable, volatile)."""
    spec = SPECS.get(topic)
    return spec.qos if spec is not None else DATA_QOS


def markdown_table() -> str:
    """Return the README's topic table, generated from this module so the two cannot drift."""
    rows = ['| topic | type | publisher | content |', '| --- | --- | --- | --- |']
    for t in TOPICS:
        crit = ' (lock-step)' if t.critical else ' (signed)' if t.signed else ''
        rows.append(f'| `{t.name}` | `{t.type}` | {t.publisher}{crit} | {t.layout} |')
    return '\n'.join(rows)
