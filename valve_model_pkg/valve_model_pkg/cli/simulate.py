"""``valve_simulate``: run a voltage-step or PWM experiment on the valve model.

Writes the trace as a CSV file of the measured-data format (read and written by
:mod:`valve_model_pkg.dataformat`): metadata lines, then ``t,voltage,current,position``
for a step; for PWM ``t,voltage,coil_voltage,current,position,duty,mass_flow``, where
``voltage`` is the main PWM input (supply voltage while the PWM is on, 0 while off),
``coil_voltage`` the voltage at the coil terminals (chopper and release pulse included)
and ``mass_flow`` eq. (12) on the suite's per-period moving average of the position (the
mean over the last complete PWM period, 0 before the first one ends:
:func:`valve_model_pkg.model.last_period_mean`). A PNG plot goes next
to it. Examples::

    valve_simulate --experiment step --voltage 24 -o fig4.csv
    valve_simulate --experiment step --voltage 15 -o fig5.csv
    valve_simulate --experiment pwm --duty 0.4 --pwm-frequency 50 --duration 0.1 \\
        -o fig6.csv
    valve_simulate --experiment pwm --electronics config/electronics/reduced_pwm_hold.yaml

Progress and results go to stderr. Exit status: 0 written, 2 refused input (a one-line
message naming the option, file or value), 1 a failure inside (e.g. writing the file).
"""
from __future__ import annotations

import argparse
import logging
import math
import sys
import time
from pathlib import Path

import numpy as np

from .. import dataformat
from ..model import (
    DEFAULT_SUPPLY_PRESSURE_PA, ElectronicsConfig, ParameterError, SimulationResult,
    ValveParameters, default_parameters_path, last_period_mean, load_electronics,
    load_parameters, orifice_mass_flow, simulate_pwm, simulate_step, step_metrics,
)
from .arguments import finite_float

__all__ = ['main', 'build_parser', 'write_csv', 'write_png', 'main_pwm_voltage']

_LOG = logging.getLogger('valve_simulate')

_DEFAULT_DURATION_S = {'step': 0.02, 'pwm': 0.1}


