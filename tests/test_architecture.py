"""
Who may import whom (docs/architecture.md), read from the source itself.

Every module under src/<pkg>/<pkg>/ is parsed with :mod:`ast` (no import is executed) and each
``import`` / ``from ... import`` (module level or inside functions, relative ones resolved) becomes
an edge. Asserted: the package-level import graph has no cycle; the whole-system packages are
layered (nodes and libraries < im_recording < im_bringup < im_studies: none imports a layer above
it); every sibling package a package imports is declared in its package.xml; the ROS-free math
modules reach no rclpy, directly or through project modules.
"""
import ast
from pathlib import Path
import re

import pytest

SRC = Path(__file__).resolve().parents[1] / 'src'
PACKAGES = sorted(p.name for p in SRC.iterdir() if (p / 'package.xml').is_file())
#: the whole-system layers, bottom to top; every other package (nodes, libraries) is below them all
LAYERS = ['im_recording', 'im_bringup', 'im_studies']


def _layer(pkg: str) -> int:
    return LAYERS.index(pkg) + 1 if pkg in LAYERS else 0


#: ROS-free math: nodes are thin shells over these, and they are unit-tested without ROS.
ROS_FREE = [
    'im_common.model', 'im_common.params', 'im_common.loads', 'im_plant.plant_sim',
    'im_common.metrics', 'im_common.steady_state', 'im_common.step_gate',
    'im_common.lockstep_protocol',
    'im_common.signing', 'im_common.lockstep_parts', 'im_common.topics',
    'im_common.compensation', 'im_observer.observer',
    'im_controller.control_law', 'im_controller.flux', 'im_controller.reference',
    'im_controller.trajectories', 'im_adapt.adaptation',
] + sorted(f'im_robust.{p.stem}' for p in (SRC / 'im_robust' / 'im_robust').glob('*.py')
           if p.stem not in ('__init__', 'cli')) + sorted(
    f'im_controller.baselines.{p.stem}'
    for p in (SRC / 'im_controller' / 'im_controller' / 'baselines').glob('*.py')
    if p.stem != '__init__')
# im_robust.cli is the command-line entry point (it strips ROS arguments when rclpy is present);
# the synthesis library it drives is in the list above.


def _module_files():
    out = {}
    for pkg in PACKAGES:
        root = SRC / pkg
        for f in (root / pkg).rglob('*.py'):
            rel = f.relative_to(root).with_suffix('')
            parts = list(rel.parts)
            if parts[-1] == '__init__':
                parts = parts[:-1]
            out['.'.join(parts)] = f
    return out


MODULES = _module_files()


def _imports(name: str, path: Path):
    """Absolute names of everything the module imports (relative imports resolved)."""
    tree = ast.parse(path.read_text(), filename=str(path))
    is_pkg = path.name == '__init__.py'
    base = name.split('.') if is_pkg else name.split('.')[:-1]
    found = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                anchor = base[:len(base) - (node.level - 1)]
                mod = '.'.join(anchor + ([node.module] if node.module else []))
            else:
                mod = node.module
            found.add(mod)
            found.update(f'{mod}.{a.name}' for a in node.names)   # `from pkg import module`
    return found


IMPORTS = {name: _imports(name, path) for name, path in MODULES.items()}


def _package_edges():
    edges = {p: set() for p in PACKAGES}
    for name, mods in IMPORTS.items():
        src = name.split('.')[0]
        for m in mods:
            dst = m.split('.')[0]
            if dst in edges and dst != src:
                edges[src].add(dst)
    return edges


def _declared(pkg: str):
    xml = (SRC / pkg / 'package.xml').read_text()
    return set(re.findall(r'<(?:exec_|build_|build_export_|test_)?depend>\s*([\w-]+)\s*<', xml))


def test_the_parser_sees_the_tree():
    # guards the other tests against passing on an empty or misread tree
    assert {'im_common', 'im_bringup', 'im_robust'} <= set(PACKAGES)
    assert 'im_bringup.offline' in MODULES and 'im_common.model' in MODULES
    assert 'im_common' in _package_edges()['im_bringup']


