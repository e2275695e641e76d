"""
No concept has two homes (issue 24).

The names of the flux strategies, the tasks and the controllers are written once, in their homes,
and imported everywhere else.

Every tuple, list or set literal of strings under src/ that holds exactly the names of one of
these vocabularies (in any order) outside its home is a second copy that will drift from the
first; the test names each one as file:line.
"""
import ast
from pathlib import Path

from im_bringup.run_file import CONTROLLERS
from im_controller.control_law import MODES, THESIS_TASKS
from im_controller.flux import COMPARED_STRATEGIES, STRATEGIES
from im_studies.campaign_spec import NOMINAL_AND_ADAPTIVE

SRC = Path(__file__).resolve().parent.parent / 'src'

#: vocabulary -> (its home's file under src/, the name it is defined as there, or None when the
#: home derives it from another vocabulary instead of spelling it out)
VOCABULARIES = {
    'im_controller.flux.STRATEGIES': (STRATEGIES, 'im_controller/im_controller/flux.py',
                                      'STRATEGIES'),
    'im_controller.flux.COMPARED_STRATEGIES': (COMPARED_STRATEGIES,
                                               'im_controller/im_controller/flux.py',
                                               'COMPARED_STRATEGIES'),
    'im_controller.control_law.MODES': (MODES, 'im_controller/im_controller/control_law.py',
                                        'MODES'),
    'im_controller.control_law.THESIS_TASKS': (THESIS_TASKS,
                                               'im_controller/im_controller/control_law.py',
                                               'THESIS_TASKS'),
    'im_bringup.run_file.CONTROLLERS': (CONTROLLERS, 'im_bringup/im_bringup/run_file.py',
                                        'CONTROLLERS'),
    'im_studies.campaign_spec.NOMINAL_AND_ADAPTIVE': (NOMINAL_AND_ADAPTIVE, None, None),
}


def _string_literals(tree: ast.AST):
    """
    Find every tuple/list/set literal made of string constants only.

    Yields (node, the strings) of each, and the name it is assigned to at module or class level
    (None otherwise).
    """
    assigned = {}
    for node in ast.walk(tree):
        if isinstance(node, (ast.Assign, ast.AnnAssign)):
            targets = node.targets if isinstance(node, ast.Assign) else [node.target]
            for t in targets:
                if isinstance(t, ast.Name) and node.value is not None:
                    assigned[id(node.value)] = t.id
    for node in ast.walk(tree):
        if isinstance(node, (ast.Tuple, ast.List, ast.Set)) and len(node.elts) >= 2 and all(
                isinstance(e, ast.Constant) and isinstance(e.value, str) for e in node.elts):
            yield node, [e.value for e in node.elts], assigned.get(id(node))


def copies(root: Path = SRC) -> list:
    """'file:line: literal copies VOCABULARY' for every copy of a vocabulary under ``root``."""
    found = []
    for path in sorted(root.rglob('*.py')):
        if any(part in ('build', 'install', 'log') for part in path.relative_to(root).parts):
            continue
        rel = path.relative_to(root).as_posix()
        tree = ast.parse(path.read_text(encoding='utf-8'), filename=str(path))
        for node, strings, name in sorted(_string_literals(tree), key=lambda x: x[0].lineno):
            for vocab, (values, home, home_name) in VOCABULARIES.items():
                if sorted(strings) != sorted(values):
                    continue
                if rel == home and name == home_name:
                    continue                       # the home itself
                found.append(f'src/{rel}:{node.lineno}: {tuple(strings)} copies {vocab}; '
                             f'import it')
    return found


def test_the_vocabularies_are_distinct():
    """Otherwise a literal could not say which one it copies."""
    seen = {}
    for vocab, (values, _, _) in VOCABULARIES.items():
        key = tuple(sorted(values))
        assert key not in seen, f'{vocab} and {seen.get(key)} hold the same names'
        seen[key] = vocab


def test_the_scanner_finds_a_copy_in_any_order(tmp_path):
    (tmp_path / 'pkg').mkdir()
    (tmp_path / 'pkg' / 'study.py').write_text(
        "TASKS = ['speed', 'position']\n"
        'def f():\n'
        "    for s in ('min_loss', 'min_energy', 'constant_flux'):\n"
        '        pass\n'
        "OTHER = ('position', 'speed', 'extra')\n"
        "ONE = ('position',)\n")
    assert copies(tmp_path) == [
        "src/pkg/study.py:1: ('speed', 'position') copies im_controller.control_law.THESIS_TASKS;"
        ' import it',
        "src/pkg/study.py:3: ('min_loss', 'min_energy', 'constant_flux') copies "
        'im_controller.flux.COMPARED_STRATEGIES; import it']


def test_no_vocabulary_has_a_second_home_under_src():
    found = copies()
    assert not found, '\n'.join(['vocabulary copied outside its home:'] + found)


#: YAML readers other than im_common.yamlio's (to be collapsed into it: docs/architecture.md)
OTHER_YAML_READERS = {('yaml', 'safe_load'), ('yaml', 'load'), ('yaml', 'full_load'),
                      ('yaml', 'unsafe_load'), ('im_common.params', 'read_yaml_file'),
                      ('im_bringup.scenario', 'merge_yaml'),
                      ('im_bringup.processes', 'load_params_yaml')}


def other_yaml_reads(root: Path) -> list:
    """'file:line: module.function' for every YAML read under ``root`` that bypasses yamlio."""
    found = []
    for path in sorted(root.rglob('*.py')):
        tree = ast.parse(path.read_text(encoding='utf-8'), filename=str(path))
        for node in ast.walk(tree):
            hits = []
            if isinstance(node, ast.ImportFrom):
                hits = [(node.module, a.name) for a in node.names]
            elif isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name):
                hits = [(node.value.id, node.attr)]
            for mod, name in hits:
                if (mod, name) in OTHER_YAML_READERS:
                    found.append(f'{path.relative_to(SRC.parent).as_posix()}:{node.lineno}: '
                                 f'{mod}.{name}')
    return found


def test_the_studies_read_every_yaml_file_through_yamlio():
    """
    Check that the studies read every YAML file through im_common.yamlio.

    Specs, gains and parameters files: one reader (im_common.yamlio), one error style (a line
    naming the file and where), whatever the study.
    """
    found = other_yaml_reads(SRC / 'im_studies')
    assert not found, '\n'.join(['YAML read outside im_common.yamlio:'] + found)
