"""Files a reader can hold and modules that depend one way (issue 33, item 4).

- No Python file of a package's code (``abp_*/abp_*/``) is longer than 600 lines; the
  benchmarks (``abp_bench``) are exempt, as are tests.
- No import cycle between the modules of one package. Every import counts, wherever it
  sits (a function-local import hides a cycle from the interpreter, not from a reader):
  ``import pkg.mod``, ``from pkg.mod import x``, ``from pkg import mod``, ``from . import mod``,
  ``from .mod import x``. An import of a name the package's ``__init__`` defines is an edge
  to ``__init__``.

Static (AST) scan of the sources: no ROS graph needed.
"""

import ast
import pathlib

import pytest

REPO = pathlib.Path(__file__).resolve().parent.parent
MAX_LINES = 600
LENGTH_EXEMPT = {'abp_bench'}  # benchmarks
PACKAGES = sorted(p for p in REPO.glob('abp_*/abp_*') if (p / '__init__.py').is_file())


def module_name(package_dir, path):
    """Dotted name of ``path`` inside the package at ``package_dir`` (``pkg.sub.mod``)."""
    parts = list(path.relative_to(package_dir.parent).with_suffix('').parts)
    if parts[-1] == '__init__':
        parts.pop()
    return '.'.join(parts)


def package_modules(package_dir):
    return {module_name(package_dir, p): p for p in sorted(package_dir.rglob('*.py'))}


def resolve_relative(importer, is_init, level, module):
    """Absolute name of ``from <level dots><module> import ...`` written in ``importer``."""
    base = importer.split('.')
    if not is_init:
        base = base[:-1]  # a module's own package
    base = base[:len(base) - (level - 1)] if level > 1 else base
    return '.'.join(base + ([module] if module else []))


def imported_modules(name, path, modules):
    """The package's own modules that the module ``name`` (file ``path``) imports."""
    is_init = path.name == '__init__.py'
    found = set()

    def add(target):
        # The longest prefix that is a module of the package: `pkg.mod.Class` -> `pkg.mod`.
        parts = target.split('.')
        while parts:
            candidate = '.'.join(parts)
            if candidate in modules:
                found.add(candidate)
                return
            parts.pop()

    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            for alias in node.names:
                add(alias.name)
        elif isinstance(node, ast.ImportFrom):
            base = (resolve_relative(name, is_init, node.level, node.module)
                    if node.level else node.module)
            for alias in node.names:
                submodule = f'{base}.{alias.name}'
                add(submodule if submodule in modules else base)
    found.discard(name)
    return found


def import_graph(package_dir):
    modules = package_modules(package_dir)
    return {name: imported_modules(name, path, modules) for name, path in modules.items()}


def find_cycle(graph):
    """One import cycle as a path ``[a, b, ..., a]``, or None (depth-first search)."""
    state = {}  # module -> 'open' while on the stack, 'done' after

    def visit(module, stack):
        state[module] = 'open'
        stack.append(module)
        for target in sorted(graph.get(module, ())):
            if state.get(target) == 'open':
                return stack[stack.index(target):] + [target]
            if target not in state:
                cycle = visit(target, stack)
                if cycle:
                    return cycle
        stack.pop()
        state[module] = 'done'
        return None

    for module in sorted(graph):
        if module not in state:
            cycle = visit(module, [])
            if cycle:
                return cycle
    return None


def test_cycle_finder_reports_the_path():
    """The checker itself: it must see a cycle closed through relative, package and
    function-local imports, and pass a graph without one."""
    assert find_cycle({'p.a': {'p.b'}, 'p.b': {'p.c'}, 'p.c': {'p.a'}}) == \
        ['p.a', 'p.b', 'p.c', 'p.a']
    assert find_cycle({'p.a': {'p.b'}, 'p.b': {'p.c'}, 'p.c': set()}) is None


def test_import_forms_resolve(tmp_path):
    package = tmp_path / 'pkg'
    package.mkdir()
    (package / '__init__.py').write_text('from .leaf import VALUE\n')
    (package / 'leaf.py').write_text('VALUE = 1\n')
    (package / 'a.py').write_text('from . import b\n')
    (package / 'b.py').write_text('import pkg.c\n')
    (package / 'c.py').write_text('def f():\n    from pkg.d import g\n    return g\n')
    (package / 'd.py').write_text('from pkg import a\nfrom pkg import VALUE\n')
    graph = import_graph(package)
    assert graph == {'pkg': {'pkg.leaf'}, 'pkg.leaf': set(), 'pkg.a': {'pkg.b'},
                     'pkg.b': {'pkg.c'}, 'pkg.c': {'pkg.d'}, 'pkg.d': {'pkg.a', 'pkg'}}
    assert find_cycle(graph) == ['pkg.a', 'pkg.b', 'pkg.c', 'pkg.d', 'pkg.a']


@pytest.mark.parametrize('package_dir', PACKAGES, ids=lambda p: p.name)
def test_no_import_cycle_between_modules(package_dir):
    cycle = find_cycle(import_graph(package_dir))
    assert cycle is None, f'{package_dir.name}: import cycle ' + ' -> '.join(cycle)


@pytest.mark.parametrize('package_dir', [p for p in PACKAGES if p.name not in LENGTH_EXEMPT],
                         ids=lambda p: p.name)
def test_no_file_over_600_lines(package_dir):
    long_files = {str(p.relative_to(REPO)): n for p in sorted(package_dir.rglob('*.py'))
                  if (n := len(p.read_text().splitlines())) > MAX_LINES}
    assert not long_files, f'files over {MAX_LINES} lines (split them at their seams): {long_files}'
