"""The one result type of the model's simulations, and the figures read from it.

:func:`~valve_model_pkg.model.simulate_trace_batch` returns a :class:`SimulationResult`
for a batch of runs (a leading run axis on every per-run array);
:func:`~valve_model_pkg.model.simulate_step`, :func:`~valve_model_pkg.model.simulate_pwm`
and :meth:`SimulationResult.run` return the same type for one run (no run axis).
"""
from __future__ import annotations

import dataclasses

import numpy as np

from .averaging import hold_period_means, moving_average
from .electronics import ElectronicsConfig
from .mechanics import MODE_CLOSED, MODE_OPEN
from .orifice import orifice_mass_flow
from .parameters import ParameterError, ValveParameters
from .trace import InputTrace

__all__ = ['SimulationResult', 'StepMetrics', 'step_metrics', 'closing_time']

#: Window of the trailing moving average of the position of an input without a main PWM
#: period (a step, a coil-voltage trace), s.
STEP_AVERAGE_WINDOW_S = 0.02

_PER_RUN = ('coil_voltage_v', 'coil_current_a', 'spool_position_m', 'spool_velocity_m_s',
            'coil_temperature_rise_k', 'mode')


@dataclasses.dataclass(frozen=True)
class SimulationResult:
    """Sampled response of one run or of a batch of runs.

    Shapes: ``t_s`` is (n_samples,). Every per-run array has a leading run axis in a batch
    (``simulate_trace_batch``): (n_runs, n_samples), (n_runs, n_periods), (n_runs,); a
    single run (``simulate_step``, ``simulate_pwm``, :meth:`run`) has none: (n_samples,),
    (n_periods,), scalars.

    Attributes
    ----------
    t_s : numpy.ndarray, shape (n_samples,)
        Sample times, s (empty for a run without samples).
    coil_voltage_v : numpy.ndarray, shape ([n_runs,] n_samples)
        Coil terminal voltage, V.
    coil_current_a : numpy.ndarray, shape ([n_runs,] n_samples)
        Coil terminal current, A (eq. 5; with eddy currents the terminal, not the
        magnetising, current).
    spool_position_m : numpy.ndarray, shape ([n_runs,] n_samples)
        Spool position x, m (0 closed, ``stroke_m`` open).
    spool_velocity_m_s : numpy.ndarray, shape ([n_runs,] n_samples)
        Spool velocity, m/s.
    coil_temperature_rise_k : numpy.ndarray, shape ([n_runs,] n_samples)
        Coil temperature above the reference (``coil_heating``), K; always instantaneous.
    mode : numpy.ndarray of int, shape ([n_runs,] n_samples)
        Mechanical mode (``mechanics.MODE_*``: 0 moving, 1 closed stop, 2 open stop,
        3 stuck); always instantaneous.
    period_end_s, period_avg_position_m : numpy.ndarray, shape ([n_runs,] n_periods), or None
        End of each completed main PWM period, s, and the exact mean spool position over
        it, m (integrated by the kernel); None unless asked for (``n_periods``). In a
        batch, a run that completed fewer periods than the longest has NaN after its last.
    sampling : str
        ``'instant'`` or ``'interval_mean'`` (current, voltage and position averaged over
        each sample interval, velocity = change of position over it).
    n_steps, n_forced_steps : int or numpy.ndarray of int, shape ([n_runs])
        RK4 steps taken (incl. redone event steps), and the steps forced by the kernel's
        no-progress guard (0 unless the kernel has a bug).
    trace : InputTrace or tuple of InputTrace
        The input: one trace shared by all runs, or one per run.
    electronics : ElectronicsConfig
        The drive electronics (``ElectronicsConfig.off()`` for a bare coil).
    params : ValveParameters, tuple of ValveParameters or numpy.ndarray
        The parameter sets: one (single run), one per run, or the matrix
        (n_runs, len(PARAMETER_FIELDS)) of ``to_vector`` rows a batch was given.
    supply_pressure_pa, output_pressure_pa : float or numpy.ndarray, shape ([n_runs])
        Gauge pressures, Pa (at t = 0 if the trace carries their course).
    """

    t_s: np.ndarray
    coil_voltage_v: np.ndarray
    coil_current_a: np.ndarray
    spool_position_m: np.ndarray
    spool_velocity_m_s: np.ndarray
    coil_temperature_rise_k: np.ndarray
    mode: np.ndarray
    period_end_s: np.ndarray | None
    period_avg_position_m: np.ndarray | None
    sampling: str
    n_steps: int | np.ndarray
    n_forced_steps: int | np.ndarray
    trace: InputTrace | tuple[InputTrace, ...]
    electronics: ElectronicsConfig
    params: ValveParameters | tuple[ValveParameters, ...] | np.ndarray
    supply_pressure_pa: float | np.ndarray
    output_pressure_pa: float | np.ndarray

    @property
    def is_batch(self) -> bool:
        """True if the per-run arrays have a leading run axis."""
        return self.coil_current_a.ndim == 2

    @property
    def n_runs(self) -> int:
        """Number of runs (1 for a single run)."""
        return self.coil_current_a.shape[0] if self.is_batch else 1

    def run(self, index: int) -> SimulationResult:
        """Run ``index`` of a batch as a single-run result (no run axis).

        Its period arrays hold the periods that run completed (no NaN padding).
        """
        if not self.is_batch:
            raise ParameterError('run() selects a run of a batch; this is a single run')
        r = range(self.n_runs)[index]
        periods = {}
        if self.period_end_s is not None:
            done = np.isfinite(self.period_end_s[r])
            periods = {'period_end_s': self.period_end_s[r][done],
                       'period_avg_position_m': self.period_avg_position_m[r][done]}
        if isinstance(self.params, tuple):
            params = self.params[r]
        else:
            params = ValveParameters.from_vector(self.params[r])
        return dataclasses.replace(
            self, **{name: getattr(self, name)[r] for name in _PER_RUN}, **periods,
            n_steps=int(self.n_steps[r]), n_forced_steps=int(self.n_forced_steps[r]),
            trace=self._trace_of(r), params=params,
            supply_pressure_pa=float(self.supply_pressure_pa[r]),
            output_pressure_pa=float(self.output_pressure_pa[r]))

    def _trace_of(self, r: int) -> InputTrace:
        return self.trace[r] if isinstance(self.trace, tuple) else self.trace

    def _periods_of(self, value: np.ndarray | None, r: int | None) -> np.ndarray | None:
        """A period array of run ``r`` of a batch, without its NaN padding."""
        if value is None or r is None:
            return value
        return value[r][np.isfinite(self.period_end_s[r])]

    def _position_avg_rows(self) -> list[np.ndarray]:
        if not self.is_batch:
            return [_position_avg(self.t_s, self.spool_position_m, self.trace,
                                  self.period_end_s, self.period_avg_position_m)]
        return [_position_avg(self.t_s, self.spool_position_m[r], self._trace_of(r),
                              self._periods_of(self.period_end_s, r),
                              self._periods_of(self.period_avg_position_m, r))
                for r in range(self.n_runs)]

    @property
    def position_avg_m(self) -> np.ndarray:
        """The suite's moving average of the spool position at each sample, m.

        Under a main PWM command: the exact mean over the last complete period, held
        (0 before the first ends; :func:`~valve_model_pkg.model.last_period_mean`), from
        the period means, so a PWM run needs ``n_periods``. Without a main PWM period (a
        step, a coil-voltage trace): a trailing window of :data:`STEP_AVERAGE_WINDOW_S`
        (:func:`~valve_model_pkg.model.moving_average`). Shape ([n_runs,] n_samples).
        """
        rows = self._position_avg_rows()
        return np.array(rows) if self.is_batch else rows[0]

    @property
    def mass_flow_kg_s(self) -> np.ndarray:
        """Mass flow from :attr:`position_avg_m`, eq. (12), kg/s; shape as the samples.

        With the pressures in force at each sample (the trace's course, if it has one).
        """
        if not self.is_batch:
            supply, output = self.supply_pressure_pa, self.output_pressure_pa
            if self.trace.has_pressures:  # the pressures in force at each sample
                supply, output = self.trace.pressures_at(self.t_s)
            return orifice_mass_flow(self.position_avg_m, supply, output, self.params)
        return np.array([self.run(r).mass_flow_kg_s for r in range(self.n_runs)])

    @property
    def steady_position_m(self) -> float | np.ndarray:
        """Mean position over the last completed main PWM period, m (NaN if none).

        The static maps' value (Section 5); shape ([n_runs]). Needs ``n_periods``.
        """
        if self.period_avg_position_m is None:
            raise ParameterError('steady_position_m needs the period means: simulate '
                                 'with n_periods')
        runs = range(self.n_runs) if self.is_batch else [None]
        rows = [self._periods_of(self.period_avg_position_m, r) for r in runs]
        last = [float(row[-1]) if row.size else np.nan for row in rows]
        return np.array(last) if self.is_batch else last[0]


