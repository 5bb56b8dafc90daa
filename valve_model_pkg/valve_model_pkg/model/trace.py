"""The input of a simulation: :class:`InputTrace`, a piecewise-constant valve input.

Three forms (build them with the classmethods):

* ``InputTrace.coil_voltage(t_s, v)``: the terminal voltage of the bare coil (a bench
  supply, a measured voltage column). The drive electronics are not involved.
* ``InputTrace.pwm_commands(t_s, duty, pwm_frequency_hz, supply_voltage_v)``: main PWM
  commands through the drive electronics (boost, chopper with PI holding current,
  negative-voltage capacitor, :class:`~valve_model_pkg.model.ElectronicsConfig`).
* ``InputTrace.step(voltage_v, step_time_s)``: the paper's voltage step (Figs. 4, 5): the
  main input switched on at ``step_time_s`` and held, on the bare coil or through the
  electronics; the edge lands exactly on ``step_time_s``.

The first two are zero-order holds: value ``k`` applies from ``t_s[k]`` to ``t_s[k + 1]``,
and the first value also from t = 0 (every run starts at t = 0 with the valve closed at
rest, the coil de-energised and the capacitor empty). A PWM command is latched at the next
main PWM period start, as :class:`~valve_model_pkg.model.ValveStepper` and the real valve
do (the first period starts at t = 0 with the first command); a command given exactly at a
period start takes effect at that period start. A duty of 0 given within a period switches
the coil off at once (docs/safety.md, "Close semantics"). A supply voltage change acts at
once. The kernel applies a change 3 ps before its time, so a sample or period start at the
same instant sees the new input.

A ``coil_voltage`` or ``pwm_commands`` trace may also carry the gauge supply and output
pressures of eq. (10) per value (``supply_pressure_pa``, ``output_pressure_pa``): a valve
in service sees them change (a cylinder filling behind it), and the pressure force moves
the spool. They are held like the other inputs and act at once, as
``ValveStepper.set_pressures`` does. :meth:`InputTrace.with_pressures` adds a pressure
course given at its own times. Without them a run has the constant pressures given to
:func:`~valve_model_pkg.model.simulate_trace_batch`.

:func:`~valve_model_pkg.model.simulate_trace_batch` simulates parameter sets under a trace.
"""
from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np

from .kernel import MIN_PERIOD_S
from .parameters import ParameterError

__all__ = ['InputTrace']

#: The kernel applies an input change this long before its time (kernel_jit._TRACE_LEAD_S).
_LEAD_S = 3e-12


def _as_1d(name: str, value: float | np.ndarray, n: int) -> np.ndarray:
    a = np.asarray(value, dtype=np.float64)
    if a.ndim == 0:
        a = np.full(n, float(a))
    if a.shape != (n,):
        raise ParameterError(f'{name} must be a scalar or have shape ({n},), got {a.shape}')
    if not np.all(np.isfinite(a)):
        raise ParameterError(f'{name} must be finite')
    return a


def _pressures(t: np.ndarray, supply: object, output: object
               ) -> tuple[np.ndarray | None, np.ndarray | None]:
    """Checked pressure arrays of shape (n,), or (None, None) when neither is given."""
    if supply is None and output is None:
        return None, None
    if supply is None or output is None:
        raise ParameterError('give both supply_pressure_pa and output_pressure_pa (or '
                             'neither: the runs then have constant pressures)')
    sup = _as_1d('supply_pressure_pa', supply, t.size)
    out = _as_1d('output_pressure_pa', output, t.size)
    for name, a in (('supply_pressure_pa', sup), ('output_pressure_pa', out)):
        if np.any(a < -1.0e5):
            raise ParameterError(f'{name} must be gauge pressures above -1 bar, got '
                                 f'{float(np.min(a))!r}')
    return sup, out


