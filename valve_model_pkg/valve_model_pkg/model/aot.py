"""The kernel's backend: the ahead-of-time module if it is there, else the numba jit.

Every compiled call of the model goes through :func:`backend`: the entry points of
model/kernel.py (the single runs, the batches, the banks) and
:class:`~valve_model_pkg.model.ValveStepper`. It loads, once per process, the extension
module that :mod:`valve_model_pkg.model.aot_build` compiled ahead of time (numba.pycc) for
the current :func:`kernel_key`; such a process never imports numba or llvmlite (about
130 MB of a simulator node's memory and most of a cold start, docs/model.md). Without a
module of the current key (not built, or built from another kernel or numba), it falls
back to the numba jit of ``model/kernel_jit.py``: the same machine code, so the same
numbers bit for bit (tests/unit/test_aot_kernel.py). Which one is used is logged once
(logger ``valve_model_pkg.model.aot``) and is :func:`backend_name`.

The module is looked up in ``$VALVE_KERNEL_AOT_DIR`` if set (``off`` or an empty value
disables it), else in ``ros2_ws/build/valve_kernel_aot`` of the source tree (never
committed: ros2_ws/build/ is ignored), else ``$XDG_CACHE_HOME/valve_suite/kernel_aot``.

The kernel's layout constants (``D_*``, ``Y_*``, ``N_*``, ...) are read from kernel.py's
source with :mod:`ast` (:func:`layout`), so the stepper and the bank need not import it.

Both backends' functions release the GIL while they run. One difference that changes no
number: the module's functions do not pickle (a pickled stepper or bank drops its backend
and the receiving process picks its own).
"""
from __future__ import annotations

import ast
import hashlib
import importlib.machinery
import importlib.util
import logging
import os
import sys
import sysconfig
from pathlib import Path
from types import ModuleType, SimpleNamespace

_LOG = logging.getLogger(__name__)
_HERE = Path(__file__).resolve().parent

#: Sources whose compiled code the exports contain (kernel.py and what it calls or reads).
KERNEL_SOURCES = ('kernel.py', 'kernel_jit.py', 'electrical.py', 'magnetics.py',
                  'mechanics.py', 'orifice.py', 'electronics.py', 'parameters.py',
                  'constants.py', 'scalars.py')
MODULE_PREFIX = '_valve_kernel_aot_'
ENV_DIR = 'VALVE_KERNEL_AOT_DIR'

_backend: SimpleNamespace | None = None
_layout: dict[str, int | float] | None = None
_constants: SimpleNamespace | None = None


def _dist_version(name: str) -> str:
    """Installed version of a distribution without importing it ('' if absent).

    Read from the name of its ``*.dist-info`` directory next to the package (what pip
    installs); importlib.metadata would cost more than the rest of a cold start.
    """
    spec = importlib.util.find_spec(name)
    if spec is None or not spec.submodule_search_locations:
        return ''
    site = Path(next(iter(spec.submodule_search_locations))).parent
    infos = sorted(site.glob(f'{name}-*.dist-info'))
    if len(infos) == 1:
        return infos[0].name[len(name) + 1:-len('.dist-info')]
    from importlib import metadata  # another layout: ask the slow way
    try:
        return metadata.version(name)
    except metadata.PackageNotFoundError:
        return ''


def kernel_key() -> str:
    """Hash of the kernel sources and the numba, llvmlite, numpy and Python versions, hex.

    A module built under another key is never loaded: its code may differ from what the
    jit would compile now.
    """
    h = hashlib.sha256()
    for name in KERNEL_SOURCES:
        h.update(name.encode())
        h.update((_HERE / name).read_bytes())
    for dist in ('numba', 'llvmlite', 'numpy'):
        h.update(f'{dist}={_dist_version(dist)};'.encode())
    h.update(sys.version.encode())
    h.update(sysconfig.get_platform().encode())
    return h.hexdigest()[:16]


def module_name(key: str) -> str:
    """Extension module name of a key (pycc names the init function after it)."""
    return MODULE_PREFIX + key


def default_dir() -> Path | None:
    """Where the module is built and looked up (None: the AOT kernel is switched off)."""
    env = os.environ.get(ENV_DIR)
    if env is not None:
        return None if env.strip() in ('', 'off') else Path(env)
    # .../valve_model_pkg/valve_model_pkg/model/aot.py in the source tree (the colcon
    # symlink install resolves to it)
    root = _HERE.parents[2]
    if (root / 'ros2_ws').is_dir() and (root / 'valve_model_pkg').is_dir():
        return root / 'ros2_ws' / 'build' / 'valve_kernel_aot'
    cache = os.environ.get('XDG_CACHE_HOME') or str(Path.home() / '.cache')
    return Path(cache) / 'valve_suite' / 'kernel_aot'


def find_module(directory: Path | None, key: str) -> Path | None:
    """The built module file of ``key`` in ``directory``, or None."""
    if directory is None or not directory.is_dir():
        return None
    suffixes = importlib.machinery.EXTENSION_SUFFIXES
    for suffix in suffixes:
        path = directory / (module_name(key) + suffix)
        if path.is_file():
            return path
    return None


