"""The README names only what exists, and names every console script.

Read as a newcomer would follow it: every relative link resolves (a file, and a heading
for a ``#fragment``), every repository path in backticks exists, every ``make`` target is
in the Makefile, every command a code block runs is a console script of the three
packages' setup.py files (or a known tool), and every console script appears. The
generated pages are what their generators make of the recorded figures: no number on
them is typed by hand.
"""
from __future__ import annotations

import importlib.util
import json
import re
import shlex
import sys
from pathlib import Path

import pytest

from suite_paths import PYTHON_PACKAGES, REPO_ROOT, console_scripts

README = REPO_ROOT / 'README.md'
#: Commands a code block may run that are not the suite's console scripts.
TOOLS = {'make', 'python', 'source', 'ros2', 'rosdep', 'colcon', 'docker', 'cd'}
#: Top-level entries of the repository that a path in the README may start with.
TOP_LEVEL = {p.name for p in REPO_ROOT.iterdir()
             if not p.name.startswith('.') and p.name not in ('demo_output', 'out')}


def make_targets() -> set[str]:
    text = (REPO_ROOT / 'Makefile').read_text(encoding='utf-8')
    return set(re.findall(r'^([A-Za-z][\w-]*):(?!=)', text, flags=re.MULTILINE))


def code_blocks(text: str) -> list[str]:
    """The lines of every fenced ``bash`` block."""
    lines = []
    for block in re.findall(r'```bash\n(.*?)```', text, flags=re.DOTALL):
        lines += [line for line in block.splitlines() if line.strip()]
    return lines


def inline_code(text: str) -> list[str]:
    """Every `inline code` span outside fenced blocks."""
    prose = re.sub(r'```.*?```', '', text, flags=re.DOTALL)
    return re.findall(r'`([^`\n]+)`', prose)


def command_words(line: str) -> list[str]:
    """``['make', 'demo']`` of ``BACKEND=can make demo   # comment``: the words run."""
    words = shlex.split(line, comments=True)
    while words and re.fullmatch(r'[A-Z_][A-Z0-9_]*=.*', words[0]):
        words.pop(0)          # environment assignments before the command
    return words


def heading_anchors(path: Path) -> set[str]:
    """GitHub's anchors of the Markdown headings of ``path``."""
    anchors = set()
    text = re.sub(r'```.*?```', '', path.read_text(encoding='utf-8'), flags=re.DOTALL)
    for title in re.findall(r'^#{1,6}\s+(.*?)\s*$', text, flags=re.MULTILINE):
        slug = re.sub(r'[^\w\- ]', '', title.lower().replace('`', '')).replace(' ', '-')
        anchors.add(slug)
    return anchors


def links(path: Path) -> list[str]:
    text = re.sub(r'```.*?```', '', path.read_text(encoding='utf-8'), flags=re.DOTALL)
    return re.findall(r'\]\(([^)\s]+)\)', text)


def _relative(target: str) -> bool:
    return not re.match(r'[a-z]+:', target) and not target.startswith('#')


# --- the checks -----------------------------------------------------------------------

def test_the_readme_is_a_guide_not_a_notebook() -> None:
    text = README.read_text(encoding='utf-8')
    assert len(text.splitlines()) <= 250
    assert not re.search(r'\b20\d\d-\d\d-\d\d\b', text), 'dates belong on generated pages'
    assert '| --- |' not in text and '|---|' not in text, 'tables of figures belong in docs/'


@pytest.mark.parametrize('page', [README, *sorted((REPO_ROOT / 'docs').glob('*.md')),
                                  REPO_ROOT / 'valve_driver_pkg' / 'README.md'],
                         ids=lambda p: str(p.relative_to(REPO_ROOT)))
def test_every_relative_link_resolves(page: Path) -> None:
    broken = []
    for target in filter(_relative, links(page)):
        file_part, _, fragment = target.partition('#')
        resolved = (page.parent / file_part).resolve() if file_part else page
        if not resolved.exists():
            broken.append(f'{target} (no {resolved})')
        elif fragment and resolved.suffix == '.md' and fragment not in heading_anchors(resolved):
            broken.append(f'{target} (no heading #{fragment})')
    assert not broken, f'{page.name}: ' + '; '.join(broken)


