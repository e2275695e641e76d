"""
The ``offered_qos_profiles`` channel metadata, as rosbag2 (metadata version 9) writes it.

A YAML list with one profile per publisher, policies by their ``rmw`` names and durations as
``{sec, nsec}`` (infinite: ``RMW_DURATION_INFINITE``); :func:`parse_qos_yaml` refuses anything
rosbag2's reader would throw on.
"""
from __future__ import annotations

from typing import Iterable, Optional

from im_common.conversions import NS_PER_S
from im_common.yamlio import yaml_problem
import yaml

INFINITE = {'sec': 9223372036, 'nsec': 854775807}     # RMW_DURATION_INFINITE
INFINITE_NS = 9223372036854775807


def _time(ns: int) -> dict:
    """
    Return an ``rmw_time_t`` as rosbag2 writes it (``sec``, ``nsec``).

    A negative or infinite duration is ``RMW_DURATION_INFINITE``.
    """
    ns = int(ns)
    if ns < 0 or ns >= INFINITE_NS:
        return dict(INFINITE)
    return {'sec': ns // NS_PER_S, 'nsec': ns % NS_PER_S}


def qos_profile_dict(profile) -> dict:
    """
    Encode one QoS profile as rosbag2 Jazzy does for metadata version 9.

    One QoS profile (an ``rclpy.qos.QoSProfile``, e.g. a ``TopicEndpointInfo.qos_profile``) as
    rosbag2 Jazzy encodes it for metadata version 9: policies as their ``rmw`` names
    (``keep_last``, ``reliable``, ``transient_local``, ``unknown``, ...), durations as ``{sec,
    nsec}``.
    """
    return {'history': profile.history.name.lower(), 'depth': int(profile.depth),
            'reliability': profile.reliability.name.lower(),
            'durability': profile.durability.name.lower(),
            'deadline': _time(profile.deadline.nanoseconds),
            'lifespan': _time(profile.lifespan.nanoseconds),
            'liveliness': profile.liveliness.name.lower(),
            'liveliness_lease_duration': _time(profile.liveliness_lease_duration.nanoseconds),
            'avoid_ros_namespace_conventions': bool(profile.avoid_ros_namespace_conventions)}


def offered_qos_yaml(profiles: Iterable) -> str:
    """
    Return the ``offered_qos_profiles`` channel metadata.

    A YAML *list* with one entry per publisher (``rclpy.qos.QoSProfile`` objects or
    :func:`qos_profile_dict` dicts), as rosbag2's recorder writes the profiles the publishers
    offer (``get_publishers_info_by_topic``).
    """
    items = [p if isinstance(p, dict) else qos_profile_dict(p) for p in profiles]
    return yaml.safe_dump(items, sort_keys=False, default_flow_style=False) if items else ''


def parse_qos_yaml(text: Optional[str], topic: str = '?') -> list:
    """
    Return the list of profiles in an ``offered_qos_profiles`` string ('' is no profile).

    Anything but a YAML list of mappings is a ValueError naming the topic (rosbag2 would
    throw).
    """
    if not text:
        return []
    try:
        items = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise ValueError(f'{topic}: offered_qos_profiles is {yaml_problem(exc)}') from None
    if not isinstance(items, list) or not all(isinstance(i, dict) for i in items):
        raise ValueError(f'{topic}: offered_qos_profiles must be a YAML list of profiles '
                         f'(rosbag2 metadata version 9), not {text[:60]!r}')
    return items


def qos_yaml(reliability: str = 'reliable', durability: str = 'volatile', depth: int = 10,
             history: str = 'keep_last') -> str:
    """One offered profile with the given policies and every duration infinite."""
    return offered_qos_yaml([{
        'history': history, 'depth': int(depth), 'reliability': reliability,
        'durability': durability, 'deadline': dict(INFINITE), 'lifespan': dict(INFINITE),
        'liveliness': 'automatic', 'liveliness_lease_duration': dict(INFINITE),
        'avoid_ros_namespace_conventions': False}])


DEFAULT_QOS = qos_yaml()
