"""
``ros2 run im_recording record``: the recorder of a running graph.

``ros2 run im_recording record [--out bags/<run>.mcap] [--force] [--topics T ...] [--continuous]``

Records a running graph to MCAP: one subscription per topic of :data:`im_common.topics.TOPICS`
(or the given topics; a topic outside the table needs ``topic:=pkg/msg/Type``), written as
received through :class:`~im_recording.bag.BagWriter`. Each message's log time is its header stamp
(simulated time), so the recording lines up with the run and not with the recorder's scheduling.

Lossless across processes. The recorder is a *lossless follower* of the run protocol
(:mod:`im_common.lockstep`): it announces itself on ``/im/status`` and acknowledges on
``/im/progress`` the last step it has received on every lock-step topic; the plant never runs
more than ``follower_window`` steps ahead of that acknowledgement, and the lock-step topics keep
twice that many samples, so no sample can be overwritten before the recorder has it — however busy
the machine. Start it before the graph, or have the plant wait for it (``wait_for`` includes
``recorder``; the launch file's ``record:=PATH`` does both); a recorder that joins a running graph
records losslessly from the step it joined (transient-local topics also give it the last
``LOCKSTEP_DEPTH`` samples before that).

The acknowledgement is the last step received on *every* lock-step topic of the run: a topic that
has brought nothing yet holds it back. Every lock-step topic is checked step by step, from the
run's first step to the plant's final one: the steps missing before the first stamp received,
between stamps and after the last are counted, their ranges logged at the end and written into
the bag's ``recording`` metadata, with the run's end state (finished, stopped, failed,
interrupted) — ``report`` shows them. In ``free_run`` (the plant waits for no one) the recorder's
threads run at ``SCHED_FIFO`` ``rt_priority`` (40), below the control loop's.

It stops when the run ends (the plant's ``finished``/``stopped``/``failed``, after receiving the
last step) unless ``--continuous``; SIGINT / SIGTERM / SIGHUP close the file (summary, footer), so
an interrupted recording is complete up to the stop. A chunk is on disk once it holds 1 s of wall
time or 4 MiB (:data:`im_recording.bag.FLUSH_WALL_S`, :data:`~im_recording.bag.FLUSH_BYTES`,
checked on every message and every :data:`FLUSH_CHECK_S`), so a hard kill costs at most that
last second; ``recover`` salvages the rest and names the missing tail. The
in-process graph records without this node (``DriveGraph(recorder=...)``).
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from typing import Dict, Iterable, List, Optional

from im_common import cdr, realtime
from im_common import topics as T
from im_common.auth import progress_payload, SEPARATOR
from im_common.cli import error as cli_error, parse_args
from im_common.conversions import NS_PER_S
from im_common.host import (enable_stack_dump, end_process, flush, make_executor, ProcessHost,
                            request_stop)
from im_common.lockstep import LockstepNode, READY, stamp_text
from im_common.lockstep_protocol import is_master, LosslessFollower
from im_common.qos import recorder as recorder_qos, writer as writer_qos
from im_common.step_gate import LOCKSTEP_DEPTH
from im_common.stopping import StopSignals
import rclpy
from rclpy.clock import Clock, ClockType
from rclpy.parameter import parameter_value_to_python
from rclpy.parameter_client import AsyncParameterClient
from rclpy.qos import DurabilityPolicy, ReliabilityPolicy
from rclpy.serialization import serialize_message
from rclpy.signals import SignalHandlerOptions
from std_msgs.msg import Header

from .bag import BagError, BagWriter, log_time_offset_for, LOG_TIMES, offered_qos_yaml
from .session import RecordingSession, StampTrack  # noqa: F401 (StampTrack: its old home)

#: Types written raw (exact CDR length known without a full decode); others are taken as
#: message objects and serialized by rclpy (rare: status events).
RAW_TYPES = {T.V3, T.JS, T.CLK}
#: Types whose first field is a header stamp (or a time): their log time is that stamp; other
#: types are logged at the recorder's clock.
STAMPED_TYPES = RAW_TYPES | {T.DIAG, T.HEADER}
REFUSED_PREFIX = T.REFUSED_PREFIX
#: After a stop signal, how long the recorder waits for the plant's final event (the run's other
#: processes got the same signal) before it closes the file [s].
STOP_WAIT_S = 1.0
#: How often the recorder checks whether its open chunk is due (bag.FLUSH_WALL_S) [s]: a SIGKILL
#: costs at most FLUSH_WALL_S + this of the run.
FLUSH_CHECK_S = 0.1


def default_topics() -> Dict[str, str]:
    return {name: T.TOPIC_TYPES[name] for name in T.RECORDED_TOPICS}


def parse_topics(items: Optional[Iterable[str]]) -> Dict[str, str]:
    """Parse ['/a', '/b:=pkg/msg/T'] -> {topic: type} (types of table topics filled in)."""
    table = default_topics()
    if not items:
        return table
    out = {}
    for it in items:
        if ':=' in it:
            topic, tname = it.split(':=', 1)
        else:
            topic, tname = it, T.TOPIC_TYPES.get(it)
            if tname is None:
                raise ValueError(f'topic {it!r} is not in im_common.topics; give its type as '
                                 f'{it}:=pkg/msg/Type')
        if not topic.startswith('/'):
            topic = '/' + topic
        out[topic] = tname
    return out


class RecorderNode(LockstepNode):
    """Subscribes to ``topics`` and writes every message to ``writer``; a lossless follower."""

    critical = False
    default_rt_priority = realtime.DEFAULT_PRIORITY - 10    # free_run: below the loop

    def __init__(self, writer: BagWriter, topics: Optional[Dict[str, str]] = None,
                 node_name: str = 'recorder', depth: int = 1000, lossless: bool = True,
                 **kwargs):
        self.topics = dict(topics or default_topics())
        critical = set(T.LOCKSTEP_TOPICS)
        # the lossless follower's part of the run protocol: what it acknowledges, the run's start
        # and end — the one home of them, which the recording's bookkeeping reads
        self.follower = LosslessFollower(T.ACKED_TOPICS, [t for t in self.topics if t in critical])
        # the recording's bookkeeping (counts, stamp tracks, the run's span, the metadata
        # records): the same session the in-process graph feeds
        self.session = RecordingSession(
            writer, self.topics, recorder='im_recording record', always=T.ACKED_TOPICS,
            announced=lambda: self.follower.announced.get(self.run_id, ()), run=self.follower)
        super().__init__(node_name, **kwargs)
        self.writer = writer
        self.lossless = lossless
        self.trimmed = 0
        self._subs = []
        self._named_at: Dict[str, float] = {}
        self._parameter_clients: Dict[str, object] = {}
        self.session.foreign = self.foreign      # the node's own: LockstepNode names them
        # Announce the lossless follower before subscribing: from the moment the plant sees it,
        # the plant stays within follower_window steps of the recorder's acknowledgements.
        self.start_protocol(input_timeout=5.0, startup_timeout=1e9)
        # a topic's channel is written on its first message, when its publishers are known:
        # the profiles they offer, as the ROS graph lists them (what rosbag2's recorder stores)
        writer.offered_qos = self.offered_qos
        for topic, tname in self.topics.items():
            # the topic table's delivery and recorder history (im_common.topics.Qos), as far as
            # the graph's publishers offer it
            infos = self.get_publishers_info_by_topic(topic)
            reliable = not any(i.qos_profile.reliability == ReliabilityPolicy.BEST_EFFORT
                               for i in infos)
            if not reliable:
                self.get_logger().warning(f'{topic} has a best-effort publisher: recorded '
                                          f'best-effort (samples may be lost)')
            # a report topic (transient-local: a report writer matched late replays its last
            # samples) with a volatile publisher already (a replay of an older bag) is read
            # volatile, or that publisher would not match
            spec = T.SPECS.get(topic)
            volatile_report = (spec is not None and spec.signed and any(
                i.qos_profile.durability == DurabilityPolicy.VOLATILE for i in infos))
            if volatile_report:
                self.get_logger().warning(f'{topic} has a volatile publisher: recorded volatile '
                                          f'(its reports from before the recorder matched are '
                                          f'not replayed to it)')
            qos = recorder_qos(topic, reliable, latched=False if volatile_report else None)
            if spec is None:        # a topic outside the table: the depth asked for
                qos.depth = depth
            writer.expect_topic(topic, tname)   # declared with its publishers' offers
            raw = tname in RAW_TYPES
            cls = cdr.message_class(tname)
            self._subs.append(self.create_subscription(
                cls, topic, self._callback(topic, tname, raw), qos, raw=raw))
        self._progress = self.create_publisher(Header, T.PROGRESS, writer_qos(T.PROGRESS))
        self.create_timer(0.02, self._maybe_ack)
        # durable: a chunk open for FLUSH_WALL_S is on disk even when no message comes to close it
        self.create_timer(FLUSH_CHECK_S, self._flush_due,
                          clock=Clock(clock_type=ClockType.STEADY_TIME))

    def _flush_due(self) -> None:
        try:
            self.writer.flush_due()
        except BagError:
            return          # writer.failed: main ends the recording with that line

    def _fetch_parameters(self, name: str) -> None:
        """
        Fetch each peer's parameters once, over its parameter services.

        Every parameter with its value (defaults included) goes into ``parameters/<name>``
        (:meth:`RecordingSession.add_parameters`, what the in-process graph records from the
        nodes themselves).
        """
        if name == self.get_name() or not self.session.expect_parameters(name):
            return
        client = self._parameter_clients[name] = AsyncParameterClient(self, name)

        def got_values(names, future) -> None:
            res = future.result()
            if res is not None and len(res.values) == len(names):
                self.session.add_parameters(name, {n: parameter_value_to_python(v)
                                                   for n, v in zip(names, res.values)})

        def got_names(future) -> None:
            res = future.result()
            if res is not None:
                names = list(res.result.names)
                client.get_parameters(names).add_done_callback(
                    lambda f: got_values(names, f))
        client.list_parameters().add_done_callback(got_names)

    # The recording's bookkeeping lives in the session; the run protocol reads and sets it here.
    def _session_attribute(name: str, doc: str):       # noqa: N805 - a class-body helper
        return property(lambda self: getattr(self.session, name),
                        lambda self, value: setattr(self.session, name, value), doc=doc)

    counts = _session_attribute('counts', 'messages written per topic')
    track = _session_attribute('track', 'the lock-step topics: their stamp tracks')
    period = _session_attribute('period', "the run's period [ns]")
    stop_at = _session_attribute('stop_at', 'see cut()')
    undecodable = _session_attribute('undecodable', 'messages not recorded: not decodable')
    unsigned = _session_attribute('unsigned', 'messages not signed by this graph, per topic')
    parameters_asked = _session_attribute('parameters_asked', 'nodes whose parameters are due')
    parameters_written = _session_attribute('parameters_written', 'nodes whose are recorded')
    # the run as followed: the lossless follower's, which the session reads (read-only)
    run_start = _session_attribute('run_start', "stamp of the followed run's first step")
    from_start = _session_attribute('from_start', 'the plant counted this recorder from step 0')
    end_state = _session_attribute('end_state', "the run's end (ENDED: the plant left)")
    end_values = _session_attribute('end_values', 'its values')
    del _session_attribute

    def offered_qos(self, topic: str) -> str:
        """Return ``topic``'s ``offered_qos_profiles``: one profile per publisher listed."""
        return offered_qos_yaml(i.qos_profile for i in self.get_publishers_info_by_topic(topic))

    def run_topics(self) -> List[str]:
        """Return the lock-step topics of the run (:meth:`RecordingSession.run_topics`)."""
        return self.session.run_topics()

    # Protocol ---------------------------------------------------------------------------
    def on_ready(self) -> None:
        self.status(READY, lossless='true' if self.lossless else 'false',
                    topics=len(self.topics))

    def on_run_adopted(self) -> None:
        # the period of the run is known before the messages kept for it are checked and written
        if self.follower.event_period:
            self.period = self.follower.event_period
        self._order_chunks()

    def _order_chunks(self) -> None:
        """
        Write the bag in log-time order: chunks sorted by stamp with a bounded reorder window.

        The window is the protocol's bound, LOCKSTEP_DEPTH steps: the plant runs at most
        ``follower_window`` (<= LOCKSTEP_DEPTH / 2) steps ahead of the last step this recorder
        received on every lock-step topic, so no lock-step message arrives later than that; a
        report that still does is written at the file's latest log time and counted. The window
        trails this run's own progress (the last measurement recorded), not the newest stamp the
        chunk holds: another graph's /clock on the domain (unsigned, recorded as it comes) ran
        0.5 s ahead and made 9,221 of this run's 10,001 measurements 'late'.
        """
        if self.period:
            self.writer.set_reorder_window(LOCKSTEP_DEPTH * self.period, progress=self.current_ns)

    def on_peer_status(self, name: str, state: str, values: dict) -> None:
        """Feed the lossless follower: the run's nodes' topics, its time master's events."""
        self._fetch_parameters(name)
        f = self.follower
        if not is_master(values):
            topics = values.get('publishes')
            if topics and values.get('run_id'):
                f.announce(values['run_id'], topics)
                f.set_run(self.run_id)
            return
        f.event_period = int(values.get('T_s_ns', 0) or 0)
        if not self.follow_master(state, values.get('run_id', '')):
            return                          # another run's time master
        if f.event_period:
            self.period = f.event_period
            self._order_chunks()
        if f.master_event(name, state, values, self.period, self.get_name(), time.monotonic()):
            f.set_run(self.run_id)          # the run started: its topics are known
        if values.get('mode') == 'free_run':   # from its 'waiting' on (lockstep.py)
            self._enter_free_run()

    def _enter_free_run(self) -> None:
        """
        Enter free_run: SCHED_FIFO below the loop's priority (as its own process).

        The loop has deadlines, the recorder has none but must keep up with 1/T_s steps, which the
        plant does not wait for. Its threads go to SCHED_FIFO *below* the loop's
        (``rt_priority``, default 40 < the loop's 50): the loop preempts the recorder, and the
        recorder preempts every ordinary process (a busy neighbour can no longer starve it until
        the publishers' histories overflow).
        """
        if self.host is not None:
            self.host.enter_realtime(self, below_loop=True)

    def current_ns(self) -> int:
        """Return the last step recorded on the measured current (its own position in the run)."""
        tr = self.track.get(T.MEAS_CURRENT)
        return tr.last if tr is not None and tr.last is not None else 0

    def check_inputs(self) -> None:      # a follower has no watchdog
        return

    def drained(self) -> bool:
        """
        Tell whether the recording is complete after the run's end.

        Complete: every lock-step topic has reached the plant's last step (or nothing new came for
        a second). A plant that left the graph without a final status (its
        last event lost, or killed) also ends the recording, and the bag says so.
        """
        f, now = self.follower, time.monotonic()
        if f.end_state is None:
            tr = self.track.get(T.MEAS_CURRENT)
            if f.master_left(now, bool(self.counts.get(T.MEAS_CURRENT)),
                             lambda: self.count_publishers(T.MEAS_CURRENT),
                             tr.last if tr is not None else None, self.period):
                self.get_logger().warning('the plant left the graph without a final status; '
                                          'closing the recording')
            if f.end_state is None:
                return False
        behind = False
        for t in self.run_topics():
            end = self.run_bounds(t)[1]
            last = self.track[t].last
            if end is not None and (last is None or last < end):
                behind = True
        return f.drained(now, behind, self._last_msg)

    # Messages ---------------------------------------------------------------------------
    def _callback(self, topic: str, tname: str, raw: bool):
        stamped = tname in STAMPED_TYPES
        signed = topic in T.SIGNED_TOPICS      # lock-step and report topics: the graph's tag
        setpoint = topic == T.SETPOINT
        if raw:
            def cb(data: bytes) -> None:
                if signed and not self.signer.verify(topic, data):
                    self.unsigned_input(topic, data, cb)
                    return
                n = cdr.payload_length(tname, data)
                if n is None or n > len(data):
                    self.undecodable += 1
                    self.get_logger().error(f'{topic}: payload of {len(data)} bytes is not a '
                                            f'valid {tname}; not recorded (so far: '
                                            f'{self.undecodable})')
                    return
                if n < len(data):
                    data = data[:n]
                    self.trimmed += 1
                t = cdr.header_stamp_ns(data)
                if setpoint:
                    self._write_setpoint(data, t)
                    return
                self._write(topic, data, t)
        else:
            def cb(msg) -> None:
                if topic == T.STATUS and not self.signing.status_verifies(msg):
                    self._refused(topic, serialize_message(msg))
                    return
                data = serialize_message(msg)
                t = cdr.header_stamp_ns(data) if stamped else self.get_clock().now().nanoseconds
                self._write(topic, data, t)
        return cb

    EARLY_MAX = T.LOCKSTEP_QOS.record_history
    EARLY_KEEP_NEWEST = True     # a late recorder: no gap between what it kept and what follows

    def refuse_unsigned(self, topic: str, data: bytes) -> None:
        self._refused(topic, data)

    def _refused(self, topic: str, data: bytes) -> None:
        """
        Keep a message not signed by this graph apart on ``/im/refused<topic>``.

        It is evidence, never mixed with the run's data; it is counted and its publisher named.
        """
        n = self.session.refused(topic)
        now = time.monotonic()
        if not self.foreign.get(topic) and now - self._named_at.get(topic, 0.0) > 0.2:
            self._named_at[topic] = now         # ask the graph until the sender has a name
            pubs = self.foreign_publishers(topic)
            self.foreign.setdefault(topic, set()).update(pubs)
            if n == 1 or pubs:
                who = ', '.join(pubs) or ('none named yet: another graph with its own key, or '
                                          'a recording played back')
                self.get_logger().error(f'{topic}: messages not signed by this graph go to '
                                        f'{REFUSED_PREFIX}{topic} (foreign publishers: {who})')
        where = REFUSED_PREFIX + topic
        try:
            self.writer.add_topic(where, self.topics[topic])
            # logged at this run's time, its own stamp kept as publish time: another graph's
            # stamps run on another clock, and its messages ahead of this run moved the bag's
            # reorder window past this run's own (two launches on one domain: 9,553 of 10,001
            # measurements written as late, at the wrong log time)
            self.writer.write_serialized(where, data, self.current_ns(),
                                         publish_ns=cdr.header_stamp_ns(data))
        except (BagError, ValueError, IndexError, KeyError):
            return

    def flush_unverified(self) -> None:
        """
        Record or refuse, at the end, the messages kept until their run was known.

        They are recorded if they verify now, else kept as refused (no run of this graph was seen:
        a playback, another graph).
        """
        self.lock_run()

    def _write(self, topic, data, t) -> None:
        try:
            self.session.write(topic, data, t)
        except BagError:
            return          # closed by a signal while a callback was pending, or its file
            # cannot be written (writer.failed: main ends the recording with that line)
        self._last_msg = time.monotonic()

    def _write_setpoint(self, data: bytes, stamp: int) -> None:
        """
        Record a setpoint at the time it takes effect, with its own stamp as publish time.

        The controller applies a setpoint at the first step at or after its stamp; a stamp in the
        past (0: ``ros2 topic pub``'s unset header) means the step the run is at. Its log time is
        therefore the later of its stamp and the latest step the run had announced to this
        recorder when it arrived (a setpoint stamped 0 was stored at t = 0, before the steps it
        changed); its publish time keeps its own stamp.
        """
        lasts = [tr.last for tr in self.track.values() if tr.last is not None]
        effective = max([stamp] + lasts)
        try:
            self.writer.write_serialized(T.SETPOINT, data, effective, publish_ns=stamp)
        except BagError:
            return
        self.counts[T.SETPOINT] += 1
        self._last_msg = time.monotonic()

    _last_msg = 0.0

    def _maybe_ack(self) -> None:
        """
        Acknowledge the last step received on every lock-step topic of the run.

        A topic that has brought nothing yet (its publisher not yet matched) holds the
        acknowledgement — and so the plant — back, while its samples wait in the publisher's
        history (:meth:`LosslessFollower.next_ack`).
        """
        f = self.follower
        if not f.ack_topics:
            return
        ack = f.next_ack([self.track[t].last for t in f.ack_topics])
        if ack is not None:
            name = self.get_name()
            tag = self.signer.tag_bytes(T.PROGRESS, progress_payload(name, ack))
            h = Header(frame_id=name + SEPARATOR + tag)
            h.stamp.sec, h.stamp.nanosec = divmod(ack, NS_PER_S)
            self._progress.publish(h)

    # Report (the session's) -------------------------------------------------------------
    def count_span(self) -> tuple:
        """Return (first step, last step, how) (:meth:`RecordingSession.count_span`)."""
        return self.session.count_span()

    def cut(self) -> None:
        """Stop counting at the last step announced (:meth:`RecordingSession.cut`)."""
        self.session.cut()

    def joined_at(self) -> Optional[int]:
        """Return the step this recorder joined the run at (:meth:`RecordingSession.joined_at`)."""
        return self.session.joined_at()

    def run_bounds(self, topic: str) -> tuple:
        """(first, last) stamp due on ``topic`` (:meth:`RecordingSession.run_bounds`)."""
        return self.session.run_bounds(topic)

    def gaps(self) -> Dict[str, dict]:
        """Return the steps missing per lock-step topic (:meth:`RecordingSession.gaps`)."""
        return self.session.gaps()

    def span_text(self) -> str:
        """Say over which steps the missing were counted (:meth:`RecordingSession.span_text`)."""
        return self.session.span_text()

    def close_metadata(self, interrupted: Optional[str]) -> dict:
        """Return the ``recording`` record (:meth:`RecordingSession.close_metadata`)."""
        return self.session.close_metadata(interrupted)


