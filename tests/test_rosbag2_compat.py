"""
Every bag the project writes opens in rosbag2 Jazzy.

Its ``rosbag2`` record and channel metadata decode by rosbag2's own rules (:mod:`rosbag2_rules`),
its schemas are the text rosbag2's recorder writes, its channels carry the QoS the publishers
offer, and both recording paths (in-process ``scenario --record`` and ``scenario --processes
--record``) write the same run metadata.
"""
import os
import subprocess

from im_bringup.processes import executable_path
from im_common import topics as T
from im_recording.bag import BagWriter, info
from im_recording.msgdefs import full_definition, msg_file, SEPARATOR
import pytest
from rosbag2_rules import decode_bag_metadata, read_metadata, Rosbag2Error

#: The topics whose publishers offer transient-local durability (lockstep_qos, report_qos,
#: status_qos): all but /clock and the user's setpoints.
TRANSIENT_LOCAL = set(T.SIGNED_TOPICS) | {T.STATUS}


def _check_against_channels(md):
    """Return the record's topics are the file's channels, with the same types, QoS and counts."""
    rec = {t['name']: t for t in md['topics_with_message_count']}
    assert set(rec) == set(md['channels'])
    for topic, ch in md['channels'].items():
        assert rec[topic]['type'] == ch['type']
        assert rec[topic]['serialization_format'] == ch['encoding'] == 'cdr'
        assert rec[topic]['offered_qos_profiles'] == ch['offered_qos_profiles']
        assert rec[topic]['message_count'] == ch['message_count']
        assert rec[topic]['type_description_hash'] == ch['topic_type_hash']
        assert ch['topic_type_hash'].startswith('RIHS01_')
        assert all(p['format'] == 9 for p in ch['offered_qos_profiles'])


def test_a_written_bag_decodes_by_rosbag2_rules(tmp_path):
    path = tmp_path / 'w.mcap'
    with BagWriter(path) as w:
        w.write_vector3(T.MEAS_CURRENT, 100, 1.0, 2.0)
        w.write_vector3(T.MEAS_CURRENT, 200, 1.0, 2.0)
    md = read_metadata(path)
    assert md['version'] == 9 and md['storage_identifier'] == 'mcap'
    assert md['message_count'] == 2 and md['ros_distro']
    assert md['relative_file_paths'] == ['w.mcap'] and md['files'][0]['path'] == 'w.mcap'
    _check_against_channels(md)


GOOD = """version: 9
storage_identifier: mcap
duration: {nanoseconds: 5}
starting_time: {nanoseconds_since_epoch: 1}
message_count: 1
topics_with_message_count:
- topic_metadata:
    name: /a
    type: std_msgs/msg/Header
    serialization_format: cdr
    offered_qos_profiles:
    - {history: keep_last, depth: 10, reliability: reliable, durability: volatile,
       deadline: {sec: 0, nsec: 0}, lifespan: {sec: 0, nsec: 0}, liveliness: automatic,
       liveliness_lease_duration: {sec: 0, nsec: 0}, avoid_ros_namespace_conventions: false}
    type_description_hash: RIHS01_x
  message_count: 1
compression_format: ''
compression_mode: ''
relative_file_paths: [a.mcap]
files: [{path: a.mcap, starting_time: {nanoseconds_since_epoch: 1}, duration: {nanoseconds: 5},
         message_count: 1}]
custom_data: {}
ros_distro: jazzy
"""


@pytest.mark.parametrize('broken, error', [
    ('rosbag2_bagfile_information:\n' + ''.join('  ' + line + '\n' for line in GOOD.splitlines()),
     'first invalid key: "version"'),
    (GOOD.replace('    offered_qos_profiles:\n',
                  "    offered_qos_profiles: '- {history: keep_last}'\n"
                  '    x:\n'), 'sequence expected'),
    (GOOD.replace('ros_distro: jazzy\n', ''), 'first invalid key: "ros_distro"'),
    (GOOD.replace('message_count: 1\ncompression', 'message_count: -1\ncompression'),
     'unsigned integer expected'),
    (GOOD.replace('durability: volatile', 'durability: volatil'), 'no rmw durability policy'),
    (GOOD.replace('depth: 10, ', ''), 'first invalid key: "depth"'),
])
def test_the_decoder_refuses_what_rosbag2_cannot_read(broken, error):
    assert decode_bag_metadata(GOOD)['topics_with_message_count'][0]['offered_qos_profiles']
    with pytest.raises(Rosbag2Error, match=error):
        decode_bag_metadata(broken)


