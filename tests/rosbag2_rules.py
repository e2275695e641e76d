"""
A strict decoder of an MCAP file's rosbag2 metadata, applying rosbag2 Jazzy's own rules.

``ros2 bag info`` and ``ros2 bag play`` open an MCAP file through rosbag2_storage_mcap's
``MCAPStorage::read_metadata()``: it loads the ``serialized_metadata`` of the ``rosbag2``
Metadata record with yaml-cpp and hands the *bare* node to ``YAML::convert<BagMetadata>::decode``
(rosbag2_storage/yaml.hpp), then decodes each channel's ``offered_qos_profiles`` with
``to_rclcpp_qos_vector`` (rosbag2_storage/qos.cpp). Nothing there catches: a missing key
(yaml-cpp ``InvalidNode``) or a value of the wrong kind (``BadConversion``) aborts the command.
This module restates those rules (written from reading the Jazzy branch, not copied):

* ``version`` (int) first; then ``storage_identifier``, ``duration.nanoseconds``,
  ``starting_time.nanoseconds_since_epoch``, ``message_count`` (unsigned),
  ``topics_with_message_count`` (a sequence), ``relative_file_paths`` (a sequence of strings);
  from version 3 ``compression_format``/``compression_mode``; from 5 ``files`` (path,
  starting_time, duration, message_count); from 6 ``custom_data`` (a mapping of strings); from 8
  ``ros_distro``.
* each topic: ``topic_metadata`` (``name``, ``type``, ``serialization_format``; from version 9
  ``offered_qos_profiles`` as a YAML *sequence* of profiles, from 4 to 8 a string holding one;
  from 7 ``type_description_hash``) and ``message_count``.
* a profile: ``history`` as an int 0-3 means the version-8 layout (policies as ints), otherwise
  policy names; ``depth`` only with ``keep_last``; ``deadline``, ``lifespan`` and
  ``liveliness_lease_duration`` as ``{sec, nsec}`` (unsigned); ``avoid_ros_namespace_conventions``
  a bool.
* a channel's ``offered_qos_profiles``: empty, or YAML holding a sequence of profiles; every
  channel has a schema; the file has a Statistics record.

Stricter than rosbag2 where rosbag2 is silently lenient (reported as errors here): a policy name
rmw does not know (rosbag2 reads UNKNOWN), a missing ``serialized_metadata`` (rosbag2 falls back to
version 8). Scalars are read untyped (PyYAML's BaseLoader), as yaml-cpp does, then converted by the
target type's rules.
"""
from __future__ import annotations

import re

import yaml

HISTORY = ('system_default', 'keep_last', 'keep_all', 'unknown')
RELIABILITY = ('system_default', 'reliable', 'best_effort', 'unknown', 'best_available')
DURABILITY = ('system_default', 'transient_local', 'volatile', 'unknown', 'best_available')
LIVELINESS = ('system_default', 'automatic', 'manual_by_topic', 'unknown', 'best_available')
_INT = re.compile(r'^[-+]?[0-9]+$')
_UINT = re.compile(r'^\+?[0-9]+$')
_TRUE = ('y', 'Y', 'yes', 'Yes', 'YES', 'true', 'True', 'TRUE', 'on', 'On', 'ON')
_FALSE = ('n', 'N', 'no', 'No', 'NO', 'false', 'False', 'FALSE', 'off', 'Off', 'OFF')
_NULL = ('~', 'null', 'Null', 'NULL')


class Rosbag2Error(Exception):
    """What rosbag2 would throw (or read wrongly), with the path of the offending node."""


def _get(node, key: str, where: str):
    if not isinstance(node, dict):
        raise Rosbag2Error(f'{where}: not a mapping, cannot read key "{key}"')
    if key not in node:
        raise Rosbag2Error(f'{where}: invalid node; first invalid key: "{key}"')
    return node[key]


