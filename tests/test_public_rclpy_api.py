"""Only rclpy's public API: no abp source reaches into rclpy's private attributes.

rclpy's private names change without notice between releases (a managed node once diffed
the node's `_publishers` lists; the node runner once replaced the executor's
`_take_subscription`), so a use of one can break silently on an rclpy update.

The private names are read from the installed rclpy's own source: every `_name` (not a
dunder) that an rclpy class defines as a method, class attribute or instance attribute
(`self._name = ...`). The abp sources (every package, its tests, tests/, scripts/; not
this file, whose samples are what it looks for) are parsed with `ast` and a use is
flagged when it is:
- `x._name` with `x` not `self`/`cls` and `_name` private in any rclpy class;
- `self._name` / `cls._name` in an abp class whose instances are rclpy objects (it
  derives from an rclpy class, directly or through abp classes, or is a mixin of such a
  class) and `_name` private in one of those rclpy classes: a subclass that reads or
  sets one uses rclpy's internals as surely as an outside caller (and one that merely
  reuses the name clobbers rclpy's attribute);
- a string constant equal to one of rclpy's private names (getattr/setattr by name);
- any of these inside a string that is a Python script using rclpy (a test's node).

`ALLOWED` lists the uses that must stay, each with its reason; it is empty.
"""

import ast
import functools
import pathlib
import re

import pytest

rclpy = pytest.importorskip('rclpy')

REPO = pathlib.Path(__file__).resolve().parents[1]
RCLPY_DIR = pathlib.Path(rclpy.__file__).resolve().parent
SKIPPED_DIRS = {'.venv', 'build', 'install', 'log', 'vendor', '.git', '__pycache__', 'docker'}

# (path relative to the repo, line text stripped) -> why it must stay. Keep it empty.
ALLOWED = {}


def is_private(name):
    return name.startswith('_') and not (name.startswith('__') and name.endswith('__'))


def private_names_in(body):
    """The private names a class body defines: methods, class attributes, `self._x = ...`."""
    names = set()
    for item in body:
        if isinstance(item, (ast.FunctionDef, ast.AsyncFunctionDef)):
            names.add(item.name)
        elif isinstance(item, ast.Assign):
            names.update(t.id for t in item.targets if isinstance(t, ast.Name))
        elif isinstance(item, ast.AnnAssign) and isinstance(item.target, ast.Name):
            names.add(item.target.id)
    for node in ast.walk(ast.Module(body=list(body), type_ignores=[])):
        targets = []
        if isinstance(node, ast.Assign):
            targets = node.targets
        elif isinstance(node, (ast.AnnAssign, ast.AugAssign)):
            targets = [node.target]
        names.update(t.attr for t in targets if isinstance(t, ast.Attribute)
                     and isinstance(t.value, ast.Name) and t.value.id == 'self')
    return {name for name in names if is_private(name)}


@functools.lru_cache(maxsize=1)
def rclpy_names():
    """(every private name rclpy defines, {rclpy class name: private names of the class
    and of its rclpy bases})."""
    own, bases = {}, {}
    for path in RCLPY_DIR.rglob('*.py'):
        for node in ast.walk(ast.parse(path.read_text(encoding='utf-8'))):
            if isinstance(node, ast.ClassDef):
                own.setdefault(node.name, set()).update(private_names_in(node.body))
                bases.setdefault(node.name, set()).update(
                    filter(None, map(last_name, node.bases)))

    def inherited(name, seen=()):
        names = set(own.get(name, ()))
        for base in bases.get(name, ()):
            if base not in seen:
                names |= inherited(base, (*seen, name))
        return names

    return set().union(*own.values()), {name: inherited(name) for name in own}


def abp_sources():
    """Every abp Python file but this one (its samples are what it looks for)."""
    for path in sorted(REPO.rglob('*.py')):
        if (not SKIPPED_DIRS.intersection(path.relative_to(REPO).parts)
                and path != pathlib.Path(__file__).resolve()):
            yield path


def last_name(expression):
    """`rclpy.node.Node` -> 'Node'; `Node` -> 'Node'; anything else -> None."""
    if isinstance(expression, ast.Attribute):
        return expression.attr
    return expression.id if isinstance(expression, ast.Name) else None


def rclpy_imported_names(tree):
    """Names a module imports from rclpy (`from rclpy.node import Node` -> Node)."""
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and (node.module or '').split('.')[0] == 'rclpy':
            names.update(alias.asname or alias.name for alias in node.names)
    return names


def rclpy_ancestors(trees, rclpy_classes):
    """{abp class name: the rclpy classes its instances are}: those it derives from,
    directly or through abp classes, and, for a mixin, those of the classes it is mixed
    into (its `self` is theirs)."""
    parents = {}   # abp class -> base names ('rclpy:Node' for an rclpy class)
    for tree in trees.values():
        from_rclpy = rclpy_imported_names(tree) | {'rclpy'}
        for node in ast.walk(tree):
            if isinstance(node, ast.ClassDef):
                parents.setdefault(node.name, set())
                for base in node.bases:
                    root = base
                    while isinstance(root, ast.Attribute):
                        root = root.value
                    last = last_name(base)
                    if (isinstance(root, ast.Name) and root.id in from_rclpy
                            and last in rclpy_classes):
                        parents.setdefault(node.name, set()).add(f'rclpy:{last}')
                    elif last is not None:
                        parents.setdefault(node.name, set()).add(last)
    ancestors = {name: {b[6:] for b in bases if b.startswith('rclpy:')}
                 for name, bases in parents.items()}
    grew = True
    while grew:
        grew = False
        for name, bases in parents.items():
            for base in bases & ancestors.keys():
                inherited = ancestors[base] - ancestors[name]     # from an abp base
                mixed_in = ancestors[name] - ancestors[base]      # into an abp mixin
                if inherited or mixed_in:
                    ancestors[name] |= inherited
                    ancestors[base] |= mixed_in
                    grew = True
    return {name: found for name, found in ancestors.items() if found}


