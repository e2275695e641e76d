"""Message definitions (``ros2msg`` schema text) and ROS 2 type hashes for MCAP channels.

The schema of a channel is the ``.msg`` text of its type followed by every type it depends on,
each introduced by a line of 80 ``=`` and ``MSG: pkg/Type`` — the layout rosbag2's MCAP storage
writes and Foxglove / PlotJuggler / rosbags parse. The text comes from the installed
``share/<pkg>/msg/<Type>.msg`` files (found through the ament index, or next to the Python
package when the environment is not sourced); if a file is missing, the definition is generated
from the message class's introspection data so that a schema is never empty.

The type hash (``RIHS01_...``) comes from the ``<Type>.json`` type description that Jazzy installs
beside the ``.msg`` file; it is stored as channel metadata ``topic_type_hash``, as rosbag2 does.
"""
from __future__ import annotations

import functools
import importlib
import json
import os
import sys
from pathlib import Path
from typing import Optional

SEPARATOR = '=' * 80
PRIMITIVES = {'bool', 'byte', 'char', 'float32', 'float64', 'int8', 'uint8', 'int16', 'uint16',
              'int32', 'uint32', 'int64', 'uint64', 'string', 'wstring'}


def split_type(type_name: str):
    """'pkg/msg/Type' or 'pkg/Type' -> ('pkg', 'Type')."""
    parts = type_name.split('/')
    if len(parts) == 3 and parts[1] == 'msg':
        return parts[0], parts[2]
    if len(parts) == 2:
        return parts[0], parts[1]
    raise ValueError(f'not a ROS 2 message type name: {type_name!r}')


@functools.lru_cache(maxsize=None)
def share_dir(package: str) -> Optional[Path]:
    """share/<package> of an installed interface package, or None."""
    candidates = []
    try:
        from ament_index_python.packages import get_package_share_directory
        candidates.append(Path(get_package_share_directory(package)))
    except Exception:  # not sourced or not registered: look beside the Python package
        pass
    try:
        mod = importlib.import_module(package)
        p = Path(mod.__file__).resolve()
        # <prefix>/lib/pythonX.Y/site-packages/<package>/__init__.py
        candidates.append(p.parents[4] / 'share' / package if len(p.parents) > 4 else None)
    except Exception:
        pass
    candidates.append(Path(sys.prefix) / 'share' / package)
    for c in candidates:
        if c is not None and (c / 'msg').is_dir():
            return c
    return None


def _msg_file(package: str, name: str, ext: str) -> Optional[Path]:
    d = share_dir(package)
    if d is None:
        return None
    f = d / 'msg' / f'{name}{ext}'
    return f if f.is_file() else None


def _dependencies(text: str, package: str):
    deps = []
    for line in text.splitlines():
        line = line.split('#', 1)[0].strip()
        if not line:
            continue
        tok = line.split()[0]
        if '=' in tok:          # e.g. a constant written without spaces
            continue
        base = tok.split('[', 1)[0].split('<=', 1)[0]
        if base in PRIMITIVES:
            continue
        if base == 'Header':
            dep = 'std_msgs/Header'
        elif '/' in base:
            dep = base
        else:
            dep = f'{package}/{base}'
        if dep not in deps:
            deps.append(dep)
    return sorted(deps)


_INTRO_MAP = {'double': 'float64', 'float': 'float32', 'boolean': 'bool', 'octet': 'byte'}


def _generated_text(type_name: str) -> str:
    """A .msg text from the class introspection (used only when no .msg file is installed)."""
    from im_common.cdr import message_class
    cls = message_class(type_name)
    lines = []
    for field, ftype in cls.get_fields_and_field_types().items():
        suffix = ''
        if ftype.startswith('sequence<'):
            ftype, suffix = ftype[len('sequence<'):-1].split(',')[0], '[]'
        elif '[' in ftype:
            ftype, rest = ftype.split('[', 1)
            suffix = '[' + rest
        ftype = _INTRO_MAP.get(ftype, ftype)
        if '/' in ftype and ftype.count('/') == 2:
            p, _, n = ftype.split('/')
            ftype = f'{p}/{n}'
        lines.append(f'{ftype}{suffix} {field}')
    return '\n'.join(lines) + '\n'


@functools.lru_cache(maxsize=None)
def msg_text(type_name: str) -> str:
    package, name = split_type(type_name)
    f = _msg_file(package, name, '.msg')
    if f is not None:
        return f.read_text(encoding='utf-8')
    return _generated_text(f'{package}/msg/{name}')


@functools.lru_cache(maxsize=None)
def full_definition(type_name: str) -> str:
    """The ``ros2msg`` schema data: root text + every dependency, depth first, each once."""
    seen = set()

    def expand(t: str) -> str:
        package, _ = split_type(t)
        text = msg_text(t)
        out = text
        for dep in _dependencies(text, package):
            if dep in seen:
                continue
            seen.add(dep)
            out += f'\n{SEPARATOR}\nMSG: {dep}\n' + expand(dep)
        return out
    return expand(type_name)


@functools.lru_cache(maxsize=None)
def type_hash(type_name: str) -> str:
    """``RIHS01_<sha256>`` of a type from its installed type description; ValueError naming the
    type and the file when it cannot be found or read (a recording without it would be
    rejected by ``ros2 bag play`` later, far from the cause)."""
    package, name = split_type(type_name)
    f = _msg_file(package, name, '.json')
    if f is None:
        raise ValueError(f'{type_name}: no installed type description ({package}/msg/{name}.json)'
                         ' to take its RIHS01 hash from; is the ROS 2 environment sourced?')
    full = f'{package}/msg/{name}'
    try:
        data = json.loads(f.read_text(encoding='utf-8'))
        for h in data.get('type_hashes', []):
            if h.get('type_name') == full and h.get('hash_string'):
                return str(h['hash_string'])
    except (OSError, ValueError, AttributeError) as exc:
        raise ValueError(f'{type_name}: unreadable type description {f}: {exc}') from None
    raise ValueError(f'{type_name}: {f} has no type hash for {full}')


def ros_distro() -> str:
    return os.environ.get('ROS_DISTRO', 'jazzy')