def _str(node, key, where):
    v = _get(node, key, where)
    if not isinstance(v, str) or v in _NULL:
        raise Rosbag2Error(f'{where}.{key}: bad conversion (a string scalar expected, got {v!r})')
    return v


def _int(node, key, where, unsigned=False):
    v = _get(node, key, where)
    if not isinstance(v, str) or not (_UINT if unsigned else _INT).match(v):
        kind = 'an unsigned integer' if unsigned else 'an integer'
        raise Rosbag2Error(f'{where}.{key}: bad conversion ({kind} expected, got {v!r})')
    return int(v)


def _bool(node, key, where):
    v = _get(node, key, where)
    if v in _TRUE:
        return True
    if v in _FALSE:
        return False
    raise Rosbag2Error(f'{where}.{key}: bad conversion (a bool expected, got {v!r})')


def _seq(v, where):
    if not isinstance(v, list):
        raise Rosbag2Error(f'{where}: bad conversion (a sequence expected, got '
                           f'{type(v).__name__} {str(v)[:60]!r})')
    return v


def _time(node, key, where):
    t = _get(node, key, where)
    return (_int(t, 'sec', f'{where}.{key}', True), _int(t, 'nsec', f'{where}.{key}', True))


def _policy(node, key, where, names, v8):
    if v8:
        return _int(node, key, where)
    v = _str(node, key, where)
    if v not in names:
        raise Rosbag2Error(f'{where}.{key}: {v!r} is no rmw {key} policy (rosbag2 would read '
                           'UNKNOWN)')
    return v


def decode_qos(node, where: str) -> dict:
    """
    One profile, as ``convert<rclcpp::QoS>::decode`` reads it.

    ``format`` 8 or 9 says which layout it was detected as.
    """
    h = _get(node, 'history', where)
    v8 = isinstance(h, str) and bool(_INT.match(h)) and 0 <= int(h) <= 3
    out = {'format': 8 if v8 else 9,
           'history': int(h) if v8 else _policy(node, 'history', where, HISTORY, False),
           'reliability': _policy(node, 'reliability', where, RELIABILITY, v8),
           'durability': _policy(node, 'durability', where, DURABILITY, v8),
           'liveliness': _policy(node, 'liveliness', where, LIVELINESS, v8)}
    if out['history'] in ('keep_last', 1):
        out['depth'] = _int(node, 'depth', where)
    for k in ('deadline', 'lifespan', 'liveliness_lease_duration'):
        out[k] = _time(node, k, where)
    out['avoid_ros_namespace_conventions'] = _bool(node, 'avoid_ros_namespace_conventions', where)
    return out


def decode_qos_list(node, where: str) -> list:
    return [decode_qos(p, f'{where}[{i}]') for i, p in enumerate(_seq(node, where))]


def decode_qos_string(text: str, where: str) -> list:
    """``to_rclcpp_qos_vector``: '' is no profile, otherwise YAML holding a sequence."""
    if text == '':
        return []
    return decode_qos_list(yaml.load(text, Loader=yaml.BaseLoader), where)


