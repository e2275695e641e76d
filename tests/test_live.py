"""
The live view, watched by a client the project did not write (docs/commands.md).

A WebSocket client (the ``websockets`` package) speaking the Foxglove WebSocket protocol
(``foxglove.sdk.v1``, formerly ``foxglove.websocket.v1``) as Foxglove does: it reads the
advertisements, subscribes to every channel, and decodes each message with the schema the channel
advertised (``rosbags``' own CDR decoder, built from that schema text alone).
What arrives live is what the run's bag holds. The shipped Foxglove layout is the one the SDK's
layout types build, and every series it plots is a field of a topic the graph publishes.
"""
import asyncio
import json
import os
import socket
import struct
import subprocess
import time

from im_bringup.processes import executable_path
from im_common import topics as T
from im_recording.bag import read_messages
import pytest

#: What Foxglove offers: the protocol's current name (foxglove-sdk servers and foxglove_bridge 3
#: accept only it) and its former one (identical messages; ws-protocol servers, bridge 0.8).
SUBPROTOCOLS = ['foxglove.sdk.v1', 'foxglove.websocket.v1']
#: the server's status when a subscription names a channel it has not registered (yet)
UNKNOWN_CHANNEL = 'Unknown channel ID: '
HERE = os.path.dirname(os.path.abspath(__file__))
LAYOUT = os.path.join(HERE, '..', 'src', 'im_bringup', 'config', 'foxglove', 'drive.json')


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(('127.0.0.1', 0))
        return s.getsockname()[1]


def _decoder(schema_name: str, schema_text: str):
    """Return a CDR decoder of the advertised schema: rosbags, from the schema text only."""
    from rosbags.typesys import get_types_from_msg, get_typestore, Stores
    store = get_typestore(Stores.EMPTY)
    store.register(get_types_from_msg(schema_text, schema_name))
    return lambda payload: store.deserialize_cdr(payload, schema_name)


async def _watch(port: int, proc: subprocess.Popen, limit_s: float):
    """Subscribe to each channel as advertised; return {topic: channel}, {topic: [messages]}."""
    from websockets.asyncio.client import connect
    from websockets.exceptions import ConnectionClosed
    t0 = time.monotonic()
    while True:                                  # the server is up once the scenario started
        try:
            ws = await connect(f'ws://127.0.0.1:{port}', subprotocols=SUBPROTOCOLS,
                               max_size=None, proxy=None)    # straight to this host
            break
        except OSError:
            if proc.poll() is not None or time.monotonic() - t0 > limit_s:
                raise AssertionError(f'no live view on port {port} (scenario: {proc.poll()})')
            await asyncio.sleep(0.1)
    assert ws.subprotocol == 'foxglove.sdk.v1'
    channels, decoders, subs, got, by_id = {}, {}, {}, {}, {}

    async def subscribe(chs):
        new = []
        for ch in chs:
            subs[len(subs) + 1] = ch
            new.append({'id': len(subs), 'channelId': ch['id']})
        await ws.send(json.dumps({'op': 'subscribe', 'subscriptions': new}))
    try:
        while time.monotonic() - t0 < limit_s:
            try:
                frame = await asyncio.wait_for(ws.recv(), timeout=1.0)
            except asyncio.TimeoutError:
                if proc.poll() is not None:
                    break
                continue
            except ConnectionClosed:
                break
            if isinstance(frame, str):
                op = json.loads(frame)
                if op['op'] == 'advertise':
                    for ch in op['channels']:
                        channels[ch['topic']] = ch
                        by_id[ch['id']] = ch
                        decoders[ch['id']] = _decoder(ch['schemaName'], ch['schema'])
                    await subscribe(op['channels'])
                elif op['op'] == 'status' and op['message'].startswith(UNKNOWN_CHANNEL):
                    # foxglove-sdk 0.30 sends an advertisement before it registers the channel
                    # for the client: a subscription that comes back at once can find it
                    # unknown (docs/commands.md); it is registered a moment later
                    await asyncio.sleep(0.05)
                    await subscribe([by_id[int(op['message'][len(UNKNOWN_CHANNEL):])]])
                continue
            assert frame[0] == 0x01, frame[:1]           # MessageData
            sub, _log_time = struct.unpack_from('<IQ', frame, 1)
            ch = subs[sub]
            got.setdefault(ch['topic'], []).append(decoders[ch['id']](bytes(frame[13:])))
    finally:
        await ws.close()
    return channels, got