def test_every_repository_path_in_backticks_exists() -> None:
    text = README.read_text(encoding='utf-8')
    missing = []
    for span in inline_code(text) + [w for line in code_blocks(text)
                                     for w in command_words(line)]:
        for token in span.split():
            first = token.split('/')[0]
            if '/' not in token or first not in TOP_LEVEL:
                continue
            path = token.rstrip('/.,;:')
            if not (any(REPO_ROOT.glob(path)) if '*' in path else (REPO_ROOT / path).exists()):
                missing.append(token)
    assert not missing, f'the README names paths that do not exist: {missing}'


def test_every_command_the_readme_runs_exists() -> None:
    text = README.read_text(encoding='utf-8')
    scripts, targets = set(console_scripts()), make_targets()
    unknown = []
    for line in code_blocks(text):
        words = command_words(line)
        if not words:
            continue
        if words[0] == 'make':
            unknown += [f'make {w}' for w in words[1:2] if '=' not in w and w not in targets]
        elif words[0] == 'python' and words[1:2] == ['-m']:
            module = REPO_ROOT / words[2].replace('.', '/')
            if not (module.with_suffix('.py').exists() or (module / '__main__.py').exists()):
                unknown.append(line)
        elif words[0] == 'python':
            if not (REPO_ROOT / words[1]).exists():
                unknown.append(line)
        elif words[0] not in TOOLS and words[0] not in scripts:
            unknown.append(words[0])
    for span in inline_code(text):
        words = span.split()
        if words[0] == 'make' and len(words) > 1 and '=' not in words[1] \
                and words[1] not in targets:
            unknown.append(span)
        for word in words:
            if re.fullmatch(r'valve_[a-z_]+', word) and word not in scripts \
                    and word not in ('valve_msgs', *PYTHON_PACKAGES):
                unknown.append(word)
    assert not unknown, f'the README runs commands that do not exist: {unknown}'


def test_every_console_script_appears_in_the_readme() -> None:
    named = set(inline_code(README.read_text(encoding='utf-8')))
    named |= {w for line in code_blocks(README.read_text(encoding='utf-8'))
              for w in command_words(line)[:1]}
    missing = sorted(set(console_scripts()) - named)
    assert not missing, f'console scripts the README does not name: {missing}'


def _module(path: Path):  # noqa: ANN202 - a module
    name = f'benchmarks_{path.stem}'
    if name not in sys.modules:
        spec = importlib.util.spec_from_file_location(name, path)
        sys.modules[name] = importlib.util.module_from_spec(spec)   # dataclasses look it up
        spec.loader.exec_module(sys.modules[name])
    return sys.modules[name]


def test_the_benchmarks_page_is_generated_from_the_results() -> None:
    collect = _module(REPO_ROOT / 'benchmarks' / 'collect.py')
    summary = json.loads((REPO_ROOT / 'benchmarks' / 'results.json').read_text())
    page = (REPO_ROOT / 'docs' / 'benchmarks.md').read_text(encoding='utf-8')
    assert page == collect.page(summary), 'regenerate: python benchmarks/collect.py'
    for line in page.splitlines():
        if line.startswith('| ') and not line.startswith('| benchmark'):
            assert '|  |' not in line and '| |' not in line, f'empty cell: {line}'


def test_the_demo_page_tables_are_generated_from_the_runs() -> None:
    demo_page = _module(REPO_ROOT / 'benchmarks' / 'demo_page.py')
    runs_file = REPO_ROOT / 'benchmarks' / 'demo_runs.json'
    runs = json.loads(runs_file.read_text()) if runs_file.exists() else []
    page = (REPO_ROOT / 'docs' / 'demo.md').read_text(encoding='utf-8')
    assert demo_page.section(runs) in page, \
        'regenerate: python benchmarks/demo_page.py --page-only'