def decode_bag_metadata(text: str) -> dict:
    """
    Decode a metadata record as rosbag2 does.

    ``YAML::convert<BagMetadata>::decode`` on ``YAML::Load(text)``: the decoded fields, or
    :class:`Rosbag2Error` where rosbag2 throws.
    """
    try:
        node = yaml.load(text, Loader=yaml.BaseLoader)
    except yaml.YAMLError as exc:
        raise Rosbag2Error(f'serialized_metadata is not YAML: {exc}') from None
    w = 'serialized_metadata'
    md = {'version': _int(node, 'version', w)}
    version = md['version']
    md['storage_identifier'] = _str(node, 'storage_identifier', w)
    md['duration'] = _int(_get(node, 'duration', w), 'nanoseconds', f'{w}.duration', True)
    md['starting_time'] = _int(_get(node, 'starting_time', w), 'nanoseconds_since_epoch',
                               f'{w}.starting_time', True)
    md['message_count'] = _int(node, 'message_count', w, True)
    topics = []
    for i, t in enumerate(_seq(_get(node, 'topics_with_message_count', w),
                               f'{w}.topics_with_message_count')):
        tw = f'{w}.topics_with_message_count[{i}]'
        tm = _get(t, 'topic_metadata', tw)
        mw = f'{tw}.topic_metadata'
        topic = {'name': _str(tm, 'name', mw), 'type': _str(tm, 'type', mw),
                 'serialization_format': _str(tm, 'serialization_format', mw)}
        if version >= 9:
            topic['offered_qos_profiles'] = decode_qos_list(
                _get(tm, 'offered_qos_profiles', mw), f'{mw}.offered_qos_profiles')
        elif version >= 4:
            topic['offered_qos_profiles'] = decode_qos_string(
                _str(tm, 'offered_qos_profiles', mw), f'{mw}.offered_qos_profiles')
        if version >= 7:
            topic['type_description_hash'] = _str(tm, 'type_description_hash', mw)
        topic['message_count'] = _int(t, 'message_count', tw, True)
        topics.append(topic)
    md['topics_with_message_count'] = topics
    paths = _seq(_get(node, 'relative_file_paths', w), f'{w}.relative_file_paths')
    md['relative_file_paths'] = [_str({'p': p}, 'p', f'{w}.relative_file_paths') for p in paths]
    if version >= 3:
        md['compression_format'] = _str(node, 'compression_format', w)
        md['compression_mode'] = _str(node, 'compression_mode', w)
    if version >= 5:
        files = []
        for i, f in enumerate(_seq(_get(node, 'files', w), f'{w}.files')):
            fw = f'{w}.files[{i}]'
            files.append({'path': _str(f, 'path', fw),
                          'starting_time': _int(_get(f, 'starting_time', fw),
                                                'nanoseconds_since_epoch', fw, True),
                          'duration': _int(_get(f, 'duration', fw), 'nanoseconds', fw, True),
                          'message_count': _int(f, 'message_count', fw, True)})
        md['files'] = files
    if version >= 6:
        cd = _get(node, 'custom_data', w)
        if not isinstance(cd, dict) or not all(isinstance(v, str) for v in cd.values()):
            raise Rosbag2Error(f'{w}.custom_data: bad conversion (a mapping of strings expected)')
        md['custom_data'] = dict(cd)
    if version >= 8:
        md['ros_distro'] = _str(node, 'ros_distro', w)
    return md


def read_metadata(path) -> dict:
    """
    Read the metadata of the file at ``path`` as rosbag2's ``MCAPStorage`` reads it.

    The decoded ``rosbag2`` record, plus per channel its topic, schema name and decoded offered
    QoS.
    """
    from mcap.reader import make_reader
    with open(path, 'rb') as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        records = [m for m in reader.iter_metadata() if m.name == 'rosbag2']
    if summary is None or summary.statistics is None:
        raise Rosbag2Error(f'{path}: no Statistics record')
    if len(records) != 1:
        raise Rosbag2Error(f'{path}: {len(records)} rosbag2 metadata records, expected 1')
    if 'serialized_metadata' not in records[0].metadata:
        raise Rosbag2Error(f"{path}: the rosbag2 record has no 'serialized_metadata'")
    md = decode_bag_metadata(records[0].metadata['serialized_metadata'])
    channels = {}
    for cid, ch in summary.channels.items():
        schema = summary.schemas.get(ch.schema_id)
        if schema is None:
            raise Rosbag2Error(f'Could not find schema for topic {ch.topic}')
        channels[ch.topic] = {
            'type': schema.name, 'encoding': ch.message_encoding,
            'offered_qos_profiles': decode_qos_string(ch.metadata.get('offered_qos_profiles', ''),
                                                      f'channel {ch.topic}'),
            'topic_type_hash': ch.metadata.get('topic_type_hash', ''),
            'message_count': summary.statistics.channel_message_counts.get(cid, 0)}
    md['channels'] = channels
    return md
