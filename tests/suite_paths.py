"""Paths and entry points of the repository for tests (a module of its own: `conftest`
names are ambiguous)."""
from __future__ import annotations

import ast
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parents[1]
#: The ament_python packages, each with a setup.py that declares its console scripts.
PYTHON_PACKAGES = ('valve_model_pkg', 'valve_driver_pkg', 'valve_bringup')


def console_scripts() -> list[str]:
    """Every console script of every package, from the entry_points in its setup.py."""
    names = []
    for package in PYTHON_PACKAGES:
        tree = ast.parse((REPO_ROOT / package / 'setup.py').read_text(encoding='utf-8'))
        for node in ast.walk(tree):
            if isinstance(node, ast.Dict):
                for key, value in zip(node.keys, node.values):
                    if isinstance(key, ast.Constant) and key.value == 'console_scripts':
                        names += [e.value.split('=')[0].strip() for e in value.elts]
    return names
