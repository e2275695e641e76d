"""
The SROS2 access-control policy of the drive graph: ``config/sros2/policy.xml``.

One enclave per node (``/im_drive/<node>``) granting exactly the topics the node publishes and
subscribes and the services it answers (its parameter services), read off the nodes themselves
(built in-process, not spun), plus ``/im_drive/user`` for a person at the console: publish a
setpoint (``ros2 topic pub /im/setpoint``), read the run protocol, set live parameters
(``ros2 param set``). The commissioning tool (``ros2 run im_bringup commission``,
docs/commissioning.md §7) has its own enclave ``/im_drive/commission``: it publishes the command
topic in the controller's place (``STANDS_IN``). ``tests/test_security.py`` checks that the
shipped file is what this module generates and that it agrees with the topic table
(:mod:`im_common.topics`).

    python -m im_bringup.sros2_policy [--write]   # print (or, from the repository's root,
                                                  # rewrite) the shipped policy

Using it needs a ROS 2 install whose middleware has DDS security (``docs/security.md``); the
Fast DDS of the PyPI wheels has none.
"""
from __future__ import annotations

import argparse
import os
import sys
import tempfile
from typing import Dict, List, Tuple
import xml.etree.ElementTree as ET
from xml.sax.saxutils import escape

from im_adapt.adapter_node import AdapterNode
from im_adapt.commissioning import Commissioning
from im_bringup.commission import make_node as commission_node
from im_common import topics as T
from im_common.host import private_domain
from im_controller.controller_node import ControllerNode
from im_observer.observer_node import ObserverNode
from im_plant.plant_node import PlantNode
from im_recording.bag import BagWriter
from im_recording.record_node import RecorderNode
import rclpy
from rclpy.context import Context

ENCLAVE_ROOT = '/im_drive'
POLICY_VERSION = '0.2.0'
NODES = ('plant', 'controller', 'observer', 'adapter', 'recorder', 'commission')
#: {node: the node whose topics it publishes in that node's place}
#: (the topic table names the other)
STANDS_IN = {'commission': 'controller'}
#: The shipped file, relative to the repository's root
#: (installed to share/im_bringup/config/sros2).
SHIPPED = os.path.join('src', 'im_bringup', 'config', 'sros2', 'policy.xml')


def node_endpoints() -> Dict[str, Dict[str, List[str]]]:
    """{node: {'publish': [...], 'subscribe': [...], 'reply': [...]}} read off the nodes."""
    ctx = Context()
    rclpy.init(context=ctx, domain_id=private_domain())
    out = {}
    tmp = tempfile.mkdtemp(prefix='im_policy_')
    writer = BagWriter(os.path.join(tmp, 'x.mcap'))
    try:
        key = bytes(32)
        P = rclpy.parameter.Parameter
        sim = P('use_sim_time', value=True)     # as written by config.to_yaml: they read /clock
        built = {'plant': PlantNode(context=ctx, graph_key=key),
                 'controller': ControllerNode(context=ctx, graph_key=key, parameter_overrides=[
                     P('use_adapter', value=True), sim]),
                 'observer': ObserverNode(context=ctx, graph_key=key, parameter_overrides=[
                     P('use_adapter', value=True), sim]),
                 'adapter': AdapterNode(context=ctx, graph_key=key, parameter_overrides=[sim]),
                 'recorder': RecorderNode(writer, context=ctx, graph_key=key),
                 'commission': commission_node(Commissioning(1e-4, 8.0, 300.0, pole_pairs=2,
                                                             test_speed=100.0),
                                               1e-4, context=ctx, graph_key=key)}
        # the same nodes speed-sensorless (docs/sensorless.md): the union of both is granted
        sl = [P('sensorless', value=True), P('use_adapter', value=True), sim]
        also = {'controller': ControllerNode(context=ctx, graph_key=key, parameter_overrides=[
                    P('mode', value='speed')] + sl),
                'observer': ObserverNode(context=ctx, graph_key=key, parameter_overrides=sl),
                'adapter': AdapterNode(context=ctx, graph_key=key, parameter_overrides=sl[::2])}
        for name, node in built.items():
            nodes = [node] + ([also[name]] if name in also else [])
            out[name] = {      # every node also logs to /rosout (rcl's own publisher)
                'publish': sorted({p.topic_name for n in nodes for p in n.publishers}
                                  | {'/rosout'}),
                'subscribe': sorted({s.topic_name for n in nodes for s in n.subscriptions}),
                'reply': sorted({'/' + s.srv_name.lstrip('/') for n in nodes for s in n.services}),
            }
            for n in nodes:
                n.destroy_node()
    finally:
        writer.discard()
        os.rmdir(tmp)
        rclpy.shutdown(context=ctx)
    return out


