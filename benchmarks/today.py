"""
The opening table of docs/benchmarks.md: today's figures and their targets, from ``make bench``.

``python benchmarks/today.py RUN1/summary.json [RUN2/summary.json ...] --doc docs/benchmarks.md``
writes, between the ``<!-- today:begin -->`` and ``<!-- today:end -->`` markers, one row per
target of :data:`run_all.TARGETS`: each run's value (every ratio measured within its own run),
the target and whether every run met it, under a line naming the machine and the runs' dates and
loads. Without ``--doc`` it prints the table. A summary that is not one of ``make bench`` (quick,
or without a target's key) is one error line naming the file.
"""
from __future__ import annotations

import argparse
import json
import os
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
if HERE not in sys.path:
    sys.path.insert(0, HERE)

from run_all import meets, TARGETS  # noqa: E402 - the benchmarks' folder is not a package

BEGIN, END = '<!-- today:begin -->', '<!-- today:end -->'


def load(path: str) -> dict:
    """Return a full run's summary.json, else raise ValueError naming the file."""
    try:
        with open(path) as f:
            doc = json.load(f)
    except (OSError, ValueError) as exc:
        raise ValueError(f'{path}: cannot read a summary: {exc}') from None
    if not isinstance(doc, dict) or doc.get('quick') is not False:
        raise ValueError(f'{path}: not the summary of a full run (make bench, not --quick)')
    return doc


def _value(key: str, v) -> str:
    if v is None:
        return '—'
    text = f'{v:.0f}' if key.endswith('_hz_busy') else f'{v:.4f}' if v < 0.1 else f'{v:.3f}'
    return text if meets(key, v) else f'**{text}** (not met)'


def table(runs: list) -> str:
    """Return the markdown of the table for the summaries ``runs`` (each a run_all summary)."""
    m = runs[0]['machine']
    loads = ', '.join(f"{r['machine']['load_1min_at_start']:.2f}" for r in runs)
    dates = ', '.join(r['date'] for r in runs)
    out = [f"{len(runs)} `make bench` run{'s' if len(runs) > 1 else ''} ({dates}) on "
           f"{m['cpu_model'] or 'an unnamed CPU'}, {m['cpus']} CPUs, Python {m['python']}; load "
           f'average at each start {loads}. Every ratio is measured within its own run.', '',
           '| figure (summary.json) | ' + ' | '.join(f'run {i + 1}' for i in range(len(runs)))
           + ' | target | met in every run |',
           '| --- | ' + ' | '.join('---:' for _ in runs) + ' | --- | --- |']
    for key, (op, bound, why) in TARGETS.items():
        vals = [r.get(key) for r in runs]
        ok = all(v is not None and meets(key, v) for v in vals)
        out.append(f'| `{key}` | ' + ' | '.join(_value(key, v) for v in vals)
                   + f" | {'≥' if op == '>=' else '≤'} {bound:g} ({why}) | "
                   + ('yes' if ok else '**no**') + ' |')
    return '\n'.join(out) + '\n'


def write(doc: str, text: str) -> None:
    """Put ``text`` between the markers of ``doc`` (ValueError naming it if they are missing)."""
    with open(doc) as f:
        body = f.read()
    if BEGIN not in body or END not in body:
        raise ValueError(f'{doc}: no {BEGIN} ... {END} markers')
    head, rest = body.split(BEGIN, 1)
    tail = rest.split(END, 1)[1]
    with open(doc, 'w') as f:
        f.write(f'{head}{BEGIN}\n{text}{END}{tail}')


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('summaries', nargs='+', metavar='SUMMARY_JSON')
    ap.add_argument('--doc', help='write the table into this file, between its markers')
    args = ap.parse_args(argv)
    try:
        text = table([load(p) for p in args.summaries])
        if args.doc:
            write(args.doc, text)
        else:
            print(text, end='')
    except ValueError as exc:
        print(f'today: error: {exc}', file=sys.stderr)
        return 2
    return 0


if __name__ == '__main__':
    sys.exit(main())
