"""Build the ahead-of-time compiled kernel (numba.pycc).

``python -m valve_model_pkg.model.aot_build [--out DIR] [--force]`` compiles every entry
point of the kernel (:data:`EXPORTS`: what model/kernel.py, the stepper and the bank
call, the batches' row loops included) into one CPython extension module that needs only
numpy at run time. A process that uses it never imports numba or llvmlite: it starts in a
fraction of the time (no numba import, no cache loading) and saves about 130 MB of memory
(docs/model.md, "The compiled kernel"). ``scripts/setup.sh`` runs this after the colcon
build; without the module (or with a stale one) the kernel runs on the numba jit.

The module's name carries :func:`~valve_model_pkg.model.aot.kernel_key` (a hash of the
kernel's sources and the numba, numpy and Python versions), so an edited kernel or an
upgraded numba simply does not find a module of its key: never a stale one.

Each export is a thin wrapper that calls the kernel's own ``@njit`` function, which numba
compiles with that function's options (no fastmath, the python error model), so the
machine code is the jit's and the outputs are bit-identical (tests/unit/test_aot_kernel.py).
Every export releases the GIL while it runs (its CPython wrapper is built with numba's
``release_gil`` flag, which pycc does not expose: :func:`_release_gil_flags`), so the
batches' row loops run in parallel on Python threads (pycc compiles no ``prange``).

pycc's default target, a generic x86-64 CPU, is kept on purpose: a build for the host CPU
(``CC.target_cpu = 'host'``) is just as bit-identical but measured no faster (within 1 %
per simulated second; the integrator is scalar, step-after-step code), and it would need
the CPU in the kernel key so that a module built elsewhere never raises an illegal
instruction (docs/model.md, "The compiled kernel").

numba.pycc is "pending deprecation" in numba (still shipped and working in 0.68; its
successor is not released yet). If a numba release drops it, this build fails with a
clear message and the suite keeps running on the jit.

Exit status: 0 built (or already up to date), 1 the build failed, 2 a bad argument.
"""
from __future__ import annotations

import argparse
import os
import shutil
import sys
import tempfile
import time
import warnings
from pathlib import Path

from . import aot as _aot

#: Exported name -> signature. Arrays are C-contiguous float64, as the stepper and the bank
#: pass them (the same types the jit specialises on). Phases are int64 (a Python int).
EXPORTS = {
    'derive': 'f8[::1](f8[::1])',
    'step_rows': 'void(f8[:, ::1], f8[::1], f8[::1], f8[::1], f8[::1], f8, f8, f8, f8, f8, '
                 'f8[:, ::1], f8[:, ::1], i8, i8)',
    'pwm_rows': 'void(f8[:, ::1], f8[::1], f8[::1], f8[::1], f8[::1], f8[::1], f8[::1], f8, '
                'f8, f8[:, ::1], i8, i8)',
    'trace_rows': 'void(f8[:, ::1], f8[::1], f8[::1], f8[::1], f8[::1], f8[::1], f8[::1], '
                  'f8[::1], f8[::1], f8[::1], f8[::1], f8, f8, f8[:, :, ::1], f8[:, ::1], '
                  'i8, i8)',
    'drive_state': 'f8[::1](f8, f8, f8, f8, f8, f8, f8, f8)',
    'command': 'void(f8, f8[::1], f8[::1], f8, f8)',
    'advance': 'void(f8[::1], f8[::1], f8[::1], f8[::1], f8, f8, f8, f8[:, ::1], f8[::1])',
    'rising_edge': 'void(f8, f8[::1], f8[::1], f8[::1], f8[::1])',
    'terminal_current': 'f8(f8, f8[::1], i8, f8[::1], f8[::1], f8[::1])',
    'voltage': 'f8(f8, i8, f8[::1], f8[::1])',
    'mass_flow': 'f8(f8, f8, f8, f8, f8, f8, f8, f8)',
    'bank_advance': 'void(f8[:, ::1], f8[:, ::1], f8[:, ::1], f8[:, ::1], f8[::1], f8, f8)',
    'bank_sample': 'void(f8[:, ::1], f8[:, ::1], f8[:, ::1], f8[:, ::1], f8[:, ::1], f8, '
                   'f8[:, ::1], f8[:, ::1])',
}