def parse_metadata(text: Optional[str]) -> Dict[str, Dict[str, str]]:
    """``--metadata`` JSON: {name: {key: value}} (ValueError naming what is wrong)."""
    if not text:
        return {}
    try:
        doc = json.loads(text)
    except ValueError as exc:
        raise ValueError(f'--metadata is not JSON ({exc})') from None
    if not isinstance(doc, dict) or not all(isinstance(v, dict) for v in doc.values()):
        raise ValueError('--metadata must be a JSON object {"name": {"key": "value"}}')
    return {str(k): {str(kk): str(vv) for kk, vv in v.items()} for k, v in doc.items()}


def _parser() -> argparse.ArgumentParser:
    """Return the ``record`` command's argument parser."""
    ap = argparse.ArgumentParser(prog='record', description='Record the drive graph to MCAP.')
    ap.add_argument('--out', '-o', default=None,
                    help='output file (default bags/run_<YYYYmmdd_HHMMSS>.mcap)')
    ap.add_argument('--force', action='store_true', help='overwrite an existing file')
    ap.add_argument('--topics', nargs='+', default=None,
                    help='topics to record (default: every topic of im_common.topics); '
                         'others as /topic:=pkg/msg/Type')
    ap.add_argument('--duration', type=float, default=None,
                    help='stop after this many wall-clock seconds')
    ap.add_argument('--continuous', action='store_true',
                    help='keep recording after the run ends (until a signal)')
    ap.add_argument('--metadata', default=None, metavar='JSON',
                    help='named metadata records to write into the bag, as JSON '
                         '{"name": {"key": "value"}} (the scenario runner passes its scenario, '
                         'versions and git records)')
    ap.add_argument('--log-time', choices=LOG_TIMES, default='wall',
                    help='log times: wall (default) offset to the wall-clock time the recording '
                         'started (viewers show the run at its date), or simulated (log time = '
                         'stamp); stamps are simulated time either way')
    ap.add_argument('--lossy', action='store_true',
                    help='do not hold the plant back (the recording may then miss steps; they '
                         'are counted and listed)')
    return ap