def _load_module(path: Path, key: str) -> ModuleType:
    spec = importlib.util.spec_from_file_location(module_name(key), path)
    if spec is None or spec.loader is None:
        raise ImportError(f'cannot load {path}')
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def layout() -> dict[str, int | float]:
    """The kernel's module-level numeric constants (``D_T``, ``N_OUT``, ...), from its source.

    Every upper-case name bound to a literal number in kernel.py; what the stepper and the
    bank index the state arrays with, without importing numba.
    """
    global _layout
    if _layout is None:
        tree = ast.parse((_HERE / 'kernel.py').read_text(encoding='utf-8'))
        found: dict[str, int | float] = {}
        for node in tree.body:
            if isinstance(node, ast.Assign) and len(node.targets) == 1 \
                    and isinstance(node.targets[0], ast.Name) \
                    and node.targets[0].id.isupper():
                try:
                    value = ast.literal_eval(node.value)
                except ValueError:
                    continue
                if isinstance(value, (int, float)) and not isinstance(value, bool):
                    found[node.targets[0].id] = value
        _layout = found
    return _layout


def constants() -> SimpleNamespace:
    """:func:`layout` as attributes (``constants().D_T``), the same object every call."""
    global _constants
    if _constants is None:
        _constants = SimpleNamespace(**layout())
    return _constants


def _aot_backend(module: ModuleType, origin: str) -> SimpleNamespace:
    ns = SimpleNamespace(**layout())
    ns.name = 'aot'
    ns.origin = origin
    ns.derive_parameters = module.derive
    ns.new_drive_state = module.drive_state
    ns.command = module.command
    ns.advance = module.advance
    ns.rising_edge = module.rising_edge
    ns.terminal_current = module.terminal_current
    ns.voltage = module.voltage
    ns.mass_flow = module.mass_flow
    ns.bank_advance = module.bank_advance
    ns.bank_sample = module.bank_sample
    ns.step_rows = module.step_rows
    ns.pwm_rows = module.pwm_rows
    ns.trace_rows = module.trace_rows
    return ns


def _jit_backend(reason: str) -> SimpleNamespace:
    from . import kernel_jit as k
    from .orifice import _mass_flow

    ns = SimpleNamespace(**layout())
    ns.name = 'jit'
    ns.origin = reason
    ns.derive_parameters = k._derive
    ns.new_drive_state = k._drive_state
    ns.command = k._command
    ns.advance = k._advance
    ns.rising_edge = k._rising_edge
    ns.terminal_current = k._terminal_current
    ns.voltage = k._voltage
    ns.mass_flow = _mass_flow
    ns.bank_advance = k._bank_advance
    ns.bank_sample = k._bank_sample
    ns.step_rows = k._step_rows
    ns.pwm_rows = k._pwm_rows
    ns.trace_rows = k._trace_rows
    return ns


def _select() -> SimpleNamespace:
    directory = default_dir()
    if directory is None:
        return _jit_backend(f'numba jit (${ENV_DIR} switches the AOT module off)')
    key = kernel_key()
    path = find_module(directory, key)
    if path is None:
        return _jit_backend(f'numba jit (no AOT module of kernel key {key} in {directory}; '
                            f'build it with python -m valve_model_pkg.model.aot_build)')
    try:
        module = _load_module(path, key)
    except Exception as exc:  # noqa: BLE001 - any failure to load: the jit works anyway
        return _jit_backend(f'numba jit (loading {path} failed: {exc})')
    return _aot_backend(module, f'AOT module {path}')


def backend() -> SimpleNamespace:
    """The kernel entry points and layout constants of this process (chosen once).

    Attributes: the layout constants of :func:`layout`; ``name`` ('aot' or 'jit');
    ``origin`` (a sentence: the module file, or why the jit); and the compiled functions
    ``derive_parameters(raw)``, ``new_drive_state(vs, duty, period, t0, p_sup, p_out,
    sample_dt, first_sample)`` (all float), ``command(t, d, e, duty, period)``,
    ``advance(p, e, y, d, t_end, h_free, h_stop, out, avg)``, ``rising_edge(t, y, p, d,
    e)``, ``terminal_current(t, y, phase, p, d, e)``, ``voltage(t, phase, d, e)``,
    ``mass_flow(x, p_up, p_down, c_d, c_a, temp, r_gas, gamma)``, ``bank_advance(p, e, y,
    d, t_end, h_free, h_stop)``, ``bank_sample(p, e, y, d, orifice, atm, iv, out)``,
    ``step_rows``, ``pwm_rows``, ``trace_rows`` (a batch's rows r0 <= r < r1, the last two
    arguments): kernel_jit's ``_derive``, ``_drive_state``, ... with exact argument types
    (float64 C-contiguous arrays, float scalars, int phase and rows).
    """
    global _backend
    if _backend is None:
        _backend = _select()
        _LOG.info('valve kernel: %s', _backend.origin)
    return _backend


def backend_name() -> str:
    """'aot' or 'jit': which kernel this process runs (selects it if not yet done)."""
    return backend().name


def _reset_for_tests() -> None:
    """Forget the choice (tests switch ``$VALVE_KERNEL_AOT_DIR`` between cases)."""
    global _backend
    _backend = None
