"""Code outside ``model/`` uses only the public names of ``valve_model_pkg.model``.

Scans (AST, no import) every Python module of the packages outside ``model/`` for:
imports of names starting with ``_`` from ``valve_model_pkg.model`` or its modules
(absolute or relative), imports of the internal ``kernel`` module, and attribute uses
``alias._name`` on an imported model module. Tests are not scanned: the kernel's own
tests check its internals on purpose.
"""
from __future__ import annotations

import ast
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
MODEL_DIR = REPO / 'valve_model_pkg' / 'valve_model_pkg' / 'model'
SKIP_PARTS = {'build', 'install', 'log', '.venv', 'tests', 'test', '__pycache__'}
#: Modules outside model/ that use the kernel's internals on purpose, and why.
INTERNAL_USERS = {
    'benchmarks/bench_kernel_c.py': 'times the kernel entry points beside the C yardstick',
}


def _sources() -> list[Path]:
    roots = [p for p in REPO.iterdir() if p.is_dir() and not p.name.startswith('.')
             and p.name not in SKIP_PARTS | {'ros2_ws', 'docker'}]
    files = []
    for root in roots:
        for path in root.rglob('*.py'):
            rel = path.relative_to(REPO)
            if SKIP_PARTS & set(rel.parts) or MODEL_DIR in path.parents \
                    or rel.as_posix() in INTERNAL_USERS:
                continue
            files.append(path)
    return files


def _module_of(path: Path) -> str:
    """Dotted module name of ``path`` (for resolving relative imports)."""
    parts = list(path.relative_to(REPO).with_suffix('').parts)
    if len(parts) > 1 and parts[0] == parts[1]:
        parts = parts[1:]  # <pkg>/<pkg>/... -> <pkg>...
    return '.'.join(parts)


def _resolve(node: ast.ImportFrom, module: str) -> str:
    if not node.level:
        return node.module or ''
    base = module.split('.')[:-node.level]
    return '.'.join(base + ([node.module] if node.module else []))


def _is_model(name: str) -> bool:
    return name == 'valve_model_pkg.model' or name.startswith('valve_model_pkg.model.')


def _violations(path: Path) -> list[str]:
    tree = ast.parse(path.read_text(encoding='utf-8'), filename=str(path))
    module = _module_of(path)
    aliases: set[str] = set()
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom):
            src = _resolve(node, module)
            if not _is_model(src):
                continue
            for a in node.names:
                target = f'{src}.{a.name}'
                if a.name.startswith('_') or target == 'valve_model_pkg.model.kernel' \
                        or src == 'valve_model_pkg.model.kernel':
                    found.append(f'{path.relative_to(REPO)}:{node.lineno} imports '
                                 f'{a.name} from {src}')
                elif src == 'valve_model_pkg.model' and a.name[:1].islower() \
                        and (MODEL_DIR / f'{a.name}.py').exists():
                    aliases.add(a.asname or a.name)  # a model module
        elif isinstance(node, ast.Import):
            for a in node.names:
                if _is_model(a.name):
                    if a.name.endswith('.kernel'):
                        found.append(f'{path.relative_to(REPO)}:{node.lineno} imports '
                                     f'{a.name}')
                    aliases.add(a.asname or a.name)
    for node in ast.walk(tree):
        if isinstance(node, ast.Attribute) and node.attr.startswith('_') \
                and not node.attr.startswith('__'):
            base = ast.unparse(node.value)
            if base in aliases:
                found.append(f'{path.relative_to(REPO)}:{node.lineno} uses {base}.{node.attr}')
    return found


def test_the_scan_sees_the_packages() -> None:
    files = {p.relative_to(REPO).as_posix() for p in _sources()}
    assert 'valve_model_pkg/valve_model_pkg/identification/model_adapter.py' in files
    assert 'valve_model_pkg/valve_model_pkg/maps/generation.py' in files
    assert any(f.startswith('valve_driver_pkg/valve_driver_pkg/emulator/') for f in files)
    assert not any('/model/' in f and f.startswith('valve_model_pkg/valve_model_pkg/model')
                   for f in files)


def test_the_scan_finds_private_uses(tmp_path: Path) -> None:
    bad = REPO / 'valve_model_pkg' / 'valve_model_pkg' / 'identification' / '_probe.py'
    text = ('from ..model import kernel as _k\nfrom ..model.orifice import _mass_flow\n'
            'import valve_model_pkg.model.simulation as sim\nsim._run\n')
    tree_path = tmp_path / 'x.py'
    tree_path.write_text(text)
    # scanned as if it were in identification/ (relative imports resolve from there)
    original = Path.read_text
    try:
        Path.read_text = lambda self, *a, **k: text if self == bad else original(self, *a, **k)
        found = _violations(bad)
    finally:
        Path.read_text = original
    assert len(found) == 3, found


def test_nothing_outside_model_uses_private_model_names() -> None:
    found = [v for path in _sources() for v in _violations(path)]
    assert not found, 'private model names used outside model/:\n' + '\n'.join(found)


def test_the_drive_state_is_initialised_in_one_place() -> None:
    """Only kernel_jit._drive_state allocates a drive-state vector (``zeros(N_D)``)."""
    hits = []
    for path in list(MODEL_DIR.rglob('*.py')) + _sources():
        for n, line in enumerate(path.read_text(encoding='utf-8').splitlines(), 1):
            if 'N_D)' in line and 'zeros' in line:
                hits.append(f'{path.relative_to(REPO)}:{n}')
    assert len(hits) == 1 and 'model/kernel_jit.py' in hits[0], hits