def _held(t_new: np.ndarray, t: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Zero-order hold of ``values`` (changing at ``t``) at the times ``t_new``."""
    return values[np.maximum(np.searchsorted(t, t_new, side='right') - 1, 0)]


def _change_times(t_s: np.ndarray | Sequence[float]) -> np.ndarray:
    t = np.asarray(t_s, dtype=np.float64)
    if t.ndim != 1 or t.size == 0:
        raise ParameterError(f't_s must be a non-empty 1-D array, got shape {t.shape}')
    if not np.all(np.isfinite(t)) or t[0] < 0.0:
        raise ParameterError('t_s must be finite and start at t >= 0 s')
    if np.any(np.diff(t) <= 0.0):
        raise ParameterError('t_s must be strictly increasing')
    return t


@dataclasses.dataclass(frozen=True)
class InputTrace:
    """A piecewise-constant input of the valve (build it with the classmethods).

    Attributes
    ----------
    kind : str
        ``'coil_voltage'`` (bare coil), ``'pwm_commands'`` (through the electronics) or
        ``'step'`` (the main input switched on at ``t_s[0]``).
    t_s : numpy.ndarray, shape (n,)
        Times at which each value starts to apply, s (strictly increasing, >= 0; the
        first value of a ``coil_voltage`` or ``pwm_commands`` trace also applies from
        t = 0; a ``step`` is off before its one time).
    supply_voltage_v : numpy.ndarray, shape (n,)
        Coil terminal voltage (``coil_voltage``) or driver supply voltage
        (``pwm_commands``, ``step``), V.
    duty : numpy.ndarray, shape (n,)
        Main PWM duty in [0, 1] (1 for ``coil_voltage`` and ``step``).
    pwm_frequency_hz : numpy.ndarray, shape (n,)
        Main PWM frequency, Hz (0 for ``coil_voltage`` and ``step``: no PWM period).
    supply_pressure_pa, output_pressure_pa : numpy.ndarray, shape (n,), or None
        Gauge pressures of eq. (10) from ``t_s[k]`` on, Pa; None (both): the run's
        constant pressures.
    """

    kind: str
    t_s: np.ndarray
    supply_voltage_v: np.ndarray
    duty: np.ndarray
    pwm_frequency_hz: np.ndarray
    supply_pressure_pa: np.ndarray | None = None
    output_pressure_pa: np.ndarray | None = None

    @classmethod
    def step(cls, voltage_v: float = 24.0, step_time_s: float = 0.0) -> InputTrace:
        """The paper's voltage step: the main input off until ``step_time_s``, then on.

        On the bare coil (the default of a step) the coil sees 0 V, then ``voltage_v``;
        through drive electronics it is one main PWM period of duty 1 starting at
        ``step_time_s`` (boost, then the holding current).

        Parameters
        ----------
        voltage_v : float
            Step (supply) voltage, V.
        step_time_s : float
            Time of the rising edge, s (>= 0).

        Returns
        -------
        InputTrace
        """
        if not np.isfinite(voltage_v):
            raise ParameterError(f'voltage must be finite, got {voltage_v!r}')
        if not np.isfinite(step_time_s) or step_time_s < 0.0:
            raise ParameterError(f'step_time_s must be non-negative, got {step_time_s!r}')
        return cls('step', np.array([float(step_time_s)]), np.array([float(voltage_v)]),
                   np.ones(1), np.zeros(1))

    def key(self) -> tuple:
        """A hashable identity of the trace (equal inputs give equal keys)."""
        return (self.kind,) + tuple(b'' if a is None else a.tobytes() for a in (
            self.t_s, self.supply_voltage_v, self.duty, self.pwm_frequency_hz,
            self.supply_pressure_pa, self.output_pressure_pa))

    @property
    def has_pressures(self) -> bool:
        """True if the trace carries the pressures (else the run's constants apply)."""
        return self.supply_pressure_pa is not None

    def pressures_at(self, t_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Supply and output gauge pressures in force at the times ``t_s``, Pa.

        As the kernel applies them: value k from 3 ps before ``t_s[k]`` on, the first
        from t = 0.

        Raises
        ------
        ParameterError
            If the trace carries no pressures.
        """
        if not self.has_pressures:
            raise ParameterError('this trace carries no pressures')
        t = np.asarray(t_s, dtype=np.float64)
        return (_held(t + _LEAD_S, self.t_s, self.supply_pressure_pa),
                _held(t + _LEAD_S, self.t_s, self.output_pressure_pa))

    def with_pressures(self, t_s: np.ndarray | Sequence[float],
                       supply_pressure_pa: np.ndarray | Sequence[float] | float,
                       output_pressure_pa: np.ndarray | Sequence[float] | float
                       ) -> InputTrace:
        """This trace with a pressure course given at its own times (zero-order hold).

        The values of both are held between their change times; the result changes at
        the union of the times (a held PWM command given again changes nothing). Before
        ``t_s[0]`` the first pressures apply.

        Parameters
        ----------
        t_s : array_like, shape (m,)
            Times each pressure value starts to apply, s.
        supply_pressure_pa, output_pressure_pa : array_like, shape (m,) or float
            Gauge pressures, Pa.

        Returns
        -------
        InputTrace
        """
        if self.kind == 'step':
            raise ParameterError('a step trace has constant pressures: give them to '
                                 'simulate_trace_batch')
        tp = _change_times(t_s)
        sup, out = _pressures(tp, supply_pressure_pa, output_pressure_pa)
        t = np.union1d(self.t_s, tp)
        fields = {name: _held(t, self.t_s, getattr(self, name))
                  for name in ('supply_voltage_v', 'duty', 'pwm_frequency_hz')}
        return dataclasses.replace(self, t_s=t, **fields,
                                   supply_pressure_pa=_held(t, tp, sup),
                                   output_pressure_pa=_held(t, tp, out))

    @property
    def is_constant(self) -> bool:
        """True for a single value (a constant command or level, or a step)."""
        return self.t_s.size == 1

    @classmethod
    def coil_voltage(cls, t_s: np.ndarray | Sequence[float],
                     v: np.ndarray | Sequence[float] | float, *,
                     supply_pressure_pa: np.ndarray | Sequence[float] | float | None = None,
                     output_pressure_pa: np.ndarray | Sequence[float] | float | None = None
                     ) -> InputTrace:
        """Terminal voltage of the bare coil, zero-order hold.

        Parameters
        ----------
        t_s : array_like, shape (n,)
            Start time of each level, s.
        v : array_like, shape (n,) or float
            Coil terminal voltage from ``t_s[k]`` on, V (negative levels allowed: the
            bare coil has no reverse-blocking diode).
        supply_pressure_pa, output_pressure_pa : array_like, shape (n,) or float, optional
            Gauge pressures from ``t_s[k]`` on, Pa (both or neither; see the module doc).

        Returns
        -------
        InputTrace
            Consecutive equal inputs are merged (an edge costs a kernel event).
        """
        t = _change_times(t_s)
        volts = _as_1d('v', v, t.size)
        sup, out = _pressures(t, supply_pressure_pa, output_pressure_pa)
        keep = np.ones(t.size, dtype=bool)
        keep[1:] = volts[1:] != volts[:-1]
        if sup is not None:
            keep[1:] |= (sup[1:] != sup[:-1]) | (out[1:] != out[:-1])
            sup, out = sup[keep], out[keep]
        t, volts = t[keep], volts[keep]
        return cls('coil_voltage', t, volts, np.ones(t.size), np.zeros(t.size), sup, out)

    @classmethod
    def pwm_commands(cls, t_s: np.ndarray | Sequence[float],
                     duty: np.ndarray | Sequence[float] | float,
                     pwm_frequency_hz: np.ndarray | Sequence[float] | float = 50.0,
                     supply_voltage_v: np.ndarray | Sequence[float] | float = 24.0, *,
                     supply_pressure_pa: np.ndarray | Sequence[float] | float | None = None,
                     output_pressure_pa: np.ndarray | Sequence[float] | float | None = None
                     ) -> InputTrace:
        """Main PWM commands through the drive electronics, zero-order hold.

        Parameters
        ----------
        t_s : array_like, shape (n,)
            Time each command is given, s. Duty and frequency are latched at the next
            main PWM period start (the first period starts at t = 0 with command 0).
        duty : array_like, shape (n,) or float
            Main PWM duty cycle in [0, 1].
        pwm_frequency_hz : array_like, shape (n,) or float
            Main PWM frequency, Hz (> 0).
        supply_voltage_v : array_like, shape (n,) or float
            Driver supply voltage from ``t_s[k]`` on (acts at once), V.
        supply_pressure_pa, output_pressure_pa : array_like, shape (n,) or float, optional
            Gauge pressures from ``t_s[k]`` on (act at once), Pa (both or neither; see the
            module doc).

        Returns
        -------
        InputTrace
        """
        t = _change_times(t_s)
        duty_a = _as_1d('duty', duty, t.size)
        freq = _as_1d('pwm_frequency_hz', pwm_frequency_hz, t.size)
        volts = _as_1d('supply_voltage_v', supply_voltage_v, t.size)
        if np.any((duty_a < 0.0) | (duty_a > 1.0)):
            raise ParameterError('duty must be in [0, 1]')
        if np.any(freq <= 0.0):
            raise ParameterError('pwm_frequency_hz must be positive')
        too_fast = np.flatnonzero(freq > 1.0 / MIN_PERIOD_S)
        if too_fast.size:
            raise ParameterError(
                f'pwm_frequency_hz[{too_fast[0]}] = {freq[too_fast[0]]:g} Hz: its period is '
                f'shorter than {MIN_PERIOD_S:g} s (a period of zero length for the model)')
        sup, out = _pressures(t, supply_pressure_pa, output_pressure_pa)
        return cls('pwm_commands', t, volts, duty_a, freq, sup, out)

    @property
    def period_s(self) -> np.ndarray:
        """Main PWM period of each value, s (inf without a main PWM: coil voltage, step)."""
        with np.errstate(divide='ignore'):
            return np.where(self.pwm_frequency_hz > 0.0, 1.0 / self.pwm_frequency_hz,
                            np.inf)