@pytest.mark.processes
@pytest.mark.slow
@pytest.mark.parametrize('processes', [False, True], ids=['in_process', 'processes'])
def test_a_foxglove_client_receives_and_decodes_every_topic_of_a_running_graph(tmp_path,
                                                                               processes):
    """
    ``scenario --live``, in one process and with ``--processes``.

    In one process the graph's publishers are tapped; with ``--processes`` the ``live`` node
    (what ``live:=true`` starts) subscribes to the graph.
    """
    port = _free_port()
    bag = str(tmp_path / 'live.mcap')
    proc = subprocess.Popen([executable_path('im_bringup', 'scenario'), '--task', 'speed',
                             '--duration', '0.3' if processes else '1.0', '--record', bag,
                             '--live-port', str(port), '--no-progress']
                            + (['--processes'] if processes else []),
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        channels, got = asyncio.run(_watch(port, proc, limit_s=240.0))
    finally:
        out, err = proc.communicate(timeout=120)
    assert proc.returncode == 0, err[-2000:]
    said = open(tmp_path / 'live_logs' / 'live.log').read() if processes else err
    assert f'ws://127.0.0.1:{port}' in said
    recorded = {}
    for topic, _t, msg in read_messages(bag):
        recorded.setdefault(topic, []).append(msg)
    # every topic the run publishes throughout is advertised with its schema and arrives
    steady = {t for t, msgs in recorded.items() if len(msgs) >= 10}
    assert {T.MEAS_CURRENT, T.CMD_VOLTAGE, T.OBS_FLUX, T.REF_SHAFT, T.TRUTH_TORQUE,
            T.TRUTH_POWER, T.CLOCK} <= steady
    # (what did arrive, and the live node's log, say which side lost it)
    assert steady <= set(got), (steady - set(got), {t: len(m) for t, m in got.items()}, said)
    for topic, ch in channels.items():
        assert ch['encoding'] == 'cdr' and ch['schemaEncoding'] == 'ros2msg'
        assert ch['schemaName'] == T.TOPIC_TYPES[topic]
    # and it is what the bag holds: the same stamps, the same values
    for topic in (T.MEAS_CURRENT, T.CMD_VOLTAGE, T.TRUTH_TORQUE):
        bag_values = {(m.header.stamp.sec, m.header.stamp.nanosec):
                      (m.vector.x, m.vector.y, m.vector.z) for m in recorded[topic]}
        for m in got[topic]:
            key = (m.header.stamp.sec, m.header.stamp.nanosec)
            assert bag_values[key] == (m.vector.x, m.vector.y, m.vector.z), (topic, key)
    ends = [s for m in got.get(T.STATUS, []) for s in m.status]
    assert any(s.message == 'finished' and s.name == 'plant' for s in ends), \
        [(s.name, s.message) for s in ends]


def test_the_shipped_layout_is_the_sdks_and_plots_fields_the_graph_publishes():
    from im_bringup.live import layout
    with open(LAYOUT) as f:
        shipped = json.load(f)
    assert shipped == json.loads(layout().to_json()), \
        'config/foxglove/drive.json is stale: python -m im_bringup.live --write-layout'
    paths = []

    def walk(node):
        if isinstance(node, dict):
            for k, v in node.items():
                if k == 'value' and isinstance(v, str) and v.startswith('/'):
                    paths.append(v)
                walk(v)
        elif isinstance(node, list):
            for v in node:
                walk(v)
    walk(shipped)
    assert len(paths) >= 20
    from im_recording.msgdefs import typestore
    fields = {}
    for type_name in set(T.TOPIC_TYPES.values()):
        fields[type_name] = typestore().fielddefs[type_name][1]
    for path in paths:
        topic, _, rest = path.partition('.')
        assert topic in T.TOPIC_TYPES, path
        first = rest.split('.')[0].split('[')[0]
        assert first in [f[0] for f in fields[T.TOPIC_TYPES[topic]]], path


def test_a_port_in_use_is_one_line_and_nothing_is_written(tmp_path, capsys):
    from im_bringup.scenario import main
    with socket.socket() as busy:
        busy.bind(('127.0.0.1', 0))
        busy.listen()
        port = busy.getsockname()[1]
        bag, out = tmp_path / 'b.mcap', tmp_path / 'b.json'
        assert main(['--duration', '0.01', '--record', str(bag), '--live-port', str(port),
                     '--no-progress']) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f'scenario: error: live view: cannot serve on 127.0.0.1:{port}: ')
    assert 'Address already in use' in err and '\n' not in err
    assert not bag.exists() and not out.exists() and not list(tmp_path.iterdir())
