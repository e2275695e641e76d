"""
The campaign's journal (docs/campaign.md): finished rows, kept so that a campaign resumes.

Every finished row is appended to ``DIR/rows.jsonl`` and synced before the next is counted, so a
killed campaign resumes with the same command and runs nothing twice; ``DIR/campaign.json`` holds
the spec's hash, so another spec is refused.
"""
from __future__ import annotations

import contextlib
from importlib import metadata
import json
import os
from pathlib import Path
import sys
from typing import Dict

from im_recording.bag import write_atomic

from .campaign_spec import spec_hash

JOURNAL = 'rows.jsonl'
STATE = 'campaign.json'


def versions() -> dict:
    out = {'python': sys.version.split()[0]}
    for dist in ('im_bringup', 'im_recording', 'im_studies', 'im_common', 'im_controller',
                 'im_observer', 'numpy', 'scipy',
                 'dask', 'distributed', 'pyarrow'):
        with contextlib.suppress(metadata.PackageNotFoundError):
            out[dist] = metadata.version(dist)
    return out


def read_journal(path: Path) -> Dict[int, dict]:
    """
    Return the rows already finished: {index: row}.

    A torn last line (the process was killed while
    writing it) is cut off, so that run is run again; nothing else is.
    """
    rows: Dict[int, dict] = {}
    if not path.exists():
        return rows
    good = 0
    with open(path, 'rb') as f:
        data = f.read()
    for line in data.splitlines(keepends=True):
        if not line.endswith(b'\n'):
            break
        try:
            row = json.loads(line)
        except ValueError:
            break
        rows[int(row['index'])] = row
        good += len(line)
    if good != len(data):
        with open(path, 'r+b') as f:
            f.truncate(good)
    return rows


class Journal:

    def __init__(self, path: Path):
        self.f = open(path, 'a', encoding='utf-8')

    def append(self, row: dict) -> None:
        self.f.write(json.dumps(row, allow_nan=True) + '\n')
        self.f.flush()
        os.fsync(self.f.fileno())

    def close(self) -> None:
        self.f.close()


def prepare_out(out: Path, spec: dict, force: bool) -> Dict[int, dict]:
    """Create or resume ``out``: rows already done (same spec), or refuse another campaign."""
    state = out / STATE
    if state.exists():
        try:
            old = json.loads(state.read_text())
        except ValueError:
            old = {}
        if old.get('spec_hash') != spec_hash(spec):
            if not force:
                raise FileExistsError(
                    f'{out}: holds another campaign ({old.get("name", "?")}, spec '
                    f'{old.get("spec_hash", "?")}); refusing to mix or overwrite it (choose '
                    'another --out, or pass --force to start over)')
            for name in (STATE, JOURNAL, 'runs.parquet', 'summary.json', 'report.md'):
                with contextlib.suppress(FileNotFoundError):
                    (out / name).unlink()
    elif (out / JOURNAL).exists() and not force:
        raise FileExistsError(f'{out}/{JOURNAL}: rows without a campaign state; refusing to '
                              'overwrite (pass --force)')
    out.mkdir(parents=True, exist_ok=True)
    if not state.exists():
        write_atomic(state, json.dumps({'name': spec['name'], 'spec_hash': spec_hash(spec),
                                        'spec': spec}, indent=2))
        with contextlib.suppress(FileNotFoundError):
            (out / JOURNAL).unlink()
    return read_journal(out / JOURNAL)