def test_schema_text_is_rosbag2s_local_message_definition():
    r"""
    Check the schema text against rosbag2's recorder.

    The .msg file as installed (comments, blank lines), then each dependency depth first in
    sorted order, after '\n', 80 '=' and 'MSG: pkg/Type' (a same-package field type qualified
    with its package).
    """
    text = full_definition('diagnostic_msgs/msg/DiagnosticArray')
    parts = text.split('\n' + SEPARATOR)
    with open(msg_file('diagnostic_msgs/msg/DiagnosticArray'), newline='') as f:
        assert parts[0] == f.read()
    assert parts[0].startswith('#')                 # the file's comments are kept
    names = [p.split('\n', 1)[0] for p in parts[1:]]
    assert names == ['MSG: diagnostic_msgs/DiagnosticStatus', 'MSG: diagnostic_msgs/KeyValue',
                     'MSG: std_msgs/Header', 'MSG: builtin_interfaces/Time']
    for name, part in zip(names, parts[1:]):
        pkg, typ = name[5:].split('/')
        with open(msg_file(f'{pkg}/msg/{typ}'), newline='') as f:
            assert part == name + '\n' + f.read()


@pytest.fixture(scope='module')
def scenario_bags(tmp_path_factory):
    """One short adaptive run recorded in-process and one with --processes."""
    out = tmp_path_factory.mktemp('rosbag2')
    bags = {}
    for name, extra in (('in_process', []), ('processes', ['--processes'])):
        bag = out / f'{name}.mcap'
        r = subprocess.run([executable_path('im_bringup', 'scenario'), '--duration', '0.05',
                            '--controller', 'adaptive', '--no-progress', '--record', str(bag)]
                           + extra, capture_output=True, text=True, timeout=300,
                           env=dict(os.environ, PYTHONUNBUFFERED='1'))
        assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-3000:]
        bags[name] = bag
    return bags


@pytest.mark.processes
@pytest.mark.slow
@pytest.mark.parametrize('path', ['in_process', 'processes'])
def test_scenario_bags_decode_with_the_qos_the_publishers_offer(scenario_bags, path):
    md = read_metadata(scenario_bags[path])
    assert md['version'] == 9
    _check_against_channels(md)
    for topic, ch in md['channels'].items():
        assert full_definition(ch['type']) == _schema(scenario_bags[path], topic)
        if topic in (T.SETPOINT, T.OBS_SPEED):  # no publisher in this run (the user's setpoints;
            continue                              # the observer's speed only when sensorless)
        offers = {p['durability'] for p in ch['offered_qos_profiles']}
        assert offers == {'transient_local' if topic in TRANSIENT_LOCAL else 'volatile'}, topic
        assert {p['reliability'] for p in ch['offered_qos_profiles']} == {'reliable'}
    assert TRANSIENT_LOCAL - {T.OBS_SPEED} <= set(md['channels'])


def _schema(path, topic):
    from mcap.reader import make_reader
    with open(path, 'rb') as f:
        s = make_reader(f).get_summary()
    ch = next(c for c in s.channels.values() if c.topic == topic)
    return s.schemas[ch.schema_id].data.decode()


@pytest.mark.processes
def test_both_recording_paths_write_the_same_run_metadata(scenario_bags):
    a = info(scenario_bags['in_process']).metadata
    b = info(scenario_bags['processes']).metadata
    run = {'scenario', 'versions', 'git', 'parameters/plant', 'parameters/controller',
           'parameters/observer', 'parameters/adapter'}
    assert run <= set(a) and run <= set(b)
    for name in ('scenario', 'versions', 'git'):
        assert a[name] == b[name]
    assert a['scenario']['controller'] == 'adaptive'
    for node in ('plant', 'controller', 'observer', 'adapter'):
        pa, pb = a[f'parameters/{node}'], b[f'parameters/{node}']
        assert set(pa) == set(pb)
        # the same values but for what differs between the two graphs by construction
        differ = {k for k in pa if pa[k] != pb[k]}
        assert differ <= {'graph_key_file', 'wait_for'}, {k: (pa[k], pb[k]) for k in differ}
    assert b['recording']['parameters_not_received'] == ''


@pytest.mark.processes
@pytest.mark.parametrize('path', ['in_process', 'processes'])
def test_rosbags_reads_the_scenario_bags(scenario_bags, path):
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore
    n = 0
    with AnyReader([scenario_bags[path]],
                   default_typestore=get_typestore(Stores.ROS2_JAZZY)) as ar:
        for conn, _t, raw in ar.messages():
            ar.deserialize(raw, conn.msgtype)
            n += 1
    assert n == info(scenario_bags[path]).message_count
