"""
The live view: a running graph served over the Foxglove WebSocket protocol (docs/commands.md).

``scenario --live`` and ``ros2 launch im_bringup drive.launch.py live:=true`` serve the graph's
topics on ``ws://127.0.0.1:8765`` (the port of ROS's ``foxglove_bridge``) with the official
``foxglove-sdk``: open Foxglove, "Open connection", Foxglove WebSocket, that address, and the
shipped layout ``share/im_bringup/config/foxglove/drive.json``. Every topic is advertised when its
first message is published, with its ``ros2msg`` schema (the text a bag of the stack carries,
:func:`im_recording.msgdefs.full_definition`) and message encoding ``cdr``: each message goes out
as the node serialized it, stamped with the wall-clock time it was served. Nothing is sent while
no client subscribes to a topic.

Two ways in, one :class:`LiveView`:

- in one process (``scenario --live``): the graph's publishers are tapped as for the recording
  (:class:`LiveTap`), no extra subscription on the ROS graph;
- as processes (``--processes --live``, ``live:=true``): the ``live`` executable, a node that
  subscribes to every topic of the topic table (best effort: it never holds the run back) and
  ends shortly after the run's time master did (its ``finished``, ``stopped`` or ``failed`` on
  ``/im/status``), or on Ctrl-C.
"""
from __future__ import annotations

import argparse
import json
import sys
import threading
import time
from typing import Dict, Optional

from im_common import topics as T
from im_common.cdr import message_class
from im_common.cli import error as cli_error, logger, parse_args
from im_common.lockstep_protocol import END_STATES, is_master
from im_common.stopping import StopSignals
from im_common.topics import STATUS, TOPIC_TYPES
from im_recording.bag import write_atomic
from im_recording.msgdefs import full_definition

#: The Foxglove WebSocket port, foxglove_bridge's default.
DEFAULT_PORT = 8765
#: Seconds the ``live`` node keeps serving after the run ended (the last messages reach the view).
END_GRACE_S = 2.0


class LiveView:
    """
    A Foxglove WebSocket server of the graph's topics (``foxglove-sdk``, its own context).

    ``write(topic, payload)`` serves one CDR-serialized message of a topic of the topic table
    (:data:`im_common.topics.TOPIC_TYPES`); other topics are not served.
    """

    def __init__(self, host: str = '127.0.0.1', port: int = DEFAULT_PORT,
                 name: str = 'im_drive'):
        import foxglove  # heavy: foxglove-sdk only when a view serves
        from foxglove.websocket import ServerListener
        self._foxglove = foxglove
        self.context = foxglove.Context()
        #: The latest /im/status event of each node (name -> payload), in the order they came:
        #: what a client that subscribes later is sent, as a latched topic would give it.
        self.latest_status: Dict[str, bytes] = {}
        self._lock = threading.Lock()
        view = self

        class _Listener(ServerListener):

            def on_subscribe(self, client, channel) -> None:
                if channel.topic == STATUS:
                    view._resend_status()

        try:
            self.server = foxglove.start_server(name=name, host=host, port=port,
                                                context=self.context,
                                                server_listener=_Listener())
        except Exception as exc:  # noqa: BLE001 - the SDK's error for a port in use, one line
            raise OSError(f'live view: cannot serve on {host}:{port}: '
                          f'{str(exc).splitlines()[0] if str(exc) else type(exc).__name__}'
                          ) from None
        self.host = host
        self.channels: Dict[str, object] = {}

    @property
    def port(self) -> int:
        return self.server.port

    @property
    def url(self) -> str:
        return f'ws://{self.host}:{self.port}'

    def channel(self, topic: str):
        """Return the channel of ``topic`` (advertised now, with its schema), None if unknown."""
        ch = self.channels.get(topic)
        if ch is None and topic not in self.channels:
            type_name = TOPIC_TYPES.get(topic)
            if type_name is not None:
                fg = self._foxglove
                schema = fg.Schema(name=type_name, encoding='ros2msg',
                                   data=full_definition(type_name).encode())
                ch = fg.Channel(topic, schema=schema, message_encoding='cdr',
                                context=self.context)
            self.channels[topic] = ch
        return ch

    def write(self, topic: str, payload: bytes) -> None:
        ch = self.channels.get(topic) or self.channel(topic)
        if topic == STATUS:
            self._keep_status(bytes(payload))
        if ch is not None and ch.has_sinks():
            ch.log(bytes(payload))

    def _keep_status(self, payload: bytes) -> None:
        """Keep ``payload`` as the latest /im/status event of its node (rare: not the hot path)."""
        # heavy: rclpy (and diagnostic_msgs) only to read a status event
        from diagnostic_msgs.msg import DiagnosticArray
        from rclpy.serialization import deserialize_message
        try:
            names = [st.name for st in deserialize_message(payload, DiagnosticArray).status]
        except Exception:  # noqa: BLE001 - not a DiagnosticArray: served, never kept
            return
        with self._lock:
            for name in names:
                self.latest_status.pop(name, None)      # the newest last, as they came
                self.latest_status[name] = payload

    def _resend_status(self) -> None:
        """
        Serve the latest /im/status event of each node again: a client has just subscribed.

        The SDK (foxglove-sdk 0.30) logs to every subscriber of a channel, not to one client:
        a client subscribed before receives these events once more (states, not counts).
        """
        ch = self.channels.get(STATUS)
        with self._lock:
            events = list(self.latest_status.values())
        if ch is not None:
            for payload in dict.fromkeys(events):
                ch.log(payload)

    def close(self) -> None:
        self.server.stop()


