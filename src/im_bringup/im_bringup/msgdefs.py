"""Message definitions and type hashes for MCAP schemas and channels, from the ``rosbags``
Jazzy typestore (pinned in requirements.txt).

:func:`full_definition` is the ``ros2msg`` schema text rosbag2 writes: the type's fields, then each
dependency after a line of 80 ``=`` and ``MSG: pkg/Type``. :func:`type_hash` is the type's
``RIHS01_`` hash; for the stack's three types it is identical to the installed
``share/<pkg>/msg/<Type>.json`` (``tests/test_bag.py``). A type the typestore does not know is a
ValueError naming it, never an empty schema or hash.
"""
from __future__ import annotations

import functools
import os


@functools.lru_cache(maxsize=1)
def typestore():
    from rosbags.typesys import Stores, get_typestore
    return get_typestore(Stores.ROS2_JAZZY)


def _known(type_name: str) -> str:
    ts = typestore()
    if type_name not in ts.fielddefs:
        raise ValueError(f'{type_name}: not a message type of the ROS 2 Jazzy typestore '
                         '(rosbags); cannot write its schema')
    return type_name


@functools.lru_cache(maxsize=None)
def full_definition(type_name: str) -> str:
    """``ros2msg`` schema text of ``type_name`` with every dependency."""
    return typestore().generate_msgdef(_known(type_name), ros_version=2)[0]


@functools.lru_cache(maxsize=None)
def type_hash(type_name: str) -> str:
    """``RIHS01_<sha256>`` of ``type_name``."""
    return typestore().hash_rihs01(_known(type_name))


def ros_distro() -> str:
    return os.environ.get('ROS_DISTRO', 'jazzy')
