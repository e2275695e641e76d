"""
The README a newcomer reads first, and the generated pages it points to (issue 24 item 5).

The README starts with the two commands CI and users run, says where the demo's files land (the
paths the Makefile's demo recipe writes), stays short, and every command it shows runs: each
``ros2 run`` names an installed executable that accepts the options shown, each ``ros2 launch``
argument is declared, each ``make`` target exists. The generated blocks are what their one
generator renders: the topic and parameter tables of docs/parameters.md from the code
(``python -m im_studies.docs``), the results of docs/results.md and the README's headline from the
committed summary (``python -m im_studies.readme_status``); ``make readme`` runs both.
"""
import ast
import os
import re
import shlex
import subprocess

from im_studies.docs import render
import pytest

ROOT = os.path.join(os.path.dirname(os.path.abspath(__file__)), '..')
README = os.path.join(ROOT, 'README.md')
#: the issue's limit: a README a newcomer reads, not a manual
MAX_README_LINES = 250
#: the first screen: what it is, the two commands, where the demo's files land, what to read next
FIRST_SCREEN_LINES = 40


def _read(*path: str) -> str:
    with open(os.path.join(ROOT, *path)) as f:
        return f.read()


#: pages whose shell commands are checked like the README's (the command catalogue)
COMMAND_PAGES = ('README.md', os.path.join('docs', 'commands.md'))


def _code_lines(text: str, lang: str = 'bash'):
    """Yield the lines of a page's ``lang`` code blocks, continuations joined, comments cut."""
    for block in re.findall(rf'```{lang}\n(.*?)```', text, re.S):
        for line in block.replace('\\\n', ' ').splitlines():
            line = line.split(' # ')[0].strip()
            if line and not line.startswith('#'):
                yield line


def _makefile_recipe(target: str) -> str:
    m = re.search(rf'^{re.escape(target)}:.*\n((?:\t.*\n?)+)', _read('Makefile'), re.M)
    assert m, f'Makefile has no target {target}'
    return m.group(1)


def test_parameter_page_tables_match_the_code():
    text = _read('docs', 'parameters.md')
    assert render(text) == text, ('docs/parameters.md tables are stale: run '
                                  '`python -m im_studies.docs docs/parameters.md` (make readme)')


def test_readme_starts_with_the_two_commands_and_ci_runs_the_test_one():
    head = _read('README.md').split('```')[1]
    assert 'make demo' in head and 'make test' in head
    assert 'make test' in _read('.ci', 'run')


def test_readme_is_short():
    n = len(_read('README.md').splitlines())
    assert n <= MAX_README_LINES, \
        f'README.md has {n} lines (at most {MAX_README_LINES}): move detail to docs/'


def test_first_screen_says_where_the_demo_files_land_and_what_to_read_next():
    """
    Check that the first screen names the paths the demo recipe writes.

    The paths on the first screen are the ones the demo recipe writes: the recording, the
    summary next to it (scenario's default) and the report directory.
    """
    recipe = _makefile_recipe('demo')
    record = re.search(r'--record (\S+)', recipe).group(1)
    report = re.search(r'--report (\S+)', recipe).group(1)
    summary = os.path.splitext(record)[0] + '.json'
    screen = '\n'.join(_read('README.md').splitlines()[:FIRST_SCREEN_LINES])
    for path in (record, summary, f'{report}/report.md'):
        assert f'`{path}`' in screen, \
            f'the first screen does not say where make demo writes {path}'
    nxt = screen.split('What to read next', 1)
    assert len(nxt) == 2, 'the first screen has no "What to read next" list'
    assert re.search(r'\]\(docs/[\w.-]+\.md\)', nxt[1]), 'the reading list links no docs/ page'


@pytest.mark.parametrize('page', COMMAND_PAGES)
def test_every_make_target_shown_exists(page):
    targets = set(re.findall(r'^([\w-]+):', _read('Makefile'), re.M))
    shown = set(re.findall(r'`make ([\w-]+)`', _read(page)))
    shown |= {line.split()[1] for line in _code_lines(_read(page)) if line.startswith('make ')}
    assert shown and shown <= targets, \
        f'{page} shows make targets the Makefile lacks: {shown - targets}'


def _ros2_run_path(package: str, executable: str) -> str:
    from ament_index_python.packages import get_package_prefix
    return os.path.join(get_package_prefix(package), 'lib', package, executable)


@pytest.mark.processes
@pytest.mark.parametrize('page', COMMAND_PAGES)
def test_every_ros2_run_shown_runs_with_the_options_shown(page):
    """
    Check that each ``ros2 run`` shown runs, with the options shown.

    Each ``ros2 run PKG EXE ...`` line: the executable is where ``ros2 run`` looks, and every
    long option shown is one its ``--help`` lists (a renamed option fails here).
    """
    runs = [shlex.split(line) for line in _code_lines(_read(page)) if line.startswith('ros2 run ')]
    assert len(runs) >= 5
    helps = {}
    for argv in runs:
        package, exe = argv[2], argv[3]
        if (package, exe) not in helps:
            path = _ros2_run_path(package, exe)
            assert os.access(path, os.X_OK), \
                f'ros2 run {package} {exe}: {path} is not an executable'
            proc = subprocess.run([path, '--help'], capture_output=True, text=True, timeout=120)
            assert proc.returncode == 0, f'ros2 run {package} {exe} --help: {proc.stderr[-1000:]}'
            helps[package, exe] = proc.stdout
        for opt in (a for a in argv[4:] if a.startswith('--') and a != '--help'):
            assert re.search(rf'{re.escape(opt)}\b', helps[package, exe]), \
                f'{page}: ros2 run {package} {exe}: --help does not list {opt}'