class LiveTap:
    """
    A recorder sink for :class:`im_bringup.graph.DriveGraph` that also serves every message live.

    ``write`` hands each message to ``tap`` (the recording's :class:`im_recording.traces.Tap`)
    and to ``view``; everything else (its ``writer``, its traces) is the tap's.
    """

    def __init__(self, tap, view: LiveView):
        self._tap, self._view = tap, view

    def write(self, topic: str, payload) -> None:
        self._tap.write(topic, payload)
        self._view.write(topic, payload)

    def __getattr__(self, name):
        return getattr(self._tap, name)

    def __setattr__(self, name, value):
        if name in ('_tap', '_view'):
            object.__setattr__(self, name, value)
        else:
            setattr(self._tap, name, value)


def layout():
    """
    Build the shipped Foxglove layout, ``config/foxglove/drive.json``, with the SDK's types.

    Eight plots against the simulated time (each message's ``header.stamp``, the same live and in
    a bag): currents, voltages, rotor flux, speed and position against their references, torque,
    losses, and the adapter's estimates against the true parameters. Field indices come from the
    topic table's name lists.
    """
    import foxglove.layouts as fl  # heavy: foxglove-sdk only to build the layout

    def series(path, label, dashed=False):
        return fl.PlotSeries(value=path, label=label, timestamp_method='headerStamp',
                             line_style='dashed' if dashed else None)

    def plot(title, *paths):
        return fl.PlotPanel(title=title, config=fl.PlotConfig(paths=list(paths),
                                                              show_legend=True))

    def js(topic, names, name, field='position'):
        return f'{topic}.{field}[{names.index(name)}]'

    power, est, par = T.POWER_NAMES, T.ESTIMATE_NAMES, T.PARAM_NAMES
    panels = [
        plot('stator current [A]',
             series(f'{T.MEAS_CURRENT}.vector.x', 'i_alpha'),
             series(f'{T.MEAS_CURRENT}.vector.y', 'i_beta'),
             series(f'{T.REF_CURRENT}.vector.x', 'i*_alpha', True),
             series(f'{T.REF_CURRENT}.vector.y', 'i*_beta', True),
             series(f'{T.OBS_CURRENT}.vector.x', 'i_alpha observed')),
        plot('stator voltage [V]',
             series(f'{T.CMD_VOLTAGE}.vector.x', 'V_alpha command'),
             series(f'{T.CMD_VOLTAGE}.vector.y', 'V_beta command'),
             series(f'{T.TRUTH_VOLTAGE}.vector.x', 'V_alpha applied', True),
             series(f'{T.TRUTH_VOLTAGE}.vector.y', 'V_beta applied', True)),
        plot('rotor flux [Wb]',
             series(f'{T.OBS_FLUX}.vector.x', 'phi_alpha observed'),
             series(f'{T.OBS_FLUX}.vector.y', 'phi_beta observed'),
             series(f'{T.TRUTH_FLUX}.vector.x', 'phi_alpha true', True),
             series(f'{T.TRUTH_FLUX}.vector.y', 'phi_beta true', True),
             series(f'{T.REF_FLUX}.vector.z', '|phi|* reference')),
        plot('speed [rad/s]',
             series(f'{T.MEAS_SHAFT}.velocity[0]', 'omega measured'),
             series(f'{T.REF_SHAFT}.velocity[0]', 'omega*', True),
             series(f'{T.OBS_SPEED}.velocity[0]', 'omega observed (sensorless)')),
        plot('position [rad]',
             series(f'{T.MEAS_SHAFT}.position[0]', 'theta measured'),
             series(f'{T.REF_SHAFT}.position[0]', 'theta*', True)),
        plot('torque [N m]',
             series(f'{T.TRUTH_TORQUE}.vector.x', 'tau_m'),
             series(f'{T.REF_SHAFT}.effort[0]', 'tau*', True),
             series(f'{T.TRUTH_TORQUE}.vector.y', 'tau_L load'),
             series(f'{T.TRUTH_TORQUE}.vector.z', 'b omega friction')),
        plot('losses [W]', *[series(js(T.TRUTH_POWER, power, n), n)
                             for n in ('P_cu_s', 'P_cu_r', 'P_core', 'P_friction')]),
        plot('adapter estimates vs true', *[
            s for n in ('R_r', 'theta', 'L_M', 'R_R')
            for s in (series(js(T.ADAPT_ESTIMATE, est, n), f'{n} estimate'),
                      series(js(T.TRUTH_PARAMS, par, n), f'{n} true', True))]),
    ]
    pairs = zip(panels[::2], panels[1::2])
    rows = [fl.SplitItem(content=fl.SplitContainer(direction='row', items=[
        fl.SplitItem(content=a), fl.SplitItem(content=b)])) for a, b in pairs]
    return fl.Layout(content=fl.SplitContainer(direction='column', items=rows))


