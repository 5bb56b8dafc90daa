"""The scalar physics functions that the compiled kernel calls, kept plain Python.

The equations of magnetics.py, electrical.py, mechanics.py and orifice.py live in small
float-in, float-out functions (``_inductance``, ``_force``, ``_mass_flow``, ...). Each is
marked with :func:`kernel_scalar`: it stays an ordinary Python function (the public
numpy-level functions of those modules and the pneumatics call it as such), and
:mod:`~valve_model_pkg.model.kernel_jit` registers every marked function with numba
(``register_jitable``) before it compiles anything, so the kernel compiles them into its
own code. A process that runs the ahead-of-time kernel (:mod:`~valve_model_pkg.model.aot`)
therefore imports these modules without importing numba.
"""
from __future__ import annotations

from collections.abc import Callable
from typing import TypeVar

__all__ = ['kernel_scalar', 'kernel_scalars']

_F = TypeVar('_F', bound=Callable[..., object])
_MARKED: list[Callable[..., object]] = []


def kernel_scalar(fn: _F) -> _F:
    """Mark ``fn`` as compiled into the kernel; returns it unchanged."""
    _MARKED.append(fn)
    return fn


def kernel_scalars() -> tuple[Callable[..., object], ...]:
    """Every function marked so far (kernel_jit imports their modules first)."""
    return tuple(_MARKED)
