"""A bank of streaming valves: N valves advanced together in one compiled call.

:class:`ValveBank` is :class:`~valve_model_pkg.model.ValveStepper` for many valves at once
(the bank simulator node, the static map's steady-state search). Each valve has its own
parameters, electronics, command, pressures and model time; ``advance_to`` integrates every
valve to its target time in one call into the compiled kernel, and ``sample_array`` reads
the state of all valves in another, so the Python cost per tick does not grow with the
number of valves the way N steppers would.

Each valve runs exactly the single-valve integrator on its own state, so a bank valve
gives the same numbers, bit for bit, as a ``ValveStepper`` with the same inputs (a test
checks it). Command semantics are the stepper's: ``set_command`` takes effect at the next
main PWM period start, ``set_pressures`` at once.
"""
from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from .aot import backend as _backend, constants as _constants
from .constants import ATMOSPHERIC_PRESSURE_PA
from .electronics import ElectronicsConfig
from .parameters import ParameterError, ValveParameters
from .sample import ValveSample
from .stepper import _check_command, _check_pressures

__all__ = ['ValveBank', 'SAMPLE_COLUMNS', 'sample_of']

# The kernel's layout constants, read without importing numba; the compiled functions
# come from _backend(): the ahead-of-time module or the jit (model/aot.py).
_k = _constants()

#: Columns of :meth:`ValveBank.sample_array`, in order (SI units, gauge pressures).
SAMPLE_COLUMNS: tuple[str, ...] = (
    't_s', 'coil_voltage_v', 'coil_current_a', 'spool_position_m', 'spool_velocity_m_s',
    'position_avg_m', 'mass_flow_kg_s', 'duty', 'pwm_frequency_hz', 'supply_pressure_pa',
    'output_pressure_pa', 'coil_temperature_rise_k', 'coil_current_mean_a',
    'coil_voltage_mean_v')


def _per_valve(value, n: int, name: str) -> list:
    """A scalar (or one object) for every valve, or a sequence of exactly n values."""
    if isinstance(value, (list, tuple, np.ndarray)):
        if len(value) != n:
            raise ParameterError(f'{name} must have one value per valve ({n}), '
                                 f'got {len(value)}')
        return list(value)
    return [value] * n


