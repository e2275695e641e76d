"""
The ament linters' rules over src/, tests/, benchmarks/ and tools/, with zero findings.

ROS 2 Jazzy's ``ament_flake8`` and ``ament_pep257`` are reproduced rather than called (their
ament wrappers are not in the pinned environment; the tools underneath are, see requirements.txt):

- flake8 with ament's configuration (``.flake8`` at the repository root is a copy of
  ament_lint's ``ament_flake8/configuration/ament_flake8.ini``: 99 columns, google import order,
  ament's ignore list) and the plugins ament_flake8 runs with (import-order, quotes, docstrings,
  builtins, comprehensions) plus blind-except, class-newline and deprecated, which ament's
  package.xml lists as optional;
- pydocstyle as ``ament_pep257`` calls it: every check except ament's ignore list (so D213, a
  multi-line docstring's summary on the line after the opening quotes, is required).

Every finding is printed as ``path:line code text``.
"""
import fnmatch
from pathlib import Path
import subprocess
import sys
import warnings

import pydocstyle
from pydocstyle.violations import ErrorRegistry
import pytest

ROOT = Path(__file__).resolve().parents[1]
TREES = ('src', 'tests', 'benchmarks', 'tools')
#: ament_pep257's default ``--ignore`` (ament_pep257/main.py, ``_ament_ignore``)
AMENT_PEP257_IGNORE = {'D100', 'D101', 'D102', 'D103', 'D104', 'D105', 'D106', 'D107',
                       'D203', 'D212', 'D404'}

#: Files whose findings are printed but do not fail the tests: empty since issue 24 (every file
#: is lint-clean; ``python tools/lint_fix.py FILE...`` does the mechanical part of a fix).
PENDING: set = set()


def _python_files():
    out = []
    for tree in TREES:
        for f in sorted((ROOT / tree).rglob('*.py')):
            rel = f.relative_to(ROOT)
            # ament's linters skip directories whose names start with '.' or '_'
            if not any(part[0] in '._' for part in rel.parts[:-1]):
                out.append(rel.as_posix())
    return out


def _pending(path: str) -> bool:
    return any(fnmatch.fnmatch(path, pattern) for pattern in PENDING)


def _split(findings):
    """Split the findings into (failing, pending); print the pending ones."""
    failing = [f for f in findings if not _pending(f.split(':', 1)[0])]
    pending = [f for f in findings if _pending(f.split(':', 1)[0])]
    if pending:
        print(f'{len(pending)} findings in files still PENDING (not failed):')
        print('\n'.join(pending))
        warnings.warn(f'{len(pending)} lint findings in the PENDING files (printed with -rP)')
    return failing, pending


def _flake8():
    proc = subprocess.run(
        [sys.executable, '-m', 'flake8', '--config', str(ROOT / '.flake8'), '--no-show-source',
         '--format=%(path)s:%(row)d %(code)s %(text)s', *_python_files()],
        cwd=ROOT, capture_output=True, text=True)
    assert proc.returncode in (0, 1), f'flake8 did not run:\n{proc.stderr}'
    # with `statistics = true` flake8 appends "<count> <code> <text>" lines; keep the findings
    return [line for line in proc.stdout.splitlines() if ':' in line.split(' ', 1)[0]]


def _pep257():
    codes = set(ErrorRegistry.get_error_codes()) - AMENT_PEP257_IGNORE
    out = []
    for err in pydocstyle.check([str(ROOT / f) for f in _python_files()], select=sorted(codes)):
        if isinstance(err, pydocstyle.Error):
            path = Path(err.filename).relative_to(ROOT).as_posix()
            out.append(f'{path}:{err.line} {err.code} {err.short_desc} ({err.definition})')
        else:                                   # a file pydocstyle could not parse
            out.append(f'?:0 E902 {err}')
    return out


@pytest.mark.processes
def test_the_linters_see_the_tree():
    # guards the lint tests against passing on an empty file list or a missing plugin
    files = _python_files()
    assert 'src/im_common/im_common/model.py' in files and 'tests/test_lint.py' in files
    assert not any('/__pycache__/' in f for f in files)
    proc = subprocess.run([sys.executable, '-m', 'flake8', '--version'],
                          capture_output=True, text=True, check=True)
    for plugin in ('flake8-docstrings', 'flake8-import-order', 'flake8_quotes', 'flake8-builtins',
                   'flake8-comprehensions'):
        assert plugin.replace('_', '-') in proc.stdout.replace('_', '-'), proc.stdout


def test_every_pending_entry_names_files():
    files = _python_files()
    stale = sorted(p for p in PENDING if not any(fnmatch.fnmatch(f, p) for f in files))
    assert not stale, f'PENDING entries matching no file (delete them): {stale}'


@pytest.mark.processes
@pytest.mark.slow
def test_flake8_with_ament_config_finds_nothing():
    failing, _ = _split(_flake8())
    assert not failing, f'{len(failing)} flake8 findings:\n' + '\n'.join(failing)


@pytest.mark.slow
def test_pep257_with_ament_ignore_list_finds_nothing():
    failing, _ = _split(_pep257())
    assert not failing, f'{len(failing)} pep257 findings:\n' + '\n'.join(failing)