def write_layout(path: str) -> None:
    """Write :func:`layout` as JSON (indented, as shipped)."""
    write_atomic(path, json.dumps(json.loads(layout().to_json()), indent=1) + '\n')


def _run_ended(payload: bytes) -> Optional[str]:
    """Return the time master's end state in a serialized ``/im/status`` message, else None."""
    # heavy: rclpy (and diagnostic_msgs) only to read a status event
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.serialization import deserialize_message
    for st in deserialize_message(payload, DiagnosticArray).status:
        if st.message in END_STATES and is_master({kv.key: kv.value for kv in st.values}):
            return st.message
    return None


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog='live', description=__doc__.split('\n\n')[0])
    ap.add_argument('--host', default='127.0.0.1',
                    help='address to serve on (default 127.0.0.1; 0.0.0.0: every interface)')
    ap.add_argument('--port', type=int, default=DEFAULT_PORT,
                    help=f'WebSocket port (default {DEFAULT_PORT}, as foxglove_bridge)')
    ap.add_argument('--keep', action='store_true',
                    help='keep serving after the run ended (until Ctrl-C)')
    ap.add_argument('--write-layout', metavar='JSON',
                    help='only write the shipped Foxglove layout (config/foxglove/drive.json)')
    return ap


def main(argv=None) -> int:
    """``ros2 run im_bringup live``: serve the graph on this ROS domain until its run ends."""
    # heavy: rclpy only for the live command (LiveView and layout() need none)
    import rclpy
    from rclpy.context import Context
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    log = logger('live')
    args = parse_args(build_parser(), argv)
    if args.write_layout:
        write_layout(args.write_layout)
        return 0
    try:
        view = LiveView(args.host, args.port)
    except OSError as exc:
        return cli_error('live', exc)
    from im_common.host import enable_stack_dump  # heavy: im_common.host imports rclpy
    enable_stack_dump()
    ctx = Context()
    rclpy.init(args=['live'] + (sys.argv[1:] if argv is None else []), context=ctx)
    node = rclpy.create_node('live', context=ctx)
    from im_common.lockstep import make_executor  # heavy: im_common.lockstep imports rclpy
    executor = make_executor(ctx)
    executor.add_node(node)
    ended = {}
    qos = QoSProfile(depth=100, reliability=ReliabilityPolicy.BEST_EFFORT)

    def forward(topic):
        def cb(payload):
            view.write(topic, payload)
            if topic == T.STATUS and 'state' not in ended:
                state = _run_ended(payload)
                if state is not None:
                    ended.update(state=state, at=time.monotonic())
        return cb
    for topic, type_name in T.TOPIC_TYPES.items():
        if topic.startswith('/im/reestimate'):
            continue                    # replay's, not a graph topic
        node.create_subscription(message_class(type_name), topic, forward(topic), qos, raw=True)
    log(f'serving this ROS domain (ROS_DOMAIN_ID={ctx.get_domain_id()}) on {view.url}')
    with StopSignals() as stop:
        try:
            while rclpy.ok(context=ctx) and not stop.requested:
                executor.spin_once(timeout_sec=0.1)
                if ('at' in ended and not args.keep
                        and time.monotonic() - ended['at'] > END_GRACE_S):
                    log(f"the run {ended['state']}; done")
                    break
        finally:
            executor.shutdown()
            node.destroy_node()
            rclpy.try_shutdown(context=ctx)
            view.close()
    return 0


if __name__ == '__main__':
    sys.exit(main())