def _position_avg(t_s: np.ndarray, position_m: np.ndarray, trace: InputTrace,
                  period_end_s: np.ndarray | None,
                  period_avg_position_m: np.ndarray | None) -> np.ndarray:
    """:attr:`SimulationResult.position_avg_m` of one run."""
    if trace.kind != 'pwm_commands':
        if t_s.size > 1:
            return moving_average(t_s, position_m, STEP_AVERAGE_WINDOW_S)
        return position_m.copy()
    if period_end_s is None:
        raise ParameterError('position_avg_m of a PWM run needs its period means: a '
                             'constant command simulated with n_periods')
    return hold_period_means(t_s, period_end_s, period_avg_position_m,
                             float(trace.period_s[0]))


@dataclasses.dataclass(frozen=True)
class StepMetrics:
    """Opening figures of a step response (Fig. 4 / Fig. 5).

    Attributes
    ----------
    motion_start_s : float
        First time the spool leaves the closed stop, s (nan if it never moves).
    stroke_end_s : float
        First time it reaches the open stop, s (nan if never).
    peak_current_a : float
        Local current peak during the motion (between start and stroke end), A.
    peak_time_s : float
        Time of that peak, s.
    final_current_a : float
        Current at the end of the trace, A.
    """

    motion_start_s: float
    stroke_end_s: float
    peak_current_a: float
    peak_time_s: float
    final_current_a: float


