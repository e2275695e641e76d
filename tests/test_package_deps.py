"""
Every package.xml declares what its package imports, and nothing it does not.

Read from the source with :mod:`ast` (no import is executed): the modules of src/<pkg>/<pkg>/
and its launch files need an ``exec_depend`` (or ``depend``) on each ROS package, message
package and third-party Python module they import, as its rosdep key; the unit tests in
src/<pkg>/test/ may use a ``test_depend`` instead. A declared key no import needs is reported.
Sibling packages (im_*) are checked by tests/test_architecture.py.
"""
import ast
import importlib.metadata
from pathlib import Path
import re
import sys

import yaml

SRC = Path(__file__).resolve().parents[1] / 'src'
PACKAGES = sorted(p.name for p in SRC.iterdir() if (p / 'package.xml').is_file())

#: ROS 2 packages imported as Python modules: the rosdep key is the package name.
ROS_PACKAGES = {
    'rclpy', 'launch', 'launch_ros', 'ament_index_python', 'rosidl_runtime_py',
    'std_msgs', 'geometry_msgs', 'sensor_msgs', 'rosgraph_msgs', 'diagnostic_msgs',
    'rcl_interfaces', 'builtin_interfaces',
}

#: Third-party Python modules -> rosdep key, as in ros/rosdistro rosdep/python.yaml.
#: Where rosdistro has no key, the pip form rosdep uses is declared (``python3-<name>-pip``) and
#: the key is defined in rosdep/python-pip.yaml at the repository root (add it to rosdep's sources,
#: see the README there); requirements.txt pins the versions either way.
PYTHON_KEYS = {
    'numpy': 'python3-numpy',
    'scipy': 'python3-scipy',
    'yaml': 'python3-yaml',
    'pydantic': 'python3-pydantic',         # in rosdistro (requirements.txt pins pydantic 2)
    'matplotlib': 'python3-matplotlib',
    'numba': 'python3-numba',               # in rosdistro (the real plant's compiled period)
    'pytest': 'python3-pytest',
    'rosbags': 'python3-rosbags-pip',       # in rosdistro (pip)
    'cvxpy': 'python3-cvxpy-pip',           # in rosdistro (pip)
    'mcap': 'python3-mcap-pip',             # not in rosdistro: rosdep/python-pip.yaml
    'lz4': 'python3-lz4-pip',               # not in rosdistro: rosdep/python-pip.yaml
    'zstandard': 'python3-zstandard-pip',   # not in rosdistro: rosdep/python-pip.yaml
    'pyarrow': 'python3-pyarrow-pip',       # not in rosdistro: rosdep/python-pip.yaml
    'distributed': 'python3-distributed-pip',   # not in rosdistro: rosdep/python-pip.yaml
    'foxglove': 'python3-foxglove-sdk-pip',     # not in rosdistro: rosdep/python-pip.yaml
}
#: the keys of PYTHON_KEYS that ros/rosdistro does not define (checked 2026-11 against its
#: rosdep/python.yaml); the project's rosdep/python-pip.yaml defines them
NOT_IN_ROSDISTRO = {'mcap', 'lz4', 'zstandard', 'pyarrow', 'distributed', 'foxglove'}
ROOT = SRC.parent


def _top_imports(files):
    """Top-level names of the absolute imports in ``files`` (stdlib left out)."""
    found = set()
    for f in files:
        for node in ast.walk(ast.parse(f.read_text(), filename=str(f))):
            if isinstance(node, ast.Import):
                found.update(a.name.split('.')[0] for a in node.names)
            elif isinstance(node, ast.ImportFrom) and not node.level:
                found.add(node.module.split('.')[0])
    return found - set(sys.stdlib_module_names) - {'__future__'}


def _runtime_files(pkg):
    return sorted((SRC / pkg / pkg).rglob('*.py')) + sorted((SRC / pkg).glob('launch/*.py'))


def _test_files(pkg):
    return sorted((SRC / pkg).glob('test/*.py'))


