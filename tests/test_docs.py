"""The docs a newcomer reads hold together (issue 33, item 5).

- Every relative link and image in README.md, docs/*.md and the other Markdown files of the
  repository points to a file that exists, and a ``#anchor`` into a Markdown file to one of
  its headings (GitHub's anchors).
- The README stays a five-minute read (at most 120 lines) and names the two commands, which
  exist and are executable; CI runs the README's test command.
- Every installed executable (``install/<pkg>/lib/<pkg>/<exe>``, ``ros2 run <pkg> <exe>``)
  and module (``python -m <pkg>.<module>``) the README and docs/ name is one a package
  defines, so a command copied from the docs runs.
- docs/USAGE.md's table of ``start_graph.sh`` options lists exactly the options the script
  parses.
- docs/img/make_results_plots.py draws every plot docs/RESULTS.md shows from the figures
  RESULTS.md records.

Static reads of the Markdown files and one run of the plot script: no ROS graph needed.
"""

import pathlib
import re
import subprocess
import sys

import pytest

REPO = pathlib.Path(__file__).resolve().parent.parent
README = REPO / 'README.md'
RESULTS = REPO / 'docs' / 'RESULTS.md'
PLOT_SCRIPT = REPO / 'docs' / 'img' / 'make_results_plots.py'
README_MAX_LINES = 120
TWO_COMMANDS = ('scripts/start_graph.sh', 'scripts/test.sh')
SKIPPED_DIRS = {'.git', '.venv', 'build', 'install', 'log', 'node_modules'}

FENCE = re.compile(r'^\s*(```|~~~)')
CODE_SPAN = re.compile(r'`+[^`]*`+')
# [text](target) and ![alt](target); the target ends at whitespace (a "title") or ')'.
LINK = re.compile(r'!?\[[^\]]*\]\(\s*<?([^)\s>]+)>?(?:\s+"[^"]*")?\s*\)')
HEADING = re.compile(r'^(#{1,6})\s+(.*?)\s*#*\s*$')


def markdown_files():
    """README.md, docs/*.md and every other Markdown file the repository keeps."""
    found = []
    for path in sorted(REPO.rglob('*.md')):
        parts = path.relative_to(REPO).parts
        if SKIPPED_DIRS.intersection(parts):
            continue
        found.append(path)
    return found


def prose_lines(text):
    """The lines of ``text`` outside fenced code blocks, with inline code blanked."""
    inside = False
    for line in text.splitlines():
        if FENCE.match(line):
            inside = not inside
            continue
        if not inside:
            # Keep a code span's place (a link's text may be one) but not its brackets.
            yield CODE_SPAN.sub('code', line)


def links(path):
    """Every link target written in ``path``'s prose."""
    return [target for line in prose_lines(path.read_text(encoding='utf-8'))
            for target in LINK.findall(line)]


def github_anchor(heading):
    """The anchor GitHub gives a heading: lower case, punctuation dropped, spaces to '-'."""
    text = CODE_SPAN.sub(lambda m: m.group(0).strip('`'), heading)
    text = re.sub(r'!?\[([^\]]*)\]\([^)]*\)', r'\1', text)      # a link keeps its text
    text = re.sub(r'[^\w\- ]', '', text.lower())
    return text.replace(' ', '-')


def anchors(path):
    """The anchors of ``path``'s headings, with GitHub's -1, -2 for repeated ones."""
    seen = {}
    result = set()
    inside = False
    for line in path.read_text(encoding='utf-8').splitlines():
        if FENCE.match(line):
            inside = not inside
            continue
        match = None if inside else HEADING.match(line)
        if match:
            anchor = github_anchor(match.group(2))
            count = seen.get(anchor, 0)
            seen[anchor] = count + 1
            result.add(anchor if count == 0 else f'{anchor}-{count}')
    return result


def broken_links(path):
    """(target, why) for each relative link of ``path`` that does not resolve."""
    broken = []
    for target in links(path):
        if re.match(r'^[a-z][a-z0-9+.-]*:', target, re.IGNORECASE):
            continue  # http:, https:, mailto: ...: not a file of the repository
        file_part, _, anchor = target.partition('#')
        linked = (path.parent / file_part).resolve() if file_part else path
        if not linked.exists():
            broken.append((target, 'no such file'))
        elif anchor and linked.suffix == '.md' and anchor not in anchors(linked):
            broken.append((target, f'no heading with the anchor #{anchor} in {linked.name}'))
    return broken