class _UsageError(Exception):
    """Bad command-line input found after parsing (reported like argparse errors)."""


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of ``valve_simulate``."""
    ap = argparse.ArgumentParser(
        prog='valve_simulate',
        description='Simulate the PWM solenoid valve model (Taghizadeh et al. 2009) and '
                    'write CSV (shared measured-data format) plus a PNG plot.')
    ap.add_argument('--experiment', choices=('step', 'pwm'), default='step',
                    help='step: voltage step on the bare coil (Fig. 4/5; through the drive '
                         'given with --electronics); pwm: main PWM '
                         'through the drive electronics (Fig. 6). Default: step.')
    ap.add_argument('--voltage', type=finite_float, default=24.0,
                    help='step voltage, or the driver supply voltage for pwm, V '
                         '(default 24)')
    ap.add_argument('--duty', type=finite_float, default=0.4,
                    help='main PWM duty cycle in [0, 1] (pwm; default 0.4)')
    ap.add_argument('--pwm-frequency', type=finite_float, default=50.0,
                    help='main PWM frequency, Hz (pwm; default 50)')
    pressure = ap.add_mutually_exclusive_group()
    pressure.add_argument('--supply-pressure', type=finite_float, default=None,
                          help='supply pressure, Pa gauge (default 400000 = 4 bar)')
    pressure.add_argument('--supply-bar', type=finite_float, default=None,
                          help='supply pressure in bar gauge (alternative)')
    ap.add_argument('--output-pressure', type=finite_float, default=0.0,
                    help='output port pressure, Pa gauge (default 0)')
    ap.add_argument('--duration', type=finite_float, default=None,
                    help='simulated time, s (default 0.02 for step, 0.1 for pwm)')
    ap.add_argument('--step-time', type=finite_float, default=0.0,
                    help='time the step voltage is switched on, s (step; default 0)')
    ap.add_argument('--params', type=Path, default=None,
                    help='parameter YAML (default: the packaged config/valve.yaml)')
    ap.add_argument('--allow-implausible', action='store_true',
                    help='accept parameter values outside their plausible ranges with a '
                         'warning (values beyond the numerically safe range are refused '
                         'anyway)')
    ap.add_argument('--electronics', type=Path, default=None, metavar='FILE',
                    help='drive electronics description (YAML, docs/model.md; default: '
                         "the paper's driver); a step then runs through them instead of "
                         'on the bare coil')
    ap.add_argument('--no-current-control', action='store_true',
                    help='pwm: switch off the peak and hold phases (current control)')
    ap.add_argument('--no-capacitor', action='store_true',
                    help='pwm: switch off the release voltage (capacitor pulse)')
    ap.add_argument('--sample-rate', type=finite_float, default=100e3,
                    help='output sampling rate, Hz (default 100000)')
    ap.add_argument('-o', '--out', type=Path, default=None,
                    help='CSV file to write (default valve_<experiment>.csv); the PNG is '
                         'written next to it with the suffix .png')
    ap.add_argument('--no-plot', action='store_true', help='do not write the PNG')
    ap.add_argument('-q', '--quiet', action='store_true', help='only errors on stderr')
    return ap


def main_pwm_voltage(result: SimulationResult) -> np.ndarray:
    """The main PWM input at each sample [V]: supply voltage while on, 0 while off.

    The first period starts with a rising edge at t = 0 (as :func:`simulate_pwm` drives it).
    """
    trace = result.trace
    period = 1.0 / trace.pwm_frequency_hz[0]
    phase = np.mod(result.t_s, period)
    # a sample a rounding error short of the next rising edge belongs to that edge
    phase[period - phase < 1e-9 * period] = 0.0
    return np.where(phase < trace.duty[0] * period, trace.supply_voltage_v[0], 0.0)


def write_csv(path: Path, result: SimulationResult, metadata: dict[str, object]) -> None:
    """Write ``result`` as a file of the measured-data format (metadata, header, rows)."""
    if result.trace.kind == 'pwm_commands':
        position_avg = last_period_mean(result.t_s, result.spool_position_m,
                                        1.0 / result.trace.pwm_frequency_hz[0])
        columns = {
            't': result.t_s, 'voltage': main_pwm_voltage(result),
            'coil_voltage': result.coil_voltage_v, 'current': result.coil_current_a,
            'position': result.spool_position_m,
            'duty': np.full_like(result.t_s, result.trace.duty[0]),
            'mass_flow': orifice_mass_flow(position_avg, result.supply_pressure_pa,
                                           result.output_pressure_pa, result.params)}
    else:
        columns = {'t': result.t_s, 'voltage': result.coil_voltage_v,
                   'current': result.coil_current_a, 'position': result.spool_position_m}
    dataformat.write_table(path, metadata, columns)


def write_png(path: Path, result: SimulationResult, title: str) -> None:
    """Plot voltage, current and position (with its PWM-period average) to ``path``."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    t_ms = result.t_s * 1e3
    fig, axes = plt.subplots(3, 1, sharex=True, figsize=(8, 7))
    pwm = result.trace.kind == 'pwm_commands'
    if pwm:
        axes[0].plot(t_ms, main_pwm_voltage(result), lw=0.8, color='grey',
                     label='main PWM input')
        axes[0].plot(t_ms, result.coil_voltage_v, lw=0.8, label='coil')
        axes[0].legend(loc='upper right', fontsize=8)
    else:
        axes[0].plot(t_ms, result.coil_voltage_v, lw=0.8)
    axes[0].set_ylabel('voltage (V)')
    axes[1].plot(t_ms, result.coil_current_a, lw=0.8, color='C1')
    axes[1].set_ylabel('current (A)')
    axes[2].plot(t_ms, result.spool_position_m * 1e3, lw=0.8, color='C2', label='position')
    if pwm:
        avg = last_period_mean(result.t_s, result.spool_position_m,
                               1.0 / result.trace.pwm_frequency_hz[0])
        axes[2].plot(t_ms, avg * 1e3, lw=1.0, color='C3', ls='--',
                     label='mean over the last complete PWM period')
        axes[2].legend(loc='upper right', fontsize=8)
    else:
        m = step_metrics(result)
        if math.isfinite(m.stroke_end_s):
            for ax in axes[1:]:
                ax.axvline(m.motion_start_s * 1e3, color='grey', lw=0.6, ls=':')
                ax.axvline(m.stroke_end_s * 1e3, color='grey', lw=0.6, ls='--')
            axes[1].plot(m.peak_time_s * 1e3, m.peak_current_a, 'kx')
            axes[1].annotate(f'{m.peak_current_a:.3f} A', (m.peak_time_s * 1e3,
                                                           m.peak_current_a),
                             textcoords='offset points', xytext=(6, -12), fontsize=8)
    axes[2].set_ylabel('position (mm)')
    axes[2].set_xlabel('time (ms)')
    for ax in axes:
        ax.grid(True, lw=0.3)
    axes[0].set_title(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def _electronics(args: argparse.Namespace) -> ElectronicsConfig:
    """The drive electronics: the --electronics file (or the default), with the switches."""
    electronics = ElectronicsConfig() if args.electronics is None \
        else load_electronics(args.electronics)
    if args.experiment == 'pwm' and (args.no_current_control or args.no_capacitor):
        electronics = electronics.replace(
            current_control=electronics.current_control and not args.no_current_control,
            negative_voltage=electronics.negative_voltage and not args.no_capacitor)
    return electronics


def _run(args: argparse.Namespace) -> int:
    if args.supply_bar is not None:
        supply_pa = args.supply_bar * 1e5
    elif args.supply_pressure is not None:
        supply_pa = args.supply_pressure
    else:
        supply_pa = DEFAULT_SUPPLY_PRESSURE_PA
    duration = args.duration if args.duration is not None else _DEFAULT_DURATION_S[
        args.experiment]
    if duration <= 0.0:
        raise _UsageError(f'--duration must be positive, got {duration!r}')
    if args.sample_rate <= 0.0:
        raise _UsageError(f'--sample-rate must be positive, got {args.sample_rate!r}')
    n_rows = duration * args.sample_rate
    if n_rows > 5e7:
        raise _UsageError(f'--duration x --sample-rate gives {n_rows:.3g} rows; '
                          'at most 5e7 are written')
    if args.experiment == 'step' and (args.no_current_control or args.no_capacitor):
        _LOG.info('step experiments drive the bare coil (or the --electronics given); '
                  '--no-current-control and --no-capacitor are ignored')
    electronics = _electronics(args)
    params_path = args.params if args.params is not None else default_parameters_path()
    params: ValveParameters = load_parameters(params_path,
                                              allow_implausible=args.allow_implausible)
    out = args.out if args.out is not None else Path(f'valve_{args.experiment}.csv')
    if out.parent and not out.parent.exists():
        raise _UsageError(f'output directory does not exist: {out.parent}')

    t0 = time.perf_counter()
    if args.experiment == 'step':
        _LOG.info('step %.3g V, supply %.4g Pa, %.4g s', args.voltage, supply_pa, duration)
        result = simulate_step(params, args.voltage, duration, supply_pa,
                               args.output_pressure, sample_rate_hz=args.sample_rate,
                               step_time_s=args.step_time,
                               electronics=electronics if args.electronics else None)
    else:
        _LOG.info('pwm duty %.3g at %.4g Hz, supply %.3g V, %.4g Pa, %.4g s', args.duty,
                  args.pwm_frequency, args.voltage, supply_pa, duration)
        result = simulate_pwm(params, electronics, args.duty, args.pwm_frequency, duration,
                              supply_pa, args.output_pressure, supply_voltage_v=args.voltage,
                              sample_rate_hz=args.sample_rate)
    wall = time.perf_counter() - t0
    _LOG.info('simulated %.4g s in %.3g s wall (%d RK4 steps)', duration, wall,
              result.n_steps)

    meta: dict[str, object] = {
        'experiment': args.experiment,
        'valve': 'valve_simulate model (Taghizadeh et al. 2009)',
        'params': str(params_path),
        'supply_pressure_pa': f'{supply_pa:.10g}',
        'output_pressure_pa': f'{args.output_pressure:.10g}',
        'supply_temperature_k': f'{params.supply_temperature_k:.10g}',
        'sample_rate_hz': f'{args.sample_rate:.10g}',
    }
    if args.electronics is not None:
        meta['electronics'] = str(args.electronics)
    if args.experiment == 'step':
        m = step_metrics(result)
        meta.update({'step_voltage_v': f'{args.voltage:.10g}',
                     'motion_start_s': f'{m.motion_start_s:.6g}',
                     'stroke_end_s': f'{m.stroke_end_s:.6g}',
                     'peak_current_a': f'{m.peak_current_a:.6g}'})
        _LOG.info('motion starts %.4g ms, stroke ends %.4g ms, local current peak %.4g A',
                  m.motion_start_s * 1e3, m.stroke_end_s * 1e3, m.peak_current_a)
        title = (f'{args.voltage:g} V step, supply {supply_pa / 1e5:g} bar: stroke end '
                 f'{m.stroke_end_s * 1e3:.3g} ms, peak {m.peak_current_a:.3g} A')
    else:
        meta.update({'pwm_frequency_hz': f'{args.pwm_frequency:.10g}',
                     'duty': f'{args.duty:.10g}',
                     'supply_voltage_v': f'{args.voltage:.10g}',
                     'current_control': str(electronics.current_control).lower(),
                     'capacitor': str(electronics.negative_voltage).lower()})
        if len(result.period_avg_position_m):
            _LOG.info('average position over the last period %.4g mm (%.1f %% of stroke)',
                      result.period_avg_position_m[-1] * 1e3,
                      100 * result.period_avg_position_m[-1] / params.stroke_m)
        title = (f'PWM {args.duty:g} at {args.pwm_frequency:g} Hz, supply '
                 f'{supply_pa / 1e5:g} bar, current control '
                 f'{"on" if electronics.current_control else "off"}, release '
                 f'{electronics.release if electronics.negative_voltage else "off"}')
    write_csv(out, result, meta)
    _LOG.info('wrote %s (%d rows)', out, len(result.t_s))
    if not args.no_plot:
        png = out.with_suffix('.png')
        write_png(png, result, title)
        _LOG.info('wrote %s', png)
    return 0


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``valve_simulate``; returns the exit status (0 ok, 2 refused input,
    1 a failure inside)."""
    parser = build_parser()
    args = parser.parse_args(argv)  # exits 2 with a usage message on syntax errors
    # own handler on the current stderr (not basicConfig: main may run more than once)
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(logging.Formatter('valve_simulate: %(message)s'))
    _LOG.handlers[:] = [handler]
    _LOG.propagate = False
    _LOG.setLevel(logging.WARNING if args.quiet else logging.INFO)
    try:
        return _run(args)
    except (_UsageError, ParameterError, FileNotFoundError, IsADirectoryError,
            PermissionError) as err:
        # refused input: one line naming the option, file or value (argparse's own errors,
        # raised before this, carry the usage as well)
        print(f'valve_simulate: error: {err}', file=sys.stderr)
        return 2
    except (OSError, ArithmeticError) as err:
        # writing the file, or the model failing on accepted (--allow-implausible) values
        print(f'valve_simulate: error: {type(err).__name__}: {err}' if isinstance(
            err, ArithmeticError) else f'valve_simulate: error: {err}', file=sys.stderr)
        return 1


if __name__ == '__main__':
    sys.exit(main())
