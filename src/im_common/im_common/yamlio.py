"""
The one writer and the one reader of ROS parameter YAML (``node: {ros__parameters: {...}}``).

Values are plain Python (numbers, strings, bools, lists of numbers); numpy scalars and arrays are
converted. Floats are written with ``repr`` precision so a file read back gives the same numbers.
A value YAML cannot carry (NaN/inf in a parameter, an object) is rejected naming the parameter.

:func:`load_parameters_file` is how every path reads a parameters file — ``scenario
--params-file``/``--gains``, the launch file, a node executable before ``rclpy.init`` — so a file
that cannot be read, is not YAML or is not laid out as a parameters file gets the same one line
everywhere (:class:`ParametersFileError`). The values themselves are checked by the nodes
(``im_common.lockstep.build_node``), also on every path. :func:`read_yaml_file` reads any other
YAML file (a campaign spec) with the same lines (:class:`YamlFileError`).
"""
from __future__ import annotations

import difflib
import math
from typing import Dict, Iterable, Mapping, Optional

import yaml


def _plain(node: str, name: str, value):
    if hasattr(value, 'tolist'):                     # numpy scalar or array
        value = value.tolist()
    if isinstance(value, (list, tuple)):
        return [_plain(node, name, v) for v in value]
    if isinstance(value, dict):     # a block, nested: ROS 2 reads it as the dotted names
        return {k: _plain(node, f'{name}.{k}', v) for k, v in value.items()}
    if isinstance(value, bool) or isinstance(value, (int, str)):
        return value
    if isinstance(value, float):
        if not math.isfinite(value):
            raise ValueError(f'parameter {node}.{name} = {value!r} is not finite')
        return value
    raise ValueError(f'parameter {node}.{name} has type {type(value).__name__}, '
                     f'not a ROS parameter type')


class _Dumper(yaml.SafeDumper):
    pass


def _list_flow(dumper, data):
    # numbers on one line ([a, b, c]), as the nodes' config files write them
    flow = all(not isinstance(v, (list, dict)) for v in data)
    return dumper.represent_sequence('tag:yaml.org,2002:seq', data, flow_style=flow)


_Dumper.add_representer(list, _list_flow)


def parameters_yaml(nodes: Mapping[str, Mapping[str, object]],
                    header: Optional[str] = None) -> str:
    """YAML text for ``{node: {param: value}}``; ``header`` (comment lines) goes first."""
    doc: Dict[str, dict] = {}
    for node, params in nodes.items():
        doc[node] = {'ros__parameters': {k: _plain(node, k, v) for k, v in params.items()}}
    text = yaml.dump(doc, Dumper=_Dumper, sort_keys=False, default_flow_style=False,
                     allow_unicode=True, width=100)
    if header:
        lines = [ln if ln.startswith('#') else f'# {ln}' for ln in header.rstrip('\n').split('\n')]
        text = '\n'.join(lines) + '\n' + text
    return text


class YamlFileError(ValueError):
    """
    A YAML file that cannot be read or parsed.

    The message is one line naming the file (and the line and column of a syntax error).
    """


class ParametersFileError(YamlFileError):
    """A parameters file that cannot be used; the message is one line naming the file."""


def _loader():
    """
    Return a safe YAML loader that, like rcl's parser, ignores tags.

    (``launch_ros`` writes lists as ``!!python/tuple``.)
    """
    class Loader(yaml.SafeLoader):
        pass

    def untagged(loader, _suffix, node):
        if isinstance(node, yaml.SequenceNode):
            return loader.construct_sequence(node)
        if isinstance(node, yaml.MappingNode):
            return loader.construct_mapping(node)
        return loader.construct_scalar(node)
    Loader.add_multi_constructor('', untagged)
    return Loader


def yaml_problem(exc: Exception) -> str:
    """Return a YAML error in one line: 'not valid YAML (line L, column C): problem'."""
    mark = getattr(exc, 'problem_mark', None)
    where = f' (line {mark.line + 1}, column {mark.column + 1})' if mark else ''
    problem = getattr(exc, 'problem', None) or type(exc).__name__
    return f'not valid YAML{where}: {problem}'


