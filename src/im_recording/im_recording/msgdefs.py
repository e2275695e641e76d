r"""
Message definitions and type hashes for MCAP schemas and channels.

:func:`full_definition` is the ``ros2msg`` schema text byte for byte as rosbag2 Jazzy's recorder
writes it (``rosbag2_cpp::LocalMessageDefinitionSource::get_full_text``): the type's installed
``share/<pkg>/msg/<Type>.msg`` file as it is (comments and blank lines kept), then each dependency
not written yet — depth first, a type's dependencies in sorted order — after ``\n``, a line of 80
``=`` and ``MSG: pkg/Type`` (a same-package field type ``Foo`` is ``pkg/Foo``). The files are found
like ``ament_index``: the first prefix of ``AMENT_PREFIX_PATH``, then the environment's own prefix
(where the pinned ROS wheels install ``share/``), that has the package in its resource index.
:func:`type_hash` is the type's ``RIHS01_`` hash from the ``rosbags`` Jazzy typestore (pinned in
requirements.txt); for the stack's types it is identical to the installed
``share/<pkg>/msg/<Type>.json`` (``tests/test_bag.py``). A type without a ``.msg`` file, or unknown
to the typestore, is a ValueError naming it, never an empty schema or hash.
"""
from __future__ import annotations

import functools
import os
import re
import sys

from rosbags.typesys import get_typestore, Stores


@functools.lru_cache(maxsize=1)
def typestore():
    return get_typestore(Stores.ROS2_JAZZY)


def _known(type_name: str) -> str:
    ts = typestore()
    if type_name not in ts.fielddefs:
        raise ValueError(f'{type_name}: not a message type of the ROS 2 Jazzy typestore '
                         '(rosbags); cannot write its schema')
    return type_name


#: ``pkg/Type`` or ``pkg/msg/Type`` (rosbag2's PACKAGE_TYPENAME_REGEX).
_TYPENAME = re.compile(r'^([a-zA-Z0-9_]+)/(?:msg/|srv/)?([a-zA-Z0-9_]+)$')
#: A field's type at the start of a line of a ``.msg`` file (rosbag2's MSG_FIELD_TYPE_REGEX).
_FIELD_TYPE = re.compile(r'(?:^|\n)\s*([a-zA-Z0-9_/]+)(?:\[[^\]]*\])?\s+', re.ASCII)
_PRIMITIVES = frozenset(('bool', 'byte', 'char', 'float32', 'float64', 'int8', 'uint8', 'int16',
                         'uint16', 'int32', 'uint32', 'int64', 'uint64', 'string'))
SEPARATOR = '=' * 80 + '\n'


def _prefixes():
    seen = []
    for p in os.environ.get('AMENT_PREFIX_PATH', '').split(os.pathsep) + [sys.prefix]:
        if p and p not in seen:
            seen.append(p)
    return seen


@functools.lru_cache(maxsize=None)
def msg_file(type_name: str) -> str:
    """
    Return the path of the installed ``.msg`` file of ``pkg/msg/Type``.

    Path of the installed ``.msg`` file of ``pkg/msg/Type`` (ValueError naming the type and where
    it was looked for).
    """
    m = _TYPENAME.match(type_name)
    if m is None:
        raise ValueError(f'{type_name}: not a message type name (pkg/msg/Type); cannot write '
                         'its schema')
    pkg, name = m.groups()
    for prefix in _prefixes():
        if os.path.exists(os.path.join(prefix, 'share', 'ament_index', 'resource_index',
                                       'packages', pkg)):
            path = os.path.join(prefix, 'share', pkg, 'msg', name + '.msg')
            if os.path.isfile(path):
                return path
            break               # ament_index: the first prefix with the package decides
    raise ValueError(f'{type_name}: no {pkg}/msg/{name}.msg installed under '
                     f'{", ".join(_prefixes())}; cannot write its schema')


@functools.lru_cache(maxsize=None)
def _msg_text(type_name: str) -> str:
    with open(msg_file(type_name), encoding='utf-8', newline='') as f:
        return f.read()


def dependencies(text: str, package: str) -> list:
    """Return the non-primitive field types of a ``.msg`` text as ``pkg/Type``, sorted."""
    out = set()
    for m in _FIELD_TYPE.finditer(text):
        t = m.group(1)
        if t in _PRIMITIVES:
            continue
        out.add(t if '/' in t else f'{package}/{t}')
    return sorted(out)


@functools.lru_cache(maxsize=None)
def full_definition(type_name: str) -> str:
    """``ros2msg`` schema text of ``type_name`` with every dependency, as rosbag2 writes it."""
    seen = set()

    def text_of(name: str, depth: int) -> str:
        if depth <= 0:
            raise ValueError(f'{type_name}: dependencies nested deeper than 50 levels')
        text = _msg_text(name)
        out = [text]
        for dep in dependencies(text, _TYPENAME.match(name).group(1)):
            if dep not in seen:
                seen.add(dep)
                out.append('\n' + SEPARATOR + f'MSG: {dep}\n' + text_of(dep, depth - 1))
        return ''.join(out)
    return text_of(type_name, 50)


@functools.lru_cache(maxsize=None)
def type_hash(type_name: str) -> str:
    """``RIHS01_<sha256>`` of ``type_name``."""
    return typestore().hash_rihs01(_known(type_name))


def ros_distro() -> str:
    return os.environ.get('ROS_DISTRO', 'jazzy')
