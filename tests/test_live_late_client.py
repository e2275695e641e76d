"""
The live view to a client that comes late, and to one that speaks only the former subprotocol.

A client that connects after the run started receives, on subscribing to ``/im/status``, the
latest run event of each node, as a latched topic would give it (``LiveView.latest_status``): a
view opened mid-run shows that the plant is running (or how the run ended), not nothing.

``foxglove-sdk`` (0.30) accepts the WebSocket subprotocol ``foxglove.sdk.v1`` only: the name is a
constant of the SDK, which has no option to accept another. A client that offers only
``foxglove.websocket.v1`` (Lichtblick, Foxglove before the rename) is refused with HTTP 400 — the
test pins what docs/commands.md says such a client sees.
"""
import asyncio
import json
import struct
import subprocess
import time

from im_bringup.processes import executable_path
from im_common import topics as T
import pytest
from test_live import _decoder, _free_port, SUBPROTOCOLS, UNKNOWN_CHANNEL


def _status(name: str, state: str, **values) -> bytes:
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
    from rclpy.serialization import serialize_message
    st = DiagnosticStatus(name=name, message=state,
                          values=[KeyValue(key=k, value=str(v)) for k, v in values.items()])
    return serialize_message(DiagnosticArray(status=[st]))


async def _status_events(port: int, limit_s: float, subprotocols=SUBPROTOCOLS, until=None):
    """Connect, subscribe to /im/status alone; return its events [(node, state)] as they came."""
    from websockets.asyncio.client import connect
    from websockets.exceptions import ConnectionClosed
    ws = await connect(f'ws://127.0.0.1:{port}', subprotocols=subprotocols, max_size=None,
                       proxy=None)
    got, decode, status_id, t0 = [], None, None, time.monotonic()
    try:
        while time.monotonic() - t0 < limit_s and not (until and until(got)):
            try:
                frame = await asyncio.wait_for(ws.recv(), timeout=0.5)
            except asyncio.TimeoutError:
                continue
            except ConnectionClosed:
                break
            if isinstance(frame, str):
                op = json.loads(frame)
                for ch in op.get('channels', []) if op['op'] == 'advertise' else []:
                    if ch['topic'] == T.STATUS and decode is None:
                        decode = _decoder(ch['schemaName'], ch['schema'])
                        status_id = ch['id']
                        await ws.send(json.dumps({'op': 'subscribe', 'subscriptions': [
                            {'id': 1, 'channelId': status_id}]}))
                if op['op'] == 'status' and op['message'] == f'{UNKNOWN_CHANNEL}{status_id}':
                    await asyncio.sleep(0.05)       # advertised before registered (test_live)
                    await ws.send(json.dumps({'op': 'subscribe', 'subscriptions': [
                        {'id': 1, 'channelId': status_id}]}))
                continue
            assert frame[0] == 0x01 and struct.unpack_from('<I', frame, 1)[0] == 1
            got += [(s.name, s.message) for s in decode(bytes(frame[13:])).status]
    finally:
        await ws.close()
    return got


def test_a_late_client_receives_the_latest_status_of_each_node_on_subscribing():
    from im_bringup.live import LiveView
    view = LiveView(port=_free_port())
    try:
        # the run's events, published before any client connected
        for name, state in (('controller', 'waiting'), ('controller', 'ready'),
                            ('observer', 'ready'), ('plant', 'waiting'), ('plant', 'running')):
            view.write(T.STATUS, _status(name, state, run_id='r1'))
        got = asyncio.run(_status_events(view.port, limit_s=60.0,
                                         until=lambda g: len(g) >= 3))
    finally:
        view.close()
    # each node's latest event, none of the older ones, the newest last
    assert got == [('controller', 'ready'), ('observer', 'ready'), ('plant', 'running')], got


def test_a_client_offering_only_the_former_subprotocol_is_refused_with_http_400():
    from websockets.exceptions import InvalidStatus
    from im_bringup.live import LiveView
    view = LiveView(port=_free_port())
    try:
        with pytest.raises(InvalidStatus) as refused:
            asyncio.run(_status_events(view.port, limit_s=5.0,
                                       subprotocols=['foxglove.websocket.v1']))
        assert refused.value.response.status_code == 400
        # and the current name, offered alone, is accepted
        view.write(T.STATUS, _status('plant', 'running'))
        assert asyncio.run(_status_events(view.port, limit_s=60.0, subprotocols=[
            'foxglove.sdk.v1'], until=lambda g: g)) == [('plant', 'running')]
    finally:
        view.close()


@pytest.mark.processes
@pytest.mark.slow
def test_a_client_connecting_mid_run_to_the_live_node_learns_that_the_plant_runs(tmp_path):
    """``scenario --processes --live``: the ``live`` node (``live:=true``), a client mid-run."""
    port = _free_port()
    logs = tmp_path / 'run_logs'
    proc = subprocess.Popen([executable_path('im_bringup', 'scenario'), '--task', 'speed',
                             '--duration', '2.0', '--record', str(tmp_path / 'run.mcap'),
                             '--live-port', str(port), '--no-progress', '--processes'],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        from im_bringup.testing import wait_until

        def plant_log():
            try:
                return (logs / 'plant.log').read_text()
            except OSError:
                return ''
        # the run started (its 'running' event was published) before the client connects
        assert wait_until(lambda: 'starting:' in plant_log() or proc.poll() is not None,
                          timeout=300.0) and proc.poll() is None, plant_log()
        time.sleep(0.5)             # not a timing assertion: let the event reach the live node
        got = asyncio.run(_status_events(port, limit_s=120.0,
                                         until=lambda g: ('plant', 'running') in g))
    finally:
        out, err = proc.communicate(timeout=300)
    assert ('plant', 'running') in got, got
    assert proc.returncode == 0, err[-2000:]
