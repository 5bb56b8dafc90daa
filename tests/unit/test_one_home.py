"""One home per fact: topic names, QoS profiles and atmospheric pressure are defined once.

Scans the source of every package for a topic name spelled as a string literal, a
``QoSProfile(...)`` built outside the interface module, and the standard atmosphere written
as a number, outside their one home (``valve_model_pkg/interface`` and
``valve_model_pkg/model/constants.py``). Docstrings and comments are prose, not facts, and
are not scanned.
"""
from __future__ import annotations

import ast
from pathlib import Path

import pytest

from suite_paths import REPO_ROOT

import valve_model_pkg.interface as interface

PACKAGES = ('valve_model_pkg', 'valve_driver_pkg', 'valve_bringup')
HOME = {
    REPO_ROOT / 'valve_model_pkg' / 'valve_model_pkg' / 'interface' / '__init__.py',
    REPO_ROOT / 'valve_model_pkg' / 'valve_model_pkg' / 'interface' / 'ros.py',
    REPO_ROOT / 'valve_model_pkg' / 'valve_model_pkg' / 'model' / 'constants.py',
}
# The recorder subscribes to any topic with the QoS its publishers offer (read from the
# graph): that profile is computed per topic, it is not one of the suite's profiles.
QOS_ALLOWED = {REPO_ROOT / 'valve_model_pkg' / 'valve_model_pkg' / 'nodes' / 'recorder_node.py'}
#: Every topic name the interface defines (SUITE_TOPICS and every TOPIC_* constant), as a
#: literal would spell it: a relative name with or without the leading slash, an absolute
#: one ('/clock') only with it ('clock' alone is a word, not a topic).
_NAMES = set(interface.SUITE_TOPICS) | {
    getattr(interface, n) for n in dir(interface) if n.startswith('TOPIC_')}
TOPIC_SPELLINGS = {name for name in _NAMES} | {
    '/' + name for name in _NAMES if not name.startswith('/')}


def _source_files() -> list[Path]:
    files = []
    for pkg in PACKAGES:
        root = REPO_ROOT / pkg
        if root.is_dir():
            files += [p for p in sorted(root.rglob('*.py')) if p not in HOME]
    return files


def _docstring_nodes(tree: ast.AST) -> set[int]:
    ids = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)):
            body = getattr(node, 'body', [])
            if body and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant):
                ids.add(id(body[0].value))
    return ids


def _violations(path: Path) -> list[str]:
    tree = ast.parse(path.read_text(encoding='utf-8'), filename=str(path))
    docstrings = _docstring_nodes(tree)
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Constant) and id(node) not in docstrings:
            value = node.value
            if isinstance(value, str) and value in TOPIC_SPELLINGS:
                found.append(f'{path.name}:{node.lineno}: topic name {value!r}')
            if isinstance(value, (int, float)) and not isinstance(value, bool) \
                    and abs(abs(float(value)) - 101_325.0) < 1.0:
                found.append(f'{path.name}:{node.lineno}: atmospheric pressure {value!r}')
        if isinstance(node, ast.Call) and path not in QOS_ALLOWED:
            func = node.func
            name = func.id if isinstance(func, ast.Name) else getattr(func, 'attr', '')
            if name == 'QoSProfile':
                found.append(f'{path.name}:{node.lineno}: QoSProfile built outside interface')
    return found


def test_the_scan_sees_the_packages() -> None:
    assert len(_source_files()) > 40


def test_the_scan_finds_a_planted_violation(tmp_path: Path) -> None:
    planted = tmp_path / 'planted.py'
    planted.write_text('"""doc valve/state"""\nT = "valve/state"\nP = 101325.0\n'
                       'q = QoSProfile(depth=1)\n', encoding='utf-8')
    assert len(_violations(planted)) == 3


@pytest.mark.parametrize('path', _source_files(), ids=lambda p: str(p.relative_to(REPO_ROOT)))
def test_facts_are_not_redefined(path: Path) -> None:
    assert _violations(path) == []
