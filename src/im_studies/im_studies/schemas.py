"""
Generate the JSON Schemas of the run file, the motor file and the efficiency-map file.

    python -m im_studies.schemas [--src src] [--running docs/running.md] [--check]
                                                            (make readme runs it)

It also writes docs/running.md's table of run-file keys from the run file's model (each key's
description and what leaving it out means), between ``<!-- run-keys:begin -->`` and
``<!-- run-keys:end -->``.

Each schema is the typed model's own (pydantic's ``model_json_schema``): the run file's
:class:`im_bringup.run_file.RunFile`, the motor file's :data:`im_common.motor_file.MotorFile`,
the efficiency map's :class:`im_studies.efficiency_map.MapFile`; a run-file key's default is the
run's (:class:`~im_bringup.run_file.Scenario`'s field). They are committed in the packages'
``schema/`` folders and installed to ``share/<package>/schema/``; the shipped files name theirs
on their first line, ``# yaml-language-server: $schema=../../schema/run.schema.json``, so an
editor with the YAML language server completes and checks them (docs/running.md).
``--check`` exits 1, naming the file, when a committed schema is not the generated one
(tests/test_schemas.py checks the same).
"""
from __future__ import annotations

import argparse
from dataclasses import fields, MISSING
import json
import os
import sys
from typing import Dict

from im_bringup.run_file import RENAMED, RunFile, Scenario
from im_common.cli import error as cli_error, parse_args
from im_common.motor_file import MotorFile
from im_recording.bag import write_atomic

from .docs import replace_section
from .efficiency_map import MapFile

#: the JSON Schema dialect pydantic generates
DIALECT = 'https://json-schema.org/draft/2020-12/schema'
#: each schema's file, under the source tree (and ``share/`` once installed)
SCHEMA_FILES = {'run': os.path.join('im_bringup', 'schema', 'run.schema.json'),
                'motor': os.path.join('im_common', 'schema', 'motor.schema.json'),
                # beside the shipped map files (im_bringup's config/runs), generated here
                'efficiency_map': os.path.join('im_bringup', 'schema',
                                               'efficiency_map.schema.json')}
#: the first line of a shipped file of each kind (its schema, relative to its config folder)
HEADER = '# yaml-language-server: $schema=../../schema/{}.schema.json'


def _run_defaults(schema: dict) -> dict:
    """Give each run-file key the run's default (a Scenario field's), not the model's None."""
    defaults = {f.name: f.default for f in fields(Scenario) if f.default is not MISSING}
    renamed = {v: k for k, v in RENAMED.items()}
    for field, default in defaults.items():
        prop = schema['properties'].get(renamed.get(field, field))
        if prop is None:
            continue
        if default is None:
            prop.pop('default', None)       # left out: the task's default (the description)
        else:
            prop['default'] = default
    for name in ('noise', 'controller_options', 'speed_observer_options'):
        schema['properties'][name].pop('default', None)
    return schema


def schemas() -> Dict[str, dict]:
    """Return the three schemas by kind (``run``, ``motor``, ``efficiency_map``)."""
    out = {'run': _run_defaults(RunFile.model_json_schema()),
           'motor': MotorFile.model_json_schema(by_alias=True),
           'efficiency_map': _run_defaults(MapFile.model_json_schema())}
    for kind, schema in out.items():
        out[kind] = {'$schema': DIALECT, **schema}
    return out


def _shown(value) -> str:
    """Return a default as a run file writes it, in backticks."""
    text = {True: 'true', False: 'false'}.get(value, value) if isinstance(value, bool) else value
    return f'`{text}`'


def run_keys_table() -> str:
    """Return docs/running.md's table of run-file keys: each key, left out, its meaning."""
    defaults = {f.name: f.default for f in fields(Scenario) if f.default is not MISSING}
    rows = ['| key | left out | meaning |', '|---|---|---|']
    for key, info in RunFile.model_fields.items():
        field = RENAMED.get(key, key)
        extra = info.json_schema_extra or {}
        default = defaults.get(field)
        shown = extra.get('left_out') or (_shown(default) if default is not None else '—')
        meaning = (info.description or '').replace('|', '\\|')
        rows.append(f'| `{key}` | {shown} | {meaning} |')
    return '\n'.join(rows) + '\n'


def render_running(text: str) -> str:
    """Return docs/running.md with its table of run-file keys generated."""
    return replace_section(text, 'run-keys', run_keys_table())


def schema_text(schema: dict) -> str:
    """Return a schema as its committed file holds it."""
    return json.dumps(schema, indent=1, sort_keys=False) + '\n'


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog='schemas', description=__doc__.split('\n\n')[0])
    ap.add_argument('--src', default='src', help='the source tree (default: src)')
    ap.add_argument('--running', default=os.path.join('docs', 'running.md'),
                    help='the page whose table of run-file keys is generated (default: '
                    'docs/running.md)')
    ap.add_argument('--check', action='store_true',
                    help='write nothing; exit 1 if a committed schema differs')
    args = parse_args(ap, argv)
    stale = []
    for kind, schema in schemas().items():
        path = os.path.join(args.src, SCHEMA_FILES[kind])
        text = schema_text(schema)
        try:
            with open(path, encoding='utf-8') as f:
                same = f.read() == text
        except FileNotFoundError:
            same = False
        if args.check:
            if not same:
                stale.append(path)
            continue
        if not same:
            try:
                os.makedirs(os.path.dirname(path), exist_ok=True)
                write_atomic(path, text)
            except OSError as exc:
                return cli_error('schemas', f'{path}: {exc.strerror or exc}')
            print(f'wrote {path}')
    try:
        with open(args.running, encoding='utf-8') as f:
            page = f.read()
    except OSError as exc:
        return cli_error('schemas', f'{args.running}: {exc.strerror or exc}')
    new = render_running(page)
    if args.check and new != page:
        stale.append(args.running)
    elif new != page:
        write_atomic(args.running, new)
        print(f'wrote {args.running}')
    if stale:
        return cli_error('schemas', f'{", ".join(stale)}: not the generated schema (run '
                         'python -m im_studies.schemas)')
    return 0


if __name__ == '__main__':
    sys.exit(main())
