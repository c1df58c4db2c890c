"""The core's folders are its layers: nothing imports from a layer above its own, no import
cycle, no file over 450 lines, and the pure layers import only numpy, scipy and numba
beside the standard library.
"""

import ast
import sys

import pytest

from conftest import ROOT


CORE = ROOT / 'curve_formation' / 'core'
# lowest first: a module may import from its own layer and those before it
LAYERS = ('base', 'formation', 'controller', 'config', 'record', 'world', 'schedule', 'sim')
# the layers whose files touch no file format, engine or validation library
PURE = ('base', 'formation', 'controller', 'record', 'schedule', 'sim')
PURE_THIRD_PARTY = {'numpy', 'scipy', 'numba'}
MAX_LINES = 450


def modules():
    """{dotted name under core: path} of every core module."""
    return {'.'.join(p.relative_to(CORE).with_suffix('').parts): p
            for p in sorted(CORE.rglob('*.py')) if p.name != '__init__.py'}


def imported(path, runtime_only=False):
    """Top-level names of what `path` imports: ('core', 'layer.module') for the core's own
    modules and ('other', 'package') for the rest. runtime_only leaves out imports under
    `if TYPE_CHECKING:`.
    """
    tree = ast.parse(path.read_text())
    skip = set()
    if runtime_only:
        for node in ast.walk(tree):
            if (isinstance(node, ast.If) and isinstance(node.test, ast.Name)
                    and node.test.id == 'TYPE_CHECKING'):
                skip.update(id(n) for n in ast.walk(node))
    found = set()
    for node in ast.walk(tree):
        if id(node) in skip:
            continue
        if isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module:
            names = [node.module + '.' + alias.name for alias in node.names]
        else:
            continue
        for name in names:
            if name.startswith('curve_formation.core.'):
                parts = name.split('.')[2:]
                found.add(('core', '.'.join(parts[:2])))
            elif name.startswith('curve_formation'):
                found.add(('package', name))
            else:
                found.add(('other', name.split('.')[0]))
    return found


@pytest.mark.parametrize('name', sorted(modules()))
def test_a_core_module_imports_nothing_from_a_layer_above_its_own(name):
    layer = LAYERS.index(name.split('.')[0])
    above = sorted(target for kind, target in imported(modules()[name])
                   if kind == 'core' and LAYERS.index(target.split('.')[0]) > layer)
    assert not above, f'{name} ({LAYERS[layer]}) imports from above: {above}'
    outside = sorted(target for kind, target in imported(modules()[name]) if kind == 'package')
    assert not outside, f'{name} imports from outside the core: {outside}'


@pytest.mark.parametrize('name', sorted(n for n in modules() if n.split('.')[0] in PURE))
def test_a_pure_core_module_imports_only_numpy_scipy_and_numba(name):
    third_party = {target for kind, target in imported(modules()[name])
                   if kind == 'other' and target not in sys.stdlib_module_names}
    assert third_party <= PURE_THIRD_PARTY, f'{name} imports {sorted(third_party)}'


def test_core_modules_import_each_other_without_a_cycle():
    graph = {name: {t for k, t in imported(path, runtime_only=True) if k == 'core'}
             for name, path in modules().items()}
    done, path = set(), []

    def visit(name):
        if name in path:
            raise AssertionError('import cycle: ' + ' -> '.join(path[path.index(name):]
                                                                + [name]))
        if name in done:
            return
        path.append(name)
        for target in sorted(graph.get(name, ())):
            visit(target)
        path.pop()
        done.add(name)

    for name in sorted(graph):
        visit(name)


@pytest.mark.parametrize('name', sorted(modules()))
def test_no_core_file_is_over_450_lines(name):
    lines = len(modules()[name].read_text().splitlines())
    assert lines <= MAX_LINES, f'{name}: {lines} lines'


def test_every_core_folder_is_a_layer():
    folders = {p.name for p in CORE.iterdir() if p.is_dir() and p.name != '__pycache__'}
    assert folders == set(LAYERS)
    assert not [p.name for p in CORE.glob('*.py') if p.name != '__init__.py']
