"""The package graph is the layering: read from the imports, it has no cycle.

    valve_msgs <- valve_model_pkg <- valve_driver_pkg <- valve_bringup

A package may use only the packages below it (to its left): the model never imports the
driver or the bringup package, the driver never imports the bringup package. Every import
counts, also the lazy ones inside functions, and so do the launch files' references to
another package's share directory or executables (``FindPackageShare('pkg')``,
``Node(package='pkg', ...)``).
"""
from __future__ import annotations

import ast
from pathlib import Path

import pytest

from suite_paths import REPO_ROOT

#: The layers, bottom first.
LAYERS = ('valve_msgs', 'valve_model_pkg', 'valve_driver_pkg', 'valve_bringup')
ALLOWED = {pkg: set(LAYERS[:i + 1]) for i, pkg in enumerate(LAYERS)}


def _python_files(package: str) -> list[Path]:
    root = REPO_ROOT / package
    return sorted(p for p in root.rglob('*.py')
                  if '__pycache__' not in p.parts and 'test' not in p.relative_to(root).parts)


def _suite_packages_named(path: Path) -> set[str]:
    """Suite packages a file imports (anywhere in it) or names in a launch description."""
    tree = ast.parse(path.read_text(encoding='utf-8'), filename=str(path))
    named: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            named.update(alias.name.split('.')[0] for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            named.add(node.module.split('.')[0])
        elif (isinstance(node, ast.Call) and path.name.endswith('.launch.py')):
            # FindPackageShare('pkg'), FindPackagePrefix('pkg'), Node(package='pkg')
            args = list(node.args) + [k.value for k in node.keywords
                                      if k.arg in ('package', 'package_name')]
            named.update(a.value for a in args
                         if isinstance(a, ast.Constant) and isinstance(a.value, str))
    return named & set(LAYERS)


def package_graph() -> dict[str, set[str]]:
    """Package -> the other suite packages it uses, read from its files."""
    graph: dict[str, set[str]] = {}
    for pkg in LAYERS:
        used: set[str] = set()
        for path in _python_files(pkg):
            used |= _suite_packages_named(path)
        graph[pkg] = used - {pkg}
    return graph


def _cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """A cycle of the graph as a list of packages, or None."""
    state: dict[str, int] = {}

    def visit(pkg: str, path: list[str]) -> list[str] | None:
        state[pkg] = 1
        for dep in sorted(graph.get(pkg, ())):
            if state.get(dep) == 1:
                return path + [pkg, dep]
            if dep not in state and (found := visit(dep, path + [pkg])):
                return found
        state[pkg] = 2
        return None

    for pkg in graph:
        if pkg not in state and (found := visit(pkg, [])):
            return found
    return None


def test_every_package_is_read() -> None:
    for pkg in LAYERS[1:]:  # valve_msgs has no Python
        assert _python_files(pkg), f'no Python files found for {pkg}'


@pytest.mark.parametrize('package', LAYERS)
def test_a_package_uses_only_the_packages_below_it(package: str) -> None:
    offending = {}
    for path in _python_files(package):
        above = _suite_packages_named(path) - ALLOWED[package]
        if above:
            offending[str(path.relative_to(REPO_ROOT))] = sorted(above)
    assert not offending, f'{package} uses packages above it: {offending}'


def test_the_package_graph_has_no_cycle() -> None:
    graph = package_graph()
    assert _cycle(graph) is None, f'import cycle: {" -> ".join(_cycle(graph))}'
    # and it is the intended one: bringup on top, using both model and driver
    assert graph['valve_bringup'] >= {'valve_model_pkg', 'valve_driver_pkg'}
    assert 'valve_model_pkg' in graph['valve_driver_pkg']


def test_the_cycle_finder_finds_a_cycle() -> None:
    assert _cycle({'a': {'b'}, 'b': {'c'}, 'c': {'a'}}) is not None
    assert _cycle({'a': {'b'}, 'b': set()}) is None


def test_the_package_xml_dependencies_follow_the_same_layers() -> None:
    import xml.etree.ElementTree as ET
    for i, pkg in enumerate(LAYERS):
        root = ET.parse(REPO_ROOT / pkg / 'package.xml').getroot()
        deps = {e.text.strip() for e in root if e.tag.endswith('depend') and e.text}
        assert not deps & set(LAYERS[i + 1:]), f'{pkg}/package.xml depends on a package above'
