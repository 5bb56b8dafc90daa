"""Every unit test file belongs to exactly one package (what `colcon test` runs per package)."""
from __future__ import annotations

from package_tests import PACKAGES, UNIT_DIR, unit_tests_of


def test_every_unit_test_file_belongs_to_exactly_one_package() -> None:
    owners: dict[str, list[str]] = {}
    for package in PACKAGES:
        for path in unit_tests_of(package):
            owners.setdefault(path.name, []).append(package)
    files = {p.name for p in UNIT_DIR.glob('test_*.py')}
    assert set(owners) == files, sorted(files - set(owners))
    shared = {name: pkgs for name, pkgs in owners.items() if len(pkgs) != 1}
    assert not shared, shared


def test_each_package_has_unit_tests_and_the_patterns_match_files() -> None:
    for package in PACKAGES:
        assert unit_tests_of(package), f'no unit tests for {package}'
    assert unit_tests_of('valve_bringup')[0].parent == UNIT_DIR
    assert any(p.name == 'test_package_graph.py' for p in unit_tests_of('valve_bringup'))
    assert any(p.name.startswith('test_can_') for p in unit_tests_of('valve_driver_pkg'))
    assert any(p.name.startswith('test_model_') for p in unit_tests_of('valve_model_pkg'))
