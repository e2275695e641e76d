"""The README's topic and parameter tables are the ones the code declares (no drift), and its
first two commands are the ones CI and users run."""
import os

from im_studies.docs import render

ROOT = os.path.join(os.path.dirname(os.path.abspath(__file__)), '..')


def test_readme_tables_match_the_code():
    with open(os.path.join(ROOT, 'README.md')) as f:
        text = f.read()
    assert render(text) == text, 'README tables are stale: run `python -m im_studies.docs README.md`'


def test_readme_starts_with_the_two_commands_and_ci_runs_the_test_one():
    with open(os.path.join(ROOT, 'README.md')) as f:
        head = f.read().split('```')[1]
    assert 'make demo' in head and 'make test' in head
    with open(os.path.join(ROOT, '.ci', 'run')) as f:
        assert 'make test' in f.read()


def test_results_block_is_generated_from_the_committed_summary():
    """The block between the status markers is exactly what `make readme` renders from
    docs/data/reproduce_summary.json (the copy `make reproduce` refreshes)."""
    from im_studies.readme_status import DEFAULT_SUMMARY, first_difference, load_summary, split_readme
    from im_studies.readme_status import render as render_status
    with open(os.path.join(ROOT, 'README.md')) as f:
        _, block, _ = split_readme(f.read())
    expected = render_status(load_summary(os.path.join(ROOT, DEFAULT_SUMMARY)))
    assert block == expected, f'README results block is stale ({first_difference(block, expected)}): run make readme'


def test_results_block_follows_the_summary_and_names_a_missing_run(tmp_path):
    """Generated, not copied: a changed figure in the summary changes the block; a summary without
    a run the block needs is refused with a message naming the run."""
    import json

    import pytest

    from im_studies.readme_status import SummaryError, load_summary
    from im_studies.readme_status import render as render_status
    runs = load_summary(os.path.join(ROOT, 'docs', 'data', 'reproduce_summary.json'))
    row = next(r for r in runs if (r['task'], r['strategy'], r['controller'], r['variation'],
                                   r['rate_hz']) == ('position', 'min_loss', 'nominal', 'none', 1e4))
    row['E_loss_J'] = 99.5
    assert '| position | min_loss (beyond the thesis) | ' in render_status(runs)
    assert '**99.50**' in render_status(runs)
    runs.remove(row)
    with pytest.raises(SummaryError, match='task=position strategy=min_loss controller=nominal'):
        render_status(runs)
    bad = tmp_path / 'summary.json'
    bad.write_text(json.dumps({'not': 'a list'}))
    with pytest.raises(SummaryError, match='not a list of runs'):
        load_summary(str(bad))
