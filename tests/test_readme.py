"""The README's topic and parameter tables are the ones the code declares (no drift), and its
first two commands are the ones CI and users run."""
import os

from im_bringup.docs import render

ROOT = os.path.join(os.path.dirname(os.path.abspath(__file__)), '..')


def test_readme_tables_match_the_code():
    with open(os.path.join(ROOT, 'README.md')) as f:
        text = f.read()
    assert render(text) == text, 'README tables are stale: run `python -m im_bringup.docs README.md`'


def test_readme_starts_with_the_two_commands_and_ci_runs_the_test_one():
    with open(os.path.join(ROOT, 'README.md')) as f:
        head = f.read().split('```')[1]
    assert 'make demo' in head and 'make test' in head
    with open(os.path.join(ROOT, '.ci', 'run')) as f:
        assert 'make test' in f.read()