def _closing_line(node, out: str) -> str:
    """Return the recorder's last line: what it wrote to ``out``, the run's end, missing steps."""
    n = sum(node.counts.values())
    gaps = node.gaps()
    counted = set(node.run_topics())
    missing = {t: g['missing_steps'] for t, g in gaps.items() if g['missing_steps']}
    text = f'record: {n} messages written to {out}'
    if node.end_state:
        text += f"; run {node.end_state} at step {node.end_values.get('step', '?')}"
    span = node.span_text()
    if missing:
        first = {t: gaps[t]['ranges'][:3] for t in missing}
        steps = ', '.join(f"{t}: {gaps[t]['missing_steps']}" for t in gaps
                          if t in counted)
        ranges = '; '.join(
            f'{t} ' + ', '.join(f'{stamp_text(x)}..{stamp_text(y)}' for x, y in r)
            for t, r in first.items())
        text += (f'; MISSING steps, {span}: {steps} (first ranges: {ranges})')
    else:
        text += f'; no step missing on the lock-step topics, {span}'
    return text


def main(argv=None) -> int:
    full = list(sys.argv if argv is None else ['record'] + list(argv))
    a = parse_args(_parser(), full[1:])
    out = a.out or time.strftime('bags/run_%Y%m%d_%H%M%S.mcap')
    # a stop signal from here on, during the start-up too, is a flag the loop acts on: the
    # file is opened and closed complete (an empty, interrupted recording), never left a .part
    with StopSignals() as stop:
        try:
            topics = parse_topics(a.topics)
            extra = parse_metadata(a.metadata)
            writer = BagWriter(out, force=a.force, metadata=extra,
                               log_time_offset_ns=log_time_offset_for(a.log_time))
        except (FileExistsError, ValueError, OSError) as exc:
            return cli_error('record', exc)
        node = ex = None
        enable_stack_dump()
        rclpy.init(args=full, signal_handler_options=SignalHandlerOptions.NO)
        try:
            try:
                node = RecorderNode(writer, topics, lossless=not a.lossy)
            except ValueError as exc:       # a graph key file that cannot be used
                writer.discard()            # nothing was recorded: leave no file behind
                return cli_error('record', exc)
            except BagError:                # its file cannot be written: said below
                if not writer.failed:
                    raise
                return 1
            node.host = ProcessHost()       # free_run may make this process real-time
            node.get_logger().info(f'recording {len(topics)} topics to {out}')
            ex = make_executor()
            ex.add_node(node)
            t_end = None if a.duration is None else time.monotonic() + a.duration
            while rclpy.ok() and not stop.requested:
                if t_end is not None and time.monotonic() >= t_end:
                    break
                if not a.continuous and node.drained():
                    break
                if writer.failed:           # its file cannot be written: end, say why below
                    break
                ex.spin_once(timeout_sec=0.05)
            if not node.drained():
                node.cut()          # stopped while the run goes on: counted to where it was
            if stop.requested:
                request_stop(node, stop.requested)
                # Ctrl-C on `ros2 launch` signals every process at once: keep recording until
                # the plant's own stop event and the last steps are in (bounded: a signal to the
                # recorder alone does not end the run)
                t_stop = time.monotonic() + STOP_WAIT_S
                while rclpy.ok() and time.monotonic() < t_stop and not node.drained():
                    ex.spin_once(timeout_sec=0.02)
        finally:
            try:
                if node is not None:
                    node.flush_unverified()
                    writer.declare_expected()   # topics that had no message, while the node lives
                    node.session.close(stop.requested)
                writer.close()
            except BagError:            # writer.failed: the error line below
                pass
            if writer.failed:
                cli_error('record', writer.failed)
                end_process(node, ex)
                return 1
            if node is not None:
                print(_closing_line(node, out), file=sys.stderr)
                flush(node, timeout=0.5)
            end_process(node, ex)   # the bag is closed: bounded from here, as a node's
    return 0