def test_the_link_checker_finds_what_it_should(tmp_path):
    (tmp_path / 'other.md').write_text('# A heading, with `code`\n\n## Twice\n\n## Twice\n')
    page = tmp_path / 'page.md'
    page.write_text(
        '# Page\n\n[ok](other.md) [ok](other.md#a-heading-with-code) [ok](other.md#twice-1)\n'
        '![missing](img/none.png) [bad](other.md#nowhere) [ok](#page) [web](https://x.org)\n'
        '`[not a link](nowhere.md)`\n\n```\n[not a link either](nowhere.md)\n```\n')
    assert broken_links(page) == [
        ('img/none.png', 'no such file'),
        ('other.md#nowhere', 'no heading with the anchor #nowhere in other.md')]


@pytest.mark.parametrize('path', markdown_files(), ids=lambda p: str(p.relative_to(REPO)))
def test_every_relative_link_resolves(path):
    assert broken_links(path) == []


def test_the_readme_is_short_and_names_the_two_commands():
    text = README.read_text(encoding='utf-8')
    assert len(text.splitlines()) <= README_MAX_LINES
    for command in TWO_COMMANDS:
        assert command in text
        script = REPO / command
        assert script.is_file() and script.stat().st_mode & 0o111, command
    ci = (REPO / '.ci' / 'run').read_text(encoding='utf-8')
    assert 'scripts/test.sh' in ci


def test_the_readme_links_the_results_and_the_benchmarks():
    assert 'docs/RESULTS.md' in links(README)
    assert 'docs/BENCHMARKS.md' in links(README)


INSTALLED = re.compile(r'install/(abp_\w+)/lib/\1/(\w+)')
ROS2_RUN = re.compile(r'ros2 run (abp_\w+) (\w+)')
MODULE = re.compile(r'python -m (abp_\w+)\.(\w+)')


def entry_points(package):
    """The console scripts ``package``'s setup.py declares."""
    setup = (REPO / package / 'setup.py').read_text(encoding='utf-8')
    return set(re.findall(r"'(\w+)\s*=\s*[\w.]+:\w+'", setup))


def named_commands():
    """(doc, kind, package, name) for each executable or module the README and docs name."""
    found = set()
    for path in [README, *sorted((REPO / 'docs').glob('*.md'))]:
        text = path.read_text(encoding='utf-8')
        doc = str(path.relative_to(REPO))
        found.update((doc, 'executable', *m) for m in INSTALLED.findall(text))
        found.update((doc, 'executable', *m) for m in ROS2_RUN.findall(text))
        found.update((doc, 'module', *m) for m in MODULE.findall(text))
    return sorted(found)


def test_every_executable_and_module_the_docs_name_exists():
    named = named_commands()
    assert any(kind == 'module' for _, kind, _, _ in named)      # the patterns still match
    assert len([n for n in named if n[1] == 'executable']) > 10
    missing = []
    for doc, kind, package, name in named:
        if kind == 'executable':
            exists = (REPO / package / 'setup.py').is_file() and name in entry_points(package)
        else:
            exists = (REPO / package / package / f'{name}.py').is_file()
        if not exists:
            missing.append(f'{doc}: {kind} {package} {name}')
    assert missing == []


def test_the_usage_table_lists_exactly_the_options_start_graph_parses():
    usage = (REPO / 'docs' / 'USAGE.md').read_text(encoding='utf-8')
    table = usage.split('### Options', 1)[1].split('\n#', 1)[0]
    options = {o for line in table.splitlines() if line.startswith('| `--')
               for o in re.findall(r'`(--[a-z-]+)', line)}
    assert len(options) > 15
    script = (REPO / 'scripts' / 'start_graph.sh').read_text(encoding='utf-8')
    # The script's argument loop names each option as a case label: "--world)" or "--world|".
    parsed = set(re.findall(r'(--[a-z-]+)[)|]', script))
    assert sorted(options - parsed) == []
    assert sorted(parsed - options - {'--help'}) == []        # and the table lists them all


def test_the_results_plots_are_drawn_from_the_recorded_figures(tmp_path):
    run = subprocess.run([sys.executable, str(PLOT_SCRIPT), '--out', str(tmp_path)],
                         capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr
    drawn = sorted(p.name for p in tmp_path.glob('*.png'))
    shown = sorted(pathlib.PurePosixPath(t).name for t in links(RESULTS)
                   if t.startswith('img/results_'))
    assert drawn == shown
    for name in drawn:
        assert (REPO / 'docs' / 'img' / name).is_file(), f'{name} is not committed'
    # The script's figures are RESULTS.md's: every number it plots is written there.
    results = RESULTS.read_text(encoding='utf-8')
    numbers = re.findall(r'(?<![\w.])\d+\.\d+(?![\w.])',
                         PLOT_SCRIPT.read_text(encoding='utf-8').split('def table_ii')[0])
    missing = sorted({n for n in numbers if n not in results})
    assert missing == []