def test_no_package_level_cycle():
    edges = _package_edges()
    state = {}

    def visit(p, stack):
        state[p] = 'open'
        for q in sorted(edges[p]):
            if state.get(q) == 'open':
                cyc = stack[stack.index(q):] + [q]
                pytest.fail('package import cycle: ' + ' -> '.join(cyc))
            if q not in state:
                visit(q, stack + [q])
        state[p] = 'done'

    for p in PACKAGES:
        if p not in state:
            visit(p, [p])


#: module circles being removed on other branches of issue 12 (bag.py/run.py,
#: config.py/offline.py); the merge that removes one deletes its entry here, and the test then
#: guards it.
PENDING_CIRCLES: set = set()


def _module_circles():
    """Strongly connected groups of two or more modules (Tarjan), as frozensets."""
    graph = {n: {m for m in mods if m in MODULES and m != n} for n, mods in IMPORTS.items()}
    index, low, stack, on, out = {}, {}, [], set(), []

    def strong(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in sorted(graph[v]):
            if w not in index:
                strong(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = set()
            while True:
                w = stack.pop()
                on.discard(w)
                comp.add(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(frozenset(comp))

    for v in sorted(graph):
        if v not in index:
            strong(v)
    return out


def test_no_module_level_import_circle():
    new = [sorted(c) for c in _module_circles() if c not in PENDING_CIRCLES]
    assert not new, f'module import circles: {new}'


def test_no_package_imports_a_layer_above_it():
    bad = sorted(f'{n} imports {m}' for n, mods in IMPORTS.items() for m in mods
                 if _layer(m.split('.')[0]) > _layer(n.split('.')[0]))
    assert not bad, 'imports of a higher layer (' + ' < '.join(LAYERS) + '):\n' + '\n'.join(bad)
    # the unit tests of a package are held to the same rule
    tests = sorted(str(f.relative_to(SRC)) for pkg in PACKAGES
                   for f in (SRC / pkg).glob('test/*.py')
                   if any(_layer(m.split('.')[0]) > _layer(pkg) for m in _imports('t', f)))
    assert not tests, f'package tests importing a higher layer: {tests}'


def test_the_layers_are_the_packages():
    # guards the layer test against a renamed package silently dropping to layer 0
    assert set(LAYERS) <= set(PACKAGES)
    assert 'im_recording' in _package_edges()['im_bringup']
    assert 'im_bringup' in _package_edges()['im_studies']


def test_imported_siblings_are_declared_in_package_xml():
    edges = _package_edges()
    missing = sorted(f'{p}: {q}' for p in PACKAGES for q in edges[p] - _declared(p))
    assert not missing, 'imported but not declared in package.xml: ' + ', '.join(missing)


def test_declared_siblings_are_imported():
    edges = _package_edges()
    extra = sorted(f'{p}: {q}' for p in PACKAGES
                   for q in (_declared(p) & set(PACKAGES)) - edges[p])
    assert not extra, 'declared in package.xml but never imported: ' + ', '.join(extra)


def _reaches_rclpy(name, seen=None, path=()):
    seen = set() if seen is None else seen
    if name in seen:
        return None
    seen.add(name)
    for m in sorted(IMPORTS[name]):
        if m.split('.')[0] in ('rclpy', 'rosidl_runtime_py', 'launch', 'launch_ros'):
            return list(path) + [name, m]
        if m in MODULES:
            hit = _reaches_rclpy(m, seen, list(path) + [name])
            if hit:
                return hit
    return None


@pytest.mark.parametrize('module', ROS_FREE)
def test_ros_free_math_imports_no_rclpy(module):
    assert module in MODULES, f'{module} is listed as ROS-free math but does not exist'
    hit = _reaches_rclpy(module)
    assert hit is None, f'{module} reaches ROS: ' + ' -> '.join(hit)


def _private_reads(path: Path):
    """
    Return the private names a file reads from other modules: ``(line, what)``.

    A name is private when it has one leading underscore (not a dunder). A read ``x._name`` is
    allowed when ``_name`` is bound in the same file (its own class's attribute, its own helper);
    ``from m import _name`` never is.
    """
    tree = ast.parse(path.read_text(encoding='utf-8'))
    own = set()
    for n in ast.walk(tree):
        if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            own.add(n.name)
        elif isinstance(n, ast.Attribute) and isinstance(n.ctx, ast.Store):
            own.add(n.attr)
        elif isinstance(n, ast.Name) and isinstance(n.ctx, ast.Store):
            own.add(n.id)
        elif isinstance(n, ast.arg):
            own.add(n.arg)

    def private(name: str) -> bool:
        return name.startswith('_') and not name.startswith('__')
    out = []
    for n in ast.walk(tree):
        if isinstance(n, ast.Attribute) and private(n.attr) and n.attr not in own:
            out.append((n.lineno, f'.{n.attr}'))
        elif isinstance(n, ast.ImportFrom):
            out += [(n.lineno, f'import {a.name} from {n.module}') for a in n.names
                    if private(a.name)]
    return out


def test_no_module_reads_another_modules_private_names():
    """
    What a module keeps private stays its own (issue 33): a reader uses a public name.

    Covers every module of every package, its node tests, and the launch files; rclpy's private
    attributes are covered too (``node._parameters`` is ``node.list_parameters``).
    """
    files = sorted(SRC.glob('*/*/*.py')) + sorted(SRC.glob('*/launch/*.py'))
    assert len(files) > 80
    found = [f'{p.relative_to(SRC)}:{line}: {what}' for p in files
             for line, what in _private_reads(p)]
    assert not found, 'private names read across modules:\n' + '\n'.join(found)


def test_the_private_name_rule_sees_a_violation(tmp_path):
    bad = tmp_path / 'bad.py'
    bad.write_text('from x import _y\n\n\ndef f(obs):\n    return obs._c + 1\n')
    assert _private_reads(bad) == [(1, 'import _y from x'), (5, '._c')]
    ok = tmp_path / 'ok.py'
    ok.write_text('class A:\n    def __init__(self):\n        self._c = 1\n\n'
                  '    def f(self, other):\n        return other._c + self.__class__.__name__\n')
    assert _private_reads(ok) == []


def _rclpy_method_names() -> set:
    """Return the method names of the rclpy classes a node uses (Node, Publisher, Subscription)."""
    from rclpy.node import Node
    from rclpy.publisher import Publisher
    from rclpy.subscription import Subscription
    return {n for cls in (Node, Publisher, Subscription) for n in dir(cls)
            if not n.startswith('__') and callable(getattr(cls, n, None))}


def _patches(path: Path, names: set):
    """Return (line, what) where a file assigns an rclpy method name on an object not ``self``."""
    tree = ast.parse(path.read_text(encoding='utf-8'))
    out = []
    for n in ast.walk(tree):
        targets = n.targets if isinstance(n, ast.Assign) else []
        for t in targets:
            if (isinstance(t, ast.Attribute) and t.attr in names
                    and not (isinstance(t.value, ast.Name) and t.value.id == 'self')):
                out.append((n.lineno, f'.{t.attr} = ...'))
        if (isinstance(n, ast.Call) and isinstance(n.func, ast.Name) and n.func.id == 'setattr'
                and len(n.args) > 1 and isinstance(n.args[1], ast.Constant)
                and n.args[1].value in names):
            out.append((n.lineno, f'setattr(..., {n.args[1].value!r}, ...)'))
    return out


def test_no_rclpy_method_is_monkeypatched():
    """
    Recording in one process uses the nodes' own tap (LockstepNode.tap), not a patched publish.

    Every module, node test and test file: no assignment of an rclpy Node / Publisher /
    Subscription method name on another object (issue 33).
    """
    names = _rclpy_method_names()
    assert {'publish', 'create_publisher', 'create_subscription'} <= names
    files = (sorted(SRC.glob('*/*/*.py')) + sorted(SRC.glob('*/test/*.py'))
             + sorted((SRC.parent / 'tests').glob('*.py')))
    found = [f'{p.relative_to(SRC.parent)}:{line}: {what}' for p in files
             for line, what in _patches(p, names)]
    assert not found, 'rclpy methods patched:\n' + '\n'.join(found)


def test_the_patch_rule_sees_one(tmp_path):
    bad = tmp_path / 'bad.py'
    bad.write_text("pub.publish = print\nsetattr(node, 'spin_once', None)\nself.publish = 1\n")
    assert [w for _, w in _patches(bad, {'publish', 'spin_once'})] == [
        '.publish = ...', "setattr(..., 'spin_once', ...)"]