class ValveBank:
    """N streaming valves: command each, advance all in one call, sample all in one call.

    Parameters
    ----------
    params : ValveParameters or sequence of ValveParameters
        One set for every valve, or one per valve.
    electronics : ElectronicsConfig or sequence, optional
        Default ``ElectronicsConfig()`` for every valve.
    supply_voltage_v : float or sequence of float
        Driver supply voltage, V.
    n_valves : int, optional
        Number of valves when ``params`` is a single set (default 1, or the length of any
        per-valve argument).
    duty, pwm_frequency_hz, supply_pressure_pa, output_pressure_pa : float or sequence
        Initial command (duty [1], frequency Hz) and gauge pressures (Pa), per valve.
    h_free_s, h_stop_s : float
        Maximum RK4 steps, s (one pair for the bank).

    Examples
    --------
    >>> bank = ValveBank(load_parameters(), n_valves=16)
    >>> bank.set_command(3, 0.4, 50.0)
    >>> bank.advance_to(0.1)          # every valve to t = 0.1 s
    >>> rows = bank.sample_array()    # (16, len(SAMPLE_COLUMNS))
    """

    def __init__(self, params: ValveParameters | Sequence[ValveParameters],
                 electronics: ElectronicsConfig | Sequence[ElectronicsConfig] | None = None,
                 supply_voltage_v: float | Sequence[float] = 24.0, *,
                 n_valves: int | None = None, duty: float | Sequence[float] = 0.0,
                 pwm_frequency_hz: float | Sequence[float] = 50.0,
                 supply_pressure_pa: float | Sequence[float] = 4.0e5,
                 output_pressure_pa: float | Sequence[float] = 0.0,
                 h_free_s: float = _k.DEFAULT_H_FREE_S,
                 h_stop_s: float = _k.DEFAULT_H_STOP_S) -> None:
        per_valve = [a for a in (params, electronics, supply_voltage_v, duty,
                                 pwm_frequency_hz, supply_pressure_pa, output_pressure_pa)
                     if isinstance(a, (list, tuple, np.ndarray))]
        n = int(n_valves) if n_valves is not None else (len(per_valve[0]) if per_valve else 1)
        if n < 1:
            raise ParameterError(f'a bank needs at least one valve, got {n}')
        self._params = _per_valve(params, n, 'params')
        elec = _per_valve(ElectronicsConfig() if electronics is None else electronics, n,
                          'electronics')
        self._electronics = elec
        vs = [float(v) for v in _per_valve(supply_voltage_v, n, 'supply_voltage_v')]
        for v in vs:
            if not math.isfinite(v):
                raise ParameterError(f'supply_voltage_v must be finite, got {v!r}')
        duty_l = _per_valve(duty, n, 'duty')
        freq_l = _per_valve(pwm_frequency_hz, n, 'pwm_frequency_hz')
        sup_l = _per_valve(supply_pressure_pa, n, 'supply_pressure_pa')
        out_l = _per_valve(output_pressure_pa, n, 'output_pressure_pa')
        for k in range(n):
            _check_command(duty_l[k], freq_l[k])
            _check_pressures(sup_l[k], out_l[k])
        self._init = [(vs[k], float(duty_l[k]), float(freq_l[k]), float(sup_l[k]),
                       float(out_l[k])) for k in range(n)]
        self._h = (float(h_free_s), float(h_stop_s))
        self._kb = _backend()
        self._p = np.ascontiguousarray(
            [self._kb.derive_parameters(np.ascontiguousarray(p.to_vector(), dtype=np.float64))
             for p in self._params], dtype=np.float64)
        self._e = np.ascontiguousarray([c.to_vector() for c in elec], dtype=np.float64)
        self._orifice = np.array(
            [(p.discharge_coefficient, p.orifice_area_gradient_m, p.supply_temperature_k,
              p.gas_constant_j_per_kg_k, p.heat_capacity_ratio) for p in self._params],
            dtype=np.float64)
        self._y = np.zeros((n, _k.N_Y))
        self._d = np.empty((n, _k.N_D))  # every row from new_drive_state (reset)
        self._t_end = np.zeros(n)
        self._rows = np.zeros((n, _k.N_S))
        # interval means (as ValveStepper.interval_means): per valve the start of the
        # running interval, the last means and whether one has ended (kernel IV_* columns)
        self._iv = np.zeros((n, _k.N_IV))
        self.reset()

    def __getstate__(self) -> dict:
        # the AOT module's functions do not pickle (its name is per kernel key): the
        # receiving process picks its own backend
        state = dict(self.__dict__)
        del state['_kb']
        return state

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state)
        self._kb = _backend()

    def __len__(self) -> int:
        return self._p.shape[0]

    @property
    def params(self) -> list[ValveParameters]:
        """The parameter set of each valve."""
        return list(self._params)

    @property
    def electronics(self) -> list[ElectronicsConfig]:
        """The electronics configuration of each valve."""
        return list(self._electronics)

    @property
    def t_s(self) -> np.ndarray:
        """Model time of each valve, s (a copy)."""
        return self._d[:, _k.D_T].copy()

    def reset(self, index: int | None = None) -> None:
        """Back to t = 0, closed at rest, initial command and pressures (one valve or all)."""
        for k in range(len(self)) if index is None else (self._index(index),):
            vs, duty, freq, p_sup, p_out = self._init[k]
            self._y[k] = 0.0
            self._d[k] = self._kb.new_drive_state(vs, duty, 1.0 / freq, 0.0, p_sup, p_out,
                                                  math.inf, 0.0)
            self._d[k, _k.D_DUTY] = duty
            self._iv[k] = 0.0

    def _index(self, index: int) -> int:
        k = int(index)
        if not 0 <= k < len(self):
            raise IndexError(f'valve index {index!r} outside [0, {len(self)})')
        return k

    def set_command(self, index: int, duty: float, pwm_frequency_hz: float) -> None:
        """Command valve ``index``: duty in [0, 1], main PWM frequency in Hz.

        The stepper's command semantics (``ValveStepper.set_command``): duty 0 switches
        the coil off at once, any other duty and the frequency take effect at that valve's
        next main PWM period start.

        Raises
        ------
        ParameterError
            Duty outside [0, 1] or non-positive/non-finite frequency.
        """
        _check_command(duty, pwm_frequency_hz)
        k = self._index(index)
        self._kb.command(float(self._d[k, _k.D_T]), self._d[k], self._e[k], float(duty),
                         1.0 / float(pwm_frequency_hz))

    def set_pressures(self, index: int, supply_pa: float, output_pa: float = 0.0) -> None:
        """Set valve ``index``'s supply and output gauge pressures in Pa (at once)."""
        _check_pressures(supply_pa, output_pa)
        k = self._index(index)
        self._d[k, _k.D_PSUP] = float(supply_pa)
        self._d[k, _k.D_POUT] = float(output_pa)

    def advance_to(self, t_s: float | np.ndarray) -> None:
        """Integrate every valve up to model time ``t_s`` in s, in one compiled call.

        ``t_s`` is one time for all valves or one per valve; a valve already at or past its
        target is left alone (as ``ValveStepper.advance_to``).

        Raises
        ------
        ParameterError
            If a target time is not finite.
        """
        if np.ndim(t_s) == 0:
            t = float(t_s)
            if not math.isfinite(t):
                raise ParameterError(f't_s must be finite, got {t_s!r}')
            self._t_end.fill(t)
        else:
            t_arr = np.asarray(t_s, dtype=np.float64)
            if t_arr.shape != self._t_end.shape or not np.all(np.isfinite(t_arr)):
                raise ParameterError(f't_s must be finite with shape {self._t_end.shape}, '
                                     f'got {t_s!r}')
            self._t_end[:] = t_arr
        self._kb.bank_advance(self._p, self._e, self._y, self._d, self._t_end, self._h[0],
                              self._h[1])

    def sample_array(self) -> np.ndarray:
        """The state of every valve now, shape (n, len(:data:`SAMPLE_COLUMNS`)).

        One compiled call; the returned array is reused by the next call (copy it to
        keep it). The interval means cover, per valve, the interval since its previous
        sampling instant and end it (``ValveStepper.interval_means``): a valve whose time
        has not advanced keeps its means; before its first interval ends, the
        instantaneous values.
        """
        self._kb.bank_sample(self._p, self._e, self._y, self._d, self._orifice,
                             float(ATMOSPHERIC_PRESSURE_PA), self._iv, self._rows)
        return self._rows

    def position_avg_m(self) -> np.ndarray:
        """Average position over each valve's last complete main PWM period, m (a copy)."""
        return self._d[:, _k.D_XAVG].copy()

    def sample(self, index: int) -> ValveSample:
        """The state of valve ``index`` now, as ``ValveStepper.sample``."""
        return sample_of(self.sample_array()[self._index(index)].tolist())


def sample_of(row: Sequence[float]) -> ValveSample:
    """The :class:`ValveSample` of one row of :meth:`ValveBank.sample_array` (floats)."""
    return ValveSample(*row[:_k.S_I_MEAN], False, row[_k.S_I_MEAN], row[_k.S_V_MEAN])