def _read(path: str, what: str, error: type, loader):
    try:
        with open(path, encoding='utf-8') as f:
            doc = yaml.load(f, Loader=loader)
    except OSError as exc:
        raise error(f'cannot read {what} {path}: {exc.strerror}') from None
    except UnicodeDecodeError as exc:
        raise error(f'{what} {path} is not UTF-8 text (byte {exc.start}: '
                    f'{exc.object[exc.start:exc.start + 1]!r})') from None
    except RecursionError:
        raise error(f'{what} {path} is nested too deeply to be read') from None
    except yaml.YAMLError as exc:
        raise error(f'{what} {path} is {yaml_problem(exc)}') from None
    if _contains_itself(doc):
        raise error(f'{what} {path}: an alias refers to a collection it is inside '
                    '(a recursive document, e.g. a: &x [*x])')
    return doc


def _contains_itself(doc) -> bool:
    """Return whether a loaded document holds a collection inside itself (a recursive alias)."""
    state = {}                          # id -> 1 on the current path, 2 done
    stack = [(doc, False)]
    while stack:
        node, leaving = stack.pop()
        if not isinstance(node, (dict, list)):
            continue
        if leaving:
            state[id(node)] = 2
            continue
        seen = state.get(id(node))
        if seen == 1:
            return True
        if seen == 2:
            continue
        state[id(node)] = 1
        stack.append((node, True))
        stack.extend((child, False) for child in (node.values() if isinstance(node, dict)
                                                  else node))
    return False


def read_yaml_file(path: str, what: str = 'YAML file', error=YamlFileError):
    """
    Return the YAML document in ``path`` (safe loading): the stack's one YAML file reader.

    A file that cannot be read or parsed is one ``error(message)`` (default
    :class:`YamlFileError`), the message naming ``what`` (e.g. 'campaign spec'), the file and,
    for a syntax error, its line and column: the lines :func:`load_parameters_file` gives.
    """
    return _read(path, what, error, yaml.SafeLoader)


def node_name(key) -> str:
    """Return the node a parameters-file section is for: ``/ns/controller`` -> ``controller``."""
    return str(key).strip('/').split('/')[-1]


def load_parameters_file(path: str, nodes: Optional[Iterable[str]] = None) -> Dict[str, dict]:
    """
    Return ``{node: {param: value}}`` of a ROS 2 parameters file.

    Section names are as written (e.g. ``/**`` or ``/controller``); with ``nodes``, sections are
    keyed by node name and a section for a node not in ``nodes`` is refused naming the nearest one.
    Every problem is one :class:`ParametersFileError` naming the file.
    """
    doc = _read(path, 'parameters file', ParametersFileError, _loader())
    if doc is None:
        doc = {}
    if not isinstance(doc, dict):
        raise ParametersFileError(f'parameters file {path} is not a ROS 2 parameters file: '
                                  f'expected a mapping of node names to '
                                  f'{{ros__parameters: {{...}}}}, not a {type(doc).__name__}')
    known = None if nodes is None else list(nodes)
    out: Dict[str, dict] = {}
    for key, body in doc.items():
        values = (body or {}).get('ros__parameters', {}) if isinstance(body, dict) else None
        if not isinstance(values, dict):
            raise ParametersFileError(f'parameters file {path} is not a ROS 2 parameters file: '
                                      f"node '{key}' needs a 'ros__parameters' mapping")
        name = str(key)
        if known is not None:
            name = node_name(key)
            if name not in known:
                near = difflib.get_close_matches(name, known, n=1)
                hint = f"; did you mean '{near[0]}'?" if near else ''
                raise ParametersFileError(f"parameters file {path}: unknown node '{key}'{hint} "
                                          f"(expected one of {', '.join(known)})")
        out.setdefault(name, {}).update(flat_parameters(values))
    return out


def flat_parameters(values: dict, prefix: str = '') -> dict:
    """
    Return a ``ros__parameters`` mapping with its nested mappings as dotted names.

    ``{inverter: {enabled: true, V_dc: 540.0}}`` is ``{inverter.enabled: true, inverter.V_dc:
    540.0}``, as ROS 2 reads a parameters file (a parameter's value is never a mapping).
    """
    out = {}
    for key, value in values.items():
        name = f'{prefix}{key}'
        if isinstance(value, dict):
            out.update(flat_parameters(value, name + '.'))
        else:
            out[name] = value
    return out


def read_parameters(text: str) -> Dict[str, dict]:
    """``{node: {param: value}}`` from parameter YAML (the inverse of :func:`parameters_yaml`)."""
    doc = yaml.safe_load(text) or {}
    return {node: flat_parameters((body or {}).get('ros__parameters', {}))
            for node, body in doc.items()}
