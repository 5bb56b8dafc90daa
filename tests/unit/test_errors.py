"""One exception tree per package: every error valve_model_pkg raises on purpose is a
ValveModelError, defined in valve_model_pkg/errors.py, and each leaf is also a built-in."""
from __future__ import annotations

import ast
import inspect

import pytest

from suite_paths import REPO_ROOT

import valve_model_pkg.errors as errors
from valve_model_pkg.errors import ValveModelError

PKG = REPO_ROOT / 'valve_model_pkg' / 'valve_model_pkg'
PUBLIC = [getattr(errors, name) for name in errors.__all__]
SUBSYSTEM_BASES = {errors.MapError, errors.RecordingError, errors.IdentificationError,
                   errors.FleetError, ValveModelError, errors.StartupRefused}


@pytest.mark.parametrize('cls', PUBLIC, ids=lambda c: c.__name__)
def test_every_error_is_beneath_the_root(cls: type) -> None:
    assert issubclass(cls, ValveModelError)


@pytest.mark.parametrize('cls', [c for c in PUBLIC if c not in SUBSYSTEM_BASES],
                         ids=lambda c: c.__name__)
def test_every_leaf_is_also_a_builtin(cls: type) -> None:
    builtins = [b for b in inspect.getmro(cls)[1:]
                if b.__module__ == 'builtins' and b not in (Exception, BaseException, object)]
    assert builtins, f'{cls.__name__} inherits no built-in error besides Exception'


def _exception_classes(path) -> list[str]:  # noqa: ANN001 - a Path
    tree = ast.parse(path.read_text(encoding='utf-8'))
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.ClassDef) and not node.name.startswith('_'):
            for base in node.bases:
                name = base.id if isinstance(base, ast.Name) else getattr(base, 'attr', '')
                if name.endswith(('Error', 'Exception', 'Refused')):
                    found.append(node.name)
    return found


def test_errors_are_defined_only_in_the_errors_module() -> None:
    elsewhere = {str(p.relative_to(PKG)): _exception_classes(p)
                 for p in sorted(PKG.rglob('*.py')) if p.name != 'errors.py' or p.parent != PKG}
    assert {k: v for k, v in elsewhere.items() if v} == {}


def test_the_tree_is_exported_whole() -> None:
    defined = {n for n, v in vars(errors).items()
               if isinstance(v, type) and issubclass(v, BaseException)
               and v.__module__ == errors.__name__}
    assert defined == set(errors.__all__)
