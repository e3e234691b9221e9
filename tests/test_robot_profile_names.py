"""No uBot-6 joint, link or controller name outside abp_description (issue 36).

The robot profile (abp_description/profiles/*.yaml) is the only robot-specific input: code
elsewhere reads names from the RobotProfile it loaded. The names come from the uBot-6's
URDF itself (every <link> and <joint>) and its profile (controllers), so a part added to
the robot is covered without editing this test.

What is scanned, and the narrow exemptions:
- every Python module of the abp_* packages but abp_description: its string literals,
  including the pieces of f-strings (a piece such as '_arm_controller' that completes a
  name counts). Docstrings and comments are prose, not code: they may say "base_link"
  when they explain a frame, and are not scanned.
- the packages' YAML and launch files, and scripts/: every line not a comment.
- exempt: abp_description (the home of robot facts) and the test folders (abp_*/test,
  tests/): tests pin the uBot-6's own behaviour and may name its parts.
"""

import ast
import re
from pathlib import Path

import pytest

from abp_description.robot_profile import load_profile

REPO = Path(__file__).resolve().parent.parent
EXEMPT_PACKAGES = {'abp_description'}
TEXT_SUFFIXES = ('.yaml', '.yml', '.launch.py', '.sh', '.xml')


def robot_names():
    """Every link and joint of the default profile's URDF, and its controller names."""
    profile = load_profile()
    text = Path(profile.urdf_file()).read_text()
    names = set(re.findall(r'<(?:link|joint)\s+name="([^"]+)"', text))
    names |= {c.name for c in profile.controllers}
    return names


NAMES = robot_names()
WORD = re.compile(r'(?<![\w])(' + '|'.join(sorted(map(re.escape, NAMES), key=len,
                                                       reverse=True)) + r')(?![\w])')


def scanned_packages():
    return sorted(p for p in REPO.glob('abp_*') if p.is_dir() and p.name not in EXEMPT_PACKAGES)


def python_files():
    for package in scanned_packages():
        for path in sorted(package.rglob('*.py')):
            rel = path.relative_to(REPO)
            if 'test' in rel.parts or rel.name == 'setup.py' or \
                    any(part in ('build', 'install', 'log') for part in rel.parts):
                continue
            yield path


def _docstring_nodes(tree):
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)):
            body = node.body
            if body and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant):
                out.add(id(body[0].value))
    return out


def _completes_a_name(piece):
    """An f-string piece of two words or more that ends ('_hand_link') or starts
    ('left_hand_') a robot name; one word ('base_') is too common to tell."""
    if len([w for w in piece.split('_') if w]) < 2:
        return False
    return any(n != piece and ((piece.startswith('_') and n.endswith(piece))
                               or (piece.endswith('_') and n.startswith(piece)))
               for n in NAMES)


def literal_hits(path):
    tree = ast.parse(path.read_text(), str(path))
    docstrings = _docstring_nodes(tree)
    hits = []
    fstring_pieces = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.JoinedStr):
            for piece in node.values:
                if isinstance(piece, ast.Constant) and isinstance(piece.value, str):
                    fstring_pieces.add(id(piece))
                    if _completes_a_name(piece.value):
                        hits.append((node.lineno, piece.value))
    for node in ast.walk(tree):
        if isinstance(node, ast.Constant) and isinstance(node.value, str) \
                and id(node) not in docstrings:
            found = WORD.findall(node.value)
            if found:
                hits.append((node.lineno, ', '.join(sorted(set(found)))))
    return hits


def text_files():
    for package in scanned_packages():
        for path in sorted(package.rglob('*')):
            rel = path.relative_to(REPO)
            if path.is_file() and path.name.endswith(TEXT_SUFFIXES) and 'test' not in rel.parts:
                yield path
    yield from sorted(p for p in (REPO / 'scripts').rglob('*') if p.is_file()
                      and p.suffix in ('.sh', '.py', '.yaml', ''))


def text_hits(path):
    hits = []
    for number, line in enumerate(path.read_text(errors='replace').splitlines(), 1):
        code = line.split('#', 1)[0]
        found = WORD.findall(code)
        if found:
            hits.append((number, ', '.join(sorted(set(found)))))
    return hits


def test_the_names_come_from_the_urdf():
    # A URDF whose names cannot be read would make the scans below pass vacuously.
    assert {'base_link', 'left_hand_link', 'torso_pitch_joint', 'head_controller'} <= NAMES
    assert len(NAMES) > 30


@pytest.mark.parametrize('kind', ['python', 'text'])
def test_no_robot_name_outside_the_description_package(kind):
    files = list(python_files()) if kind == 'python' else list(text_files())
    assert files, 'nothing scanned'
    scan = literal_hits if kind == 'python' else text_hits
    found = [f'{path.relative_to(REPO)}:{line}: {what}'
             for path in files for line, what in scan(path)]
    assert not found, ('robot names outside abp_description (read them from the robot '
                       'profile instead):\n' + '\n'.join(found))


def test_the_scan_finds_a_planted_name(tmp_path):
    # The scanners themselves: a literal, an f-string piece and a YAML value are caught;
    # a docstring and a comment are not.
    module = tmp_path / 'planted.py'
    module.write_text('"""In base_link."""\n# torso_link\nA = "head_pan_joint"\n'
                      "B = f'{side}_hand_link'\n")
    assert sorted(line for line, _ in literal_hits(module)) == [3, 4]
    config = tmp_path / 'planted.yaml'
    config.write_text('# base_link here is a comment\nframe: camera_optical_frame\n')
    assert text_hits(config) == [(2, 'camera_optical_frame')]