def private_uses(source, tree, private, class_private):
    """(line, text, reason) for each use of an rclpy private name in one module's source.
    `class_private`: {abp class: the rclpy private names its instances have}. A string
    that is a Python script using rclpy (a test's node script) is scanned too."""
    lines = source.splitlines()
    found = []

    def flag(node, reason):
        found.append((node.lineno, lines[node.lineno - 1].strip(), reason))

    def visit(node, own_private):
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.ClassDef):
                visit(child, class_private.get(child.name, set()))
                continue
            if isinstance(child, ast.Attribute):
                owner = child.value
                is_self = isinstance(owner, ast.Name) and owner.id in ('self', 'cls')
                if not is_self and child.attr in private:
                    flag(child, f'`.{child.attr}` is private in rclpy')
                elif is_self and child.attr in own_private:
                    flag(child, f'`self.{child.attr}` in a subclass of an rclpy class is '
                                "rclpy's private attribute")
            elif (isinstance(child, ast.Constant) and isinstance(child.value, str)
                  and child.value in private):
                flag(child, f"'{child.value}' names a private rclpy attribute")
            elif isinstance(child, ast.Constant) and is_rclpy_script(child.value):
                script = child.value
                found.extend(
                    (child.lineno + line - 1, text, f'{reason}, in a script')
                    for line, text, reason in private_uses(
                        script, ast.parse(script), private, script_class_private(script)))
            visit(child, own_private)

    visit(tree, set())
    return found


def is_rclpy_script(value):
    if not isinstance(value, str) or 'rclpy' not in value or '\n' not in value:
        return False
    try:
        ast.parse(value)
    except SyntaxError:
        return False
    return True


def script_class_private(script):
    private, rclpy_private = rclpy_names()
    ancestors = rclpy_ancestors({'script': ast.parse(script)}, rclpy_private.keys())
    return {name: set().union(*(rclpy_private[a] for a in found))
            for name, found in ancestors.items()}


def find_private_uses():
    private, rclpy_private = rclpy_names()
    trees = {path: ast.parse(path.read_text(encoding='utf-8'), str(path))
             for path in abp_sources()}
    ancestors = rclpy_ancestors(trees, rclpy_private.keys())
    class_private = {name: set().union(*(rclpy_private[a] for a in found))
                     for name, found in ancestors.items()}
    uses = []
    for path, tree in trees.items():
        relative = str(path.relative_to(REPO))
        source = path.read_text(encoding='utf-8')
        for line, text, reason in private_uses(source, tree, private, class_private):
            if (relative, text) not in ALLOWED:
                uses.append(f'{relative}:{line}: {text}  ({reason})')
    return uses, private, ancestors


def test_the_scanner_knows_rclpy_private_names_and_our_node_classes():
    """The rule is only as good as its inputs: rclpy's internals that abp once used are in
    the set, and the managed node base class is seen as an rclpy subclass."""
    _, private, ancestors = find_private_uses()
    assert {'_publishers', '_parameters', '_take_subscription', '_state_machine',
            '_parameter_overrides'} <= private
    assert 'LifecycleNode' in ancestors['ManagedNode']
    assert 'LifecycleNode' in ancestors['BeliefNode']
    assert 'LifecycleNode' in ancestors['EntityRegistry']     # a mixin of ManagedNode
    assert 'Node' in ancestors['LifecycleManager']
    assert 'Node' not in ancestors.get('ParamSpec', ())


def test_the_scanner_flags_private_access():
    script = (
        'from rclpy.node import Node\n'
        'class Listener(Node):\n'
        '    def f(self):\n'
        '        self._parameters\n')
    source = (
        'from rclpy.lifecycle import LifecycleNode\n'
        'class Mine(LifecycleNode):\n'
        '    def f(self, executor):\n'
        '        self._state_machine\n'
        '        executor._take_subscription = None\n'
        "        getattr(self, '_publishers')\n"
        'class Plain:\n'
        '    def f(self):\n'
        '        self._publishers = []\n'
        f'SCRIPT = """\n{script}"""\n')
    private, rclpy_private = rclpy_names()
    uses = private_uses(source, ast.parse(source), private,
                        {'Mine': rclpy_private['LifecycleNode']})
    assert [line for line, _, _ in uses] == [4, 5, 6, 10 + 4]


def test_no_abp_source_uses_a_private_rclpy_attribute():
    uses, _, _ = find_private_uses()
    assert not uses, 'private rclpy attributes used:\n' + '\n'.join(uses)


def test_every_allowed_use_has_a_reason_and_still_exists():
    for (relative, text), reason in ALLOWED.items():
        assert len(reason) > 20, f'{relative}: {text}: give the reason'
        assert text in (REPO / relative).read_text(encoding='utf-8'), \
            f'{relative}: allow-listed `{text}` is gone; drop it from ALLOWED'
        assert re.search(r'\._', text) or "'_" in text
