"""
The test lanes: the suite tests the source tree, and ``make test-fast`` is the edit-test loop.

pytest.ini puts every package of src/ on the path (before, ``im_recording`` and ``im_studies``
were left off: the suite tested install/'s copy, stale until a rebuild); tests/conftest.py
refuses a session that imported one from anywhere else. The marks ``processes`` and ``slow``
split the suite: ``make test-fast`` runs what carries neither, ``make test`` (CI) runs all.
"""
import configparser
import os
import re
import shutil
import subprocess
import sys

from conftest import not_from_source, ROOT, source_packages
import pytest

PROBE_TEST = """
import importlib


def test_probe():
    for name in {names!r}:
        assert importlib.import_module(name).SUITE_PROBE == 'edited', name
"""


def _ini():
    ini = configparser.ConfigParser()
    ini.read(os.path.join(ROOT, 'pytest.ini'))
    return ini['pytest']


def _copy_with_edit(tmp_path, pythonpath=None):
    """Copy the repository's test setup and src/ into tmp_path, each package's __init__ edited."""
    shutil.copytree(os.path.join(ROOT, 'src'), tmp_path / 'src',
                    ignore=shutil.ignore_patterns('__pycache__'))
    (tmp_path / 'tests').mkdir()
    shutil.copy(os.path.join(ROOT, 'tests', 'conftest.py'), tmp_path / 'tests')
    ini = open(os.path.join(ROOT, 'pytest.ini')).read()
    if pythonpath is not None:
        ini = re.sub(r'^pythonpath = .*$', f'pythonpath = {pythonpath}', ini, flags=re.M)
    (tmp_path / 'pytest.ini').write_text(ini)
    for name in source_packages():
        with open(tmp_path / 'src' / name / name / '__init__.py', 'a') as f:
            f.write("\nSUITE_PROBE = 'edited'\n")
    (tmp_path / 'tests' / 'test_probe.py').write_text(
        PROBE_TEST.format(names=sorted(source_packages())))
    return subprocess.run([sys.executable, '-m', 'pytest', '-q', '-p', 'no:randomly',
                           'tests/test_probe.py'], cwd=tmp_path, capture_output=True,
                          text=True, timeout=300)


def test_the_pythonpath_is_every_package_of_src():
    want = {f'src/{name}' for name in source_packages()}
    assert set(_ini()['pythonpath'].split()) == want


def test_this_session_imported_every_package_from_src():
    pkgs = source_packages()
    loaded = {n: m for n, m in sys.modules.items() if n.split('.')[0] in pkgs}
    assert set(pkgs) <= set(loaded)
    assert not_from_source(loaded) == []
    # the guard names a copy elsewhere (install/'s, after colcon build)
    fake = type(sys)('im_recording.bag')
    fake.__file__ = os.path.join(ROOT, 'install', 'im_recording', 'lib', 'python3.11',
                                 'site-packages', 'im_recording', 'bag.py')
    (line,) = not_from_source({'im_recording.bag': fake})
    assert line.startswith('im_recording.bag is imported from ') and 'install' in line


@pytest.mark.processes
def test_an_edit_of_the_source_is_what_the_suite_runs(tmp_path):
    """
    Edit every package in a copy of src/ (no rebuild): a test run by its pytest.ini sees the edit.

    install/ (on PYTHONPATH from install/setup.bash) holds the old code meanwhile.
    """
    r = _copy_with_edit(tmp_path / 'ok')
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    assert '1 passed' in r.stdout


@pytest.mark.processes
def test_a_package_left_off_the_path_stops_the_session_with_one_message(tmp_path):
    """The pythonpath as it was (im_recording and im_studies off): the session refuses to run."""
    old = ' '.join(f'src/{n}' for n in source_packages() if n not in ('im_recording',
                                                                      'im_studies'))
    r = _copy_with_edit(tmp_path / 'off', pythonpath=old)
    assert r.returncode != 0 and 'passed' not in r.stdout
    out = r.stdout + r.stderr
    assert 'the suite must test the source tree' in out, out[-3000:]
    assert 'im_recording is imported from ' in out and 'im_studies is imported from ' in out


def test_the_fast_lane_leaves_out_the_marked_tests_and_ci_runs_all():
    makefile = open(os.path.join(ROOT, 'Makefile')).read()
    fast = re.search(r'^test-fast:.*\n((?:\t.*\n?)+)', makefile, re.M)
    assert fast and '-m "not processes and not slow"' in fast.group(1)
    full = re.search(r'^test:.*\n((?:\t.*\n?)+)', makefile, re.M).group(1)
    assert '-m "' not in full and 'not slow' not in full
    assert 'make test' in open(os.path.join(ROOT, '.ci', 'run')).read()
    marks = {ln.split(':')[0].strip() for ln in _ini()['markers'].strip().splitlines()}
    assert marks == {'processes', 'slow'} and '--strict-markers' in _ini()['addopts']