@pytest.mark.parametrize('page', COMMAND_PAGES)
def test_every_ros2_launch_argument_shown_is_declared(page):
    src = _read('src', 'im_bringup', 'launch', 'drive.launch.py')
    args = next(n for n in ast.walk(ast.parse(src)) if isinstance(n, ast.Assign)
                and getattr(n.targets[0], 'id', '') == 'ARGUMENTS')
    declared = {elt.elts[0].value for elt in args.value.elts}
    launches = [shlex.split(line) for line in _code_lines(_read(page))
                if line.startswith('ros2 launch ')]
    assert launches
    for argv in launches:
        assert argv[2:4] == ['im_bringup', 'drive.launch.py'], argv
        used = {a.split(':=')[0] for a in argv[4:] if ':=' in a}
        assert used <= declared, f'{page}: ros2 launch: undeclared arguments {used - declared}'


@pytest.mark.processes
def test_readme_ros2_stand_in_runs_an_executable(tmp_path):
    """
    Check that the README's ``ros2`` stand-in runs an installed executable.

    Without a ROS 2 install the README's ``ros2`` shell function is how a user types ``ros2
    run``: pasted as shown, it runs the installed executable and refuses other verbs in one
    line.
    """
    defs = [line for line in _code_lines(_read('README.md')) if line.startswith('ros2()')]
    assert len(defs) == 1, 'the README defines its ros2 stand-in once'
    script = tmp_path / 'shell.sh'
    script.write_text(defs[0] + '\nros2 run im_recording report --help || exit 1\n'
                      'ros2 launch im_bringup drive.launch.py; echo "launch rc $?"\n')
    proc = subprocess.run(['bash', str(script)], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr[-1000:]
    assert 'usage' in proc.stdout.lower() and 'launch rc 2' in proc.stdout
    assert proc.stderr.strip().count('\n') == 0 and 'ros2 launch' in proc.stderr


def _blocks():
    from im_studies.readme_status import split_block
    return (split_block(_read('docs', 'results.md'), 'status', 'docs/results.md')[1],
            split_block(_read('README.md'), 'headline', 'README.md')[1])


def test_results_and_headline_are_generated_from_the_committed_summary():
    """
    Check that the results block and headline are generated from the committed summary.

    docs/results.md's status block and the README's headline are exactly what `make readme`
    renders from docs/data/reproduce_summary.json (the copy `make reproduce` refreshes).
    """
    from im_studies.readme_status import (DEFAULT_SUMMARY, first_difference, load_summary,
                                          render_headline)
    from im_studies.readme_status import render as render_status
    runs = load_summary(os.path.join(ROOT, DEFAULT_SUMMARY))
    results, headline = _blocks()
    expected = render_status(runs)
    assert results == expected, \
        f'docs/results.md is stale ({first_difference(results, expected)}): run make readme'
    expected = render_headline(runs)
    assert headline == expected, \
        f'README headline is stale ({first_difference(headline, expected)}): run make readme'
    assert 2 <= len([l_ for l_ in headline.splitlines() if l_.startswith('- ')]) <= 5


def test_results_block_follows_the_summary_and_names_a_missing_run(tmp_path):
    """
    Check that the results block follows the summary and names a missing run.

    Generated, not copied: a changed figure in the summary changes the block and the headline; a
    summary without a run the blocks need is refused with a message naming the run.
    """
    import json

    from im_studies.readme_status import SummaryError, load_summary, render_headline
    from im_studies.readme_status import render as render_status
    runs = load_summary(os.path.join(ROOT, 'docs', 'data', 'reproduce_summary.json'))
    key = ('position', 'min_loss', 'nominal', 'none', 1e4)
    row = next(r for r in runs
               if (r['task'], r['strategy'], r['controller'], r['variation'], r['rate_hz']) == key)
    row['E_loss_J'] = 99.5
    assert '| position | min_loss (beyond the thesis) | ' in render_status(runs)
    assert '**99.50**' in render_status(runs)
    assert 'loses 99.50 J on the' in render_headline(runs)
    runs.remove(row)
    for renderer in (render_status, render_headline):
        with pytest.raises(SummaryError,
                           match='task=position strategy=min_loss controller=nominal'):
            renderer(runs)
    bad = tmp_path / 'summary.json'
    bad.write_text(json.dumps({'not': 'a list'}))
    with pytest.raises(SummaryError, match='not a list of runs'):
        load_summary(str(bad))


def test_check_names_the_stale_file_and_write_restores_it(tmp_path):
    """
    Check that ``--check`` names the stale file and ``--write`` restores it.

    `readme_status --check` exits 1 naming the file whose block is stale; `--write` fills both
    files; a file without its markers is one line naming file and markers, exit 2.
    """
    import shutil

    from im_studies.readme_status import main
    results, readme = tmp_path / 'results.md', tmp_path / 'README.md'
    shutil.copy(os.path.join(ROOT, 'docs', 'results.md'), results)
    shutil.copy(README, readme)
    argv = ['--summary', os.path.join(ROOT, 'docs', 'data', 'reproduce_summary.json'),
            '--results', str(results), '--readme', str(readme)]
    assert main(argv + ['--check']) == 0
    readme.write_text(readme.read_text().replace('<!-- headline:begin -->\n',
                                                 '<!-- headline:begin -->\nhand-edited\n'))
    assert main(argv + ['--check']) == 1
    assert main(argv + ['--write']) == 0 and main(argv + ['--check']) == 0
    assert readme.read_text() == _read('README.md')
    results.write_text('no markers\n')
    assert main(argv + ['--write']) == 2
