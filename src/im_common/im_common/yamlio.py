"""The one writer of ROS parameter YAML (``node: {ros__parameters: {...}}``) in the project.

Values are plain Python (numbers, strings, bools, lists of numbers); numpy scalars and arrays are
converted. Floats are written with ``repr`` precision so a file read back gives the same numbers.
A value YAML cannot carry (NaN/inf in a parameter, an object) is rejected naming the parameter.
"""
from __future__ import annotations

import math
from typing import Dict, Mapping, Optional

import yaml


def _plain(node: str, name: str, value):
    if hasattr(value, 'tolist'):                     # numpy scalar or array
        value = value.tolist()
    if isinstance(value, (list, tuple)):
        return [_plain(node, name, v) for v in value]
    if isinstance(value, bool) or isinstance(value, (int, str)):
        return value
    if isinstance(value, float):
        if not math.isfinite(value):
            raise ValueError(f'parameter {node}.{name} = {value!r} is not finite')
        return value
    raise ValueError(f'parameter {node}.{name} has type {type(value).__name__}, not a ROS parameter type')


class _Dumper(yaml.SafeDumper):
    pass


def _list_flow(dumper, data):
    # numbers on one line ([a, b, c]), as the nodes' config files write them
    flow = all(not isinstance(v, (list, dict)) for v in data)
    return dumper.represent_sequence('tag:yaml.org,2002:seq', data, flow_style=flow)


_Dumper.add_representer(list, _list_flow)


def parameters_yaml(nodes: Mapping[str, Mapping[str, object]], header: Optional[str] = None) -> str:
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


def read_parameters(text: str) -> Dict[str, dict]:
    """``{node: {param: value}}`` from parameter YAML (the inverse of :func:`parameters_yaml`)."""
    doc = yaml.safe_load(text) or {}
    return {node: dict((body or {}).get('ros__parameters', {})) for node, body in doc.items()}