def step_metrics(result: SimulationResult) -> StepMetrics:
    """Start of motion, end of stroke and the local current peak of a step response.

    The start of motion is the first sample at which the spool has left the closed stop
    (mechanical mode, exact to one sample); the stroke end is the first sample on the open
    stop; the peak is the largest current sample between the two. ``result`` is a single
    run (``simulate_step``, or ``batch.run(r)``).
    """
    t, i, mode = result.t_s, result.coil_current_a, result.mode
    left = np.nonzero(mode != MODE_CLOSED)[0]
    if len(left) == 0:
        return StepMetrics(np.nan, np.nan, np.nan, np.nan, float(i[-1]))
    k0 = int(left[0])
    at_open = np.nonzero(mode[k0:] == MODE_OPEN)[0]
    if len(at_open) == 0:
        return StepMetrics(float(t[k0]), np.nan, np.nan, np.nan, float(i[-1]))
    k1 = k0 + int(at_open[0])
    kp = k0 + int(np.argmax(i[k0:k1 + 1]))
    return StepMetrics(float(t[k0]), float(t[k1]), float(i[kp]), float(t[kp]), float(i[-1]))


def closing_time(result: SimulationResult, falling_edge_s: float) -> float:
    """Time from a main PWM falling edge until the spool is back on the closed stop, s.

    ``result`` is a single run; NaN if the spool does not move after the edge or does not
    close again.
    """
    t, x = result.t_s, result.spool_position_m
    after = np.nonzero((t >= falling_edge_s) & (x <= 0.0))[0]
    moved = np.nonzero((t >= falling_edge_s) & (x > 0.0))[0]
    if len(moved) == 0 or len(after) == 0:
        return np.nan
    closed = after[after > moved[0]]
    return float(t[closed[0]] - falling_edge_s) if len(closed) else np.nan
