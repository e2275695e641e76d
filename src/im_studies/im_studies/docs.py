"""
Regenerate the topic and parameter tables of docs/parameters.md from the code.

    python -m im_studies.docs [docs/parameters.md]      (make readme runs it)

The tables sit between ``<!-- topics:begin -->`` / ``<!-- topics:end -->`` and
``<!-- parameters:begin -->`` / ``<!-- parameters:end -->``; ``tests/test_readme.py`` fails when
the page no longer matches what the nodes declare.
"""
from __future__ import annotations

import os
import re
import sys

from im_adapt.adapter_node import AdapterNode
from im_common.cli import error as cli_error
from im_common.host import private_domain
from im_common.lockstep import parameter_table
from im_common.topics import markdown_table
from im_controller.baselines.drive import GAINS
from im_controller.controller_node import ControllerNode
from im_observer.observer_node import ObserverNode
from im_plant.plant_node import PlantNode
import rclpy
from rclpy.context import Context
from rclpy.parameter import Parameter

#: the page holding the generated tables
DEFAULT_PAGE = os.path.join('docs', 'parameters.md')


def parameter_tables() -> str:
    parts = []
    for title, factory in (('plant (`ros2 run im_plant plant`)', PlantNode),
                           ('controller (`ros2 run im_controller controller`)', ControllerNode),
                           ('observer (`ros2 run im_observer observer`)', ObserverNode),
                           ('adapter (`ros2 run im_adapt adapter`)', AdapterNode)):
        ctx = Context()
        rclpy.init(context=ctx, domain_id=private_domain())
        try:
            node = factory(context=ctx, graph_key=bytes(32))
            parts.append(f'### {title}\n\n{parameter_table(node)}\n')
            node.destroy_node()
            if factory is ControllerNode:
                parts += _baseline_tables(ctx)
        finally:
            rclpy.shutdown(context=ctx)
    return '\n'.join(parts)


def _baseline_tables(ctx) -> list:
    """Return the controller's ``baseline.*`` rows of each baseline law (declared with it)."""
    parts = []
    for law in GAINS:
        task = [Parameter('mode', value='speed')] if law == 'vhz' else []
        node = ControllerNode(context=ctx, graph_key=bytes(32), parameter_overrides=[
            Parameter('law', value=law)] + task)
        lines = parameter_table(node).splitlines()
        node.destroy_node()
        rows = [ln for ln in lines if ln.startswith('| `baseline.')]
        parts.append(f"#### controller `law: {law}`: its gains (the run file's `baseline:` "
                     f'block)\n\n' + '\n'.join(lines[:2] + rows) + '\n')
    return parts


def render(text: str) -> str:
    text = replace_section(text, 'topics', markdown_table())
    return replace_section(text, 'parameters', parameter_tables())


def replace_section(text: str, name: str, body: str) -> str:
    pattern = re.compile(rf'(<!-- {name}:begin -->\n)(.*?)(<!-- {name}:end -->)', re.S)
    if not pattern.search(text):
        raise ValueError(f'no <!-- {name}:begin --> ... <!-- {name}:end --> section')
    return pattern.sub(lambda m: m.group(1) + body.rstrip('\n') + '\n' + m.group(3), text)


def main(argv=None) -> int:
    path = (argv or sys.argv[1:] or [os.path.join(os.getcwd(), DEFAULT_PAGE)])[0]
    try:
        with open(path) as f:
            text = f.read()
        new = render(text)
    except (OSError, ValueError) as exc:
        return cli_error('docs', f'{path}: {getattr(exc, "strerror", None) or exc}')
    with open(path, 'w') as f:
        f.write(new)
    print(f'{path}: tables regenerated')
    return 0


if __name__ == '__main__':
    sys.exit(main())