def _declared(pkg, tags):
    xml = (SRC / pkg / 'package.xml').read_text()
    xml = re.sub(r'<!--.*?-->', '', xml, flags=re.S)
    return set(re.findall(rf'<(?:{tags})>\s*([\w.-]+)\s*</', xml))


def _key(module):
    if module in ROS_PACKAGES:
        return module
    return PYTHON_KEYS.get(module)


def _external(mods):
    return {m for m in mods if not (m.startswith('im_') and m in PACKAGES)}


def test_the_parser_sees_the_packages():
    # guards the other tests against passing on an empty or misread tree
    assert {'im_common', 'im_bringup', 'im_recording'} <= set(PACKAGES)
    assert {'rclpy', 'numpy'} <= _top_imports(_runtime_files('im_common'))
    assert 'launch' in _top_imports(_runtime_files('im_bringup'))
    assert 'python3-numpy' in _declared('im_common', 'exec_depend|depend')


def test_every_import_has_a_rosdep_key():
    unknown = sorted(f'{pkg}: {m}' for pkg in PACKAGES
                     for m in _external(_top_imports(_runtime_files(pkg) + _test_files(pkg)))
                     if _key(m) is None)
    assert not unknown, ('imports with no rosdep key in this test (add the module to ROS_PACKAGES '
                         'or PYTHON_KEYS with its key from rosdistro):\n' + '\n'.join(unknown))


def test_every_import_is_declared():
    missing = []
    for pkg in PACKAGES:
        run = _declared(pkg, 'exec_depend|depend')
        test = run | _declared(pkg, 'test_depend')
        missing += [f'{pkg}: <exec_depend>{_key(m)}</exec_depend>'
                    for m in sorted(_external(_top_imports(_runtime_files(pkg))))
                    if _key(m) and _key(m) not in run]
        missing += [f'{pkg}: <test_depend>{_key(m)}</test_depend>'
                    for m in sorted(_external(_top_imports(_test_files(pkg))))
                    if _key(m) and _key(m) not in test]
    assert not missing, 'imported but not declared in package.xml:\n' + '\n'.join(missing)


def test_nothing_declared_is_unused():
    extra = []
    for pkg in PACKAGES:
        run = {_key(m) for m in _external(_top_imports(_runtime_files(pkg)))}
        test = {_key(m) for m in _external(_top_imports(_test_files(pkg)))}
        declared = _declared(pkg, 'exec_depend|depend|test_depend') - set(PACKAGES)
        extra += [f'{pkg}: {k}' for k in sorted(declared - run - test)]
        # a test-only key declared as exec_depend ships a dependency users do not need
        extra += [f'{pkg}: {k} (used by the tests only: test_depend)'
                  for k in sorted((_declared(pkg, 'exec_depend|depend') & test) - run)]
    assert not extra, 'declared in package.xml but never imported:\n' + '\n'.join(extra)


def test_keys_missing_from_rosdistro_are_defined_by_the_project():
    rules = yaml.safe_load((ROOT / 'rosdep' / 'python-pip.yaml').read_text())
    assert set(rules) == {PYTHON_KEYS[m] for m in NOT_IN_ROSDISTRO}
    for module in NOT_IN_ROSDISTRO:
        pip_name = rules[PYTHON_KEYS[module]]['*']['pip']['packages'][0]
        # the pip distribution named there is the one that provides the module here
        provided = importlib.metadata.packages_distributions().get(module, [])
        assert pip_name in provided, f'{module}: {pip_name} not in {provided}'


def test_license_file_matches_the_declared_license():
    text = (ROOT / 'LICENSE').read_text()
    assert 'Apache License' in text and 'Version 2.0, January 2004' in text
    assert 'END OF TERMS AND CONDITIONS' in text     # the full text, not a pointer to it
    for pkg in PACKAGES:
        xml = (SRC / pkg / 'package.xml').read_text()
        assert re.findall(r'<license>(.*?)</license>', xml) == ['Apache-2.0'], pkg
        assert "license='Apache-2.0'" in (SRC / pkg / 'setup.py').read_text(), pkg