def _wrappers() -> dict:
    """The exported Python functions: each calls one compiled kernel function."""
    from . import kernel_jit as k
    from .orifice import _mass_flow

    def derive(raw):
        return k._derive(raw)

    def step_rows(raw, e, voltage, p_sup, p_out, duration, step_time, sample_dt, h_free,
                  h_stop, cur, pos, r0, r1):
        k._step_rows(raw, e, voltage, p_sup, p_out, duration, step_time, sample_dt, h_free,
                     h_stop, cur, pos, r0, r1)

    def pwm_rows(raw, e, supply_v, duty, period, p_sup, p_out, h_free, h_stop, avg, r0, r1):
        k._pwm_rows(raw, e, supply_v, duty, period, p_sup, p_out, h_free, h_stop, avg, r0, r1)

    def trace_rows(raw, e, seg_t, seg_vs, seg_duty, seg_period, seg_psup, seg_pout, p_sup,
                   p_out, t_samp, h_free, h_stop, out, stats, r0, r1):
        k._trace_rows(raw, e, seg_t, seg_vs, seg_duty, seg_period, seg_psup, seg_pout, p_sup,
                      p_out, t_samp, h_free, h_stop, out, stats, r0, r1)

    def drive_state(vs, duty, period, t0, p_sup, p_out, sample_dt, first_sample):
        return k._drive_state(vs, duty, period, t0, p_sup, p_out, sample_dt, first_sample)

    def command(t_cmd, d, e, duty, period):
        k._command(t_cmd, d, e, duty, period)

    def advance(p, e, y, d, t_end, h_free, h_stop, out, avg_out):
        k._advance(p, e, y, d, t_end, h_free, h_stop, out, avg_out)

    def rising_edge(t, y, p, d, e):
        k._rising_edge(t, y, p, d, e)

    def terminal_current(t, y, phase, p, d, e):
        return k._terminal_current(t, y, phase, p, d, e)

    def voltage(t, phase, d, e):
        return k._voltage(t, phase, d, e)

    def mass_flow(x, p_up, p_down, c_d, c_a, temp, r_gas, gamma):
        # _mass_flow is plain Python registered with numba by kernel_jit (model/scalars.py)
        return _mass_flow(x, p_up, p_down, c_d, c_a, temp, r_gas, gamma)

    def bank_advance(p, e, y, d, t_end, h_free, h_stop):
        k._bank_advance(p, e, y, d, t_end, h_free, h_stop)

    def bank_sample(p, e, y, d, orifice, atmosphere_pa, iv, out):
        k._bank_sample(p, e, y, d, orifice, atmosphere_pa, iv, out)

    return {name: fn for name, fn in locals().items() if name in EXPORTS}


def _release_gil_flags(compiler_module) -> None:
    """Make pycc build every export's CPython wrapper with numba's ``release_gil`` flag.

    pycc compiles each export with a fresh ``numba.core.compiler.Flags()``; the flag is the
    one ``@njit(nogil=True)`` sets. The wrapper takes the GIL back before it builds the
    return value or raises.
    """
    base = compiler_module.Flags
    if getattr(base, 'valve_releases_gil', False):
        return

    class ReleaseGilFlags(base):
        valve_releases_gil = True

        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            self.release_gil = True

    compiler_module.Flags = ReleaseGilFlags


def build(out_dir: Path, force: bool = False) -> Path:
    """Compile the module of the current kernel key into ``out_dir``; returns its path.

    Nothing is done when the module of the current key is already there (unless
    ``force``). Modules of other keys in ``out_dir`` are removed. The compilation runs with
    a private numba cache directory: pycc must link the kernel's LLVM IR, which a function
    loaded from numba's on-disk cache (object code only) does not have. That directory is
    set before numba is first imported, so call this in a process that has not imported
    numba yet (the command line does).
    """
    key = _aot.kernel_key()
    name = _aot.module_name(key)
    out_dir.mkdir(parents=True, exist_ok=True)
    existing = _aot.find_module(out_dir, key)
    if existing is not None and not force:
        return existing
    with tempfile.TemporaryDirectory(prefix='valve_aot_') as tmp:
        os.environ['NUMBA_CACHE_DIR'] = tmp  # read when numba is first imported
        with warnings.catch_warnings():
            # "pycc is pending deprecation": known, documented above and in docs/model.md
            warnings.simplefilter('ignore')
            from numba.pycc import CC, compiler as pycc_compiler
        _release_gil_flags(pycc_compiler)
        cc = CC(name)
        cc.output_dir = tmp
        cc.verbose = False
        for export, fn in _wrappers().items():
            cc.export(export, EXPORTS[export])(fn)
        cc.compile()
        built = _aot.find_module(Path(tmp), key)
        if built is None:
            raise RuntimeError(f'pycc produced no module {name} in {tmp}')
        for old in out_dir.glob(_aot.MODULE_PREFIX + '*'):
            old.unlink()
        # copy then rename: a process loading the directory never sees half a file
        part = out_dir / (built.name + '.part')
        shutil.copyfile(built, part)
        final = out_dir / built.name
        part.replace(final)
    return final


def main(argv: list[str] | None = None) -> int:
    """Command line: build the module; exit 0 built/up to date, 1 failed, 2 bad argument."""
    parser = argparse.ArgumentParser(
        prog='python -m valve_model_pkg.model.aot_build',
        description='Compile the streaming kernel ahead of time (numba.pycc).')
    parser.add_argument('-o', '--out', type=Path, default=None,
                        help=f'output directory (default: {_aot.default_dir()})')
    parser.add_argument('--force', action='store_true', help='rebuild even if up to date')
    args = parser.parse_args(argv)
    out_dir = args.out if args.out is not None else _aot.default_dir()
    if out_dir is None:
        print(f'aot_build: ${_aot.ENV_DIR} switches the AOT kernel off; nothing built',
              file=sys.stderr)
        return 0
    if out_dir.exists() and not out_dir.is_dir():
        print(f'aot_build: --out {out_dir} is not a directory', file=sys.stderr)
        return 2
    start = time.perf_counter()
    try:
        path = build(out_dir, force=args.force)
    except Exception as exc:  # noqa: BLE001 - one line, the suite falls back to the jit
        print(f'aot_build: failed ({type(exc).__name__}: {exc}); the suite uses the numba '
              f'jit', file=sys.stderr)
        return 1
    print(f'aot_build: {path} ({time.perf_counter() - start:.1f} s)', file=sys.stderr)
    return 0


if __name__ == '__main__':
    sys.exit(main())