def user_endpoints(nodes: Dict[str, Dict[str, List[str]]]) -> Dict[str, List[str]]:
    """Return the console user's endpoints: setpoint, run protocol, parameters of every node."""
    services = sorted({s for e in nodes.values() for s in e['reply'] if 'parameter' in s})
    return {'publish': [T.SETPOINT, '/rosout', '/parameter_events'],
            'subscribe': [T.STATUS, '/rosout', '/parameter_events'],
            'request': services}


def _rel(name: str) -> str:
    return name[1:] if name.startswith('/') else name


def _block(kind: str, rule: str, names: List[str], tag: str, indent: str) -> List[str]:
    if not names:
        return []
    lines = [f'{indent}<{kind} {rule}="ALLOW">']
    lines += [f'{indent}  <{tag}>{escape(_rel(n))}</{tag}>' for n in names]
    lines.append(f'{indent}</{kind}>')
    return lines


def policy_xml(endpoints: Dict[str, Dict[str, List[str]]] = None) -> str:
    endpoints = endpoints or node_endpoints()
    lines = ['<?xml version="1.0" encoding="UTF-8"?>',
             '<!-- Generated from the nodes themselves by im_bringup/sros2_policy.py (make '
             'policy);',
             '     tests/test_security.py keeps it equal to the code. See docs/security.md. -->',
             f'<policy version="{POLICY_VERSION}">', '  <enclaves>']
    entries: List[Tuple[str, Dict[str, List[str]]]] = [(n, endpoints[n]) for n in NODES]
    entries.append(('user', user_endpoints(endpoints)))
    for name, e in entries:
        ind = '          '
        lines += [f'    <enclave path="{ENCLAVE_ROOT}/{name}">', '      <profiles>',
                  f'        <profile ns="/" node="{name if name != "user" else "*"}">']
        lines += _block('topics', 'publish', e.get('publish', []), 'topic', ind)
        lines += _block('topics', 'subscribe', e.get('subscribe', []), 'topic', ind)
        lines += _block('services', 'reply', e.get('reply', []), 'service', ind)
        lines += _block('services', 'request', e.get('request', []), 'service', ind)
        lines += ['        </profile>', '      </profiles>', '    </enclave>']
    lines += ['  </enclaves>', '</policy>', '']
    return '\n'.join(lines)


def parse_policy(text: str) -> Dict[str, Dict[str, List[str]]]:
    """{enclave name: {'publish'|'subscribe'|'reply'|'request': [absolute names]}}."""
    root = ET.fromstring(text)
    out = {}
    for enc in root.iter('enclave'):
        name = enc.get('path').rsplit('/', 1)[-1]
        rules: Dict[str, List[str]] = {}
        for group in enc.iter():
            for rule in ('publish', 'subscribe', 'reply', 'request'):
                if group.get(rule) == 'ALLOW':
                    rules.setdefault(rule, []).extend(
                        '/' + c.text for c in group)
        out[name] = rules
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog='sros2_policy', description=__doc__.strip().splitlines()[0])
    ap.add_argument('--write', action='store_true', help=f'rewrite {SHIPPED}')
    a = ap.parse_args(argv)
    text = policy_xml()
    if a.write:
        os.makedirs(os.path.dirname(SHIPPED), exist_ok=True)
        with open(SHIPPED, 'w') as f:
            f.write(text)
        print(f'wrote {SHIPPED}', file=sys.stderr)
    else:
        sys.stdout.write(text)
    return 0


if __name__ == '__main__':
    sys.exit(main())
