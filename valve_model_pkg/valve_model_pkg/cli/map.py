"""valve_map: generate the static duty map (paper Section 5, Figs. 8 and 9).

Simulates x_avg / x_max at periodic steady state against duty on a grid of supply
pressures and PWM frequencies, drive electronics on, writes the versioned map file, draws
Fig. 8 (50 Hz, all pressures) and Fig. 9 (4 bar, all frequencies) and prints the dead band,
saturation duty and effective width of every curve.

Examples::

    valve_map                                   # paper grid -> ./valve_map.json + PNGs
    valve_map -o out/map.json --params my_valve.yaml
    valve_map --electronics my_driver.yaml      # the valve behind another drive
    valve_map --duty-step 0.005 --pressures-bar 0 1 2 3 4 5 6 --frequencies 20 50 100
    valve_map --show valve_model_pkg/config/valve_map.json   # summary + figures only

Exit status: 0 done, 2 refused input (parameter file, grid, map file; one line naming
it), 1 a failure inside (generation, writing the map).
"""
from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

__all__ = ['main', 'summary_table', 'trend_summary']


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog='valve_map', description=__doc__.split('\n\n')[0],
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog='Pressures are gauge. Duties and positions are printed in percent.')
    p.add_argument('-o', '--out', default='valve_map.json',
                   help='map file to write (default: %(default)s)')
    p.add_argument('--output', dest='out', help=argparse.SUPPRESS)  # the old spelling
    p.add_argument('--params', default='',
                   help="valve parameter YAML (default: the paper's, config/valve.yaml)")
    p.add_argument('--allow-implausible', action='store_true',
                   help='accept parameter values outside their plausible ranges with a '
                        'warning (values beyond the numerically safe range are refused '
                        'anyway)')
    p.add_argument('--duty-step', type=float, default=0.01,
                   help='duty grid step as a fraction (default: %(default)s = 1 %%)')
    p.add_argument('--pressures-bar', type=float, nargs='+', default=[0.0, 2.0, 4.0, 6.0],
                   help='supply pressures, bar gauge (default: %(default)s)')
    p.add_argument('--frequencies', type=float, nargs='+', default=[20.0, 50.0, 100.0, 200.0],
                   help='PWM frequencies, Hz (default: %(default)s)')
    p.add_argument('--output-pressure-bar', type=float, default=0.0,
                   help='output port pressure, bar gauge (default: %(default)s)')
    p.add_argument('--supply-voltage', type=float, default=24.0,
                   help='drive supply voltage, V (default: %(default)s)')
    p.add_argument('--electronics', default='', metavar='FILE',
                   help="drive electronics description (YAML, docs/model.md; default: the "
                        "paper's driver)")
    p.add_argument('--no-current-control', action='store_true',
                   help='switch the peak and hold phases (current control) off')
    p.add_argument('--no-negative-voltage', action='store_true',
                   help='switch the release voltage (capacitor pulse) off')
    p.add_argument('--tolerance', type=float, default=1e-4,
                   help='steady-state tolerance, fraction of x_max (default: %(default)s)')
    p.add_argument('--max-periods', type=int, default=400,
                   help='periods after which a point counts as unconverged (default: '
                        '%(default)s)')
    p.add_argument('--no-refine', action='store_true',
                   help='do not refine the dead band / saturation edges by bisection')
    p.add_argument('--edge-tolerance', type=float, default=1e-3,
                   help='edge refinement bracket, duty fraction (default: %(default)s)')
    p.add_argument('--workers', type=int, default=None,
                   help='worker processes (default: one per core)')
    p.add_argument('--fig-dir', default=None,
                   help='directory for fig8_pressures.png / fig9_frequencies.png (default: '
                        'next to the map file)')
    p.add_argument('--no-figures', action='store_true', help='do not draw the figures')
    p.add_argument('--fig8-frequency', type=float, default=50.0,
                   help='frequency of Fig. 8, Hz (default: %(default)s)')
    p.add_argument('--fig9-pressure-bar', type=float, default=4.0,
                   help='pressure of Fig. 9, bar (default: %(default)s)')
    p.add_argument('--show', metavar='MAP', default=None,
                   help='do not generate: read MAP, print its summary and draw its figures')
    p.add_argument('-q', '--quiet', action='store_true', help='no progress display')
    return p


def summary_table(duty_map) -> str:  # noqa: ANN001 - DutyMap
    """One line per curve: dead band, opening, saturation, width (grid and refined)."""
    lines = ['  f [Hz]  p [bar]  dead band  edge    opens  saturation  edge    width  '
             'refined width  steady periods (max)',
             '  ------  -------  ---------  ------  -----  ----------  ------  -----  '
             '-------------  --------------------']

    islands: list[str] = []

    def pct(v: float) -> str:
        return '   -  ' if v is None or (isinstance(v, float) and math.isnan(v)) \
            else f'{v * 100:5.1f}%'
    for i, f in enumerate(duty_map.pwm_frequencies_hz):
        for j, p in enumerate(duty_map.supply_pressures_pa):
            ft = duty_map.features(i, j)
            db = math.nan if duty_map.dead_band_edges is None else duty_map.dead_band_edges[i, j]
            se = math.nan if duty_map.saturation_edges is None \
                else duty_map.saturation_edges[i, j]
            rw = se - db if not (math.isnan(se) or math.isnan(db)) else math.nan
            per = '' if duty_map.periods is None else f'{int(duty_map.periods[i, j].max()):d}'
            lines.append(f'  {f:6g}  {p / 1e5:7g}  {pct(ft.dead_band_duty):>9}  {pct(db)}  '
                         f'{pct(ft.opening_duty)}  {pct(ft.saturation_duty):>10}  {pct(se)}  '
                         f'{pct(ft.effective_width)}  {pct(rw):>13}  {per:>20}')
            if ft.first_saturation_duty < ft.saturation_duty:
                islands.append(f'  island: {f:g} Hz, {p / 1e5:g} bar reaches the open stop at '
                               f'{ft.first_saturation_duty:.0%} but leaves it again below '
                               f'{ft.saturation_duty:.0%}')
    return '\n'.join(lines + islands)


def trend_summary(duty_map) -> str:  # noqa: ANN001 - DutyMap
    """The Fig. 8 / Fig. 9 trends in words: shift with pressure, narrowing with frequency."""
    import numpy as np
    out = []
    for i, f in enumerate(duty_map.pwm_frequencies_hz):
        feats = [duty_map.features(i, j) for j in range(duty_map.supply_pressures_pa.size)]
        db = [x.dead_band_duty for x in feats]
        sat = [x.saturation_duty for x in feats]
        width = [x.effective_width for x in feats]
        shift = 'shifts up' if np.all(np.diff(db) >= 0) and np.all(np.diff(sat) >= 0) \
            else 'does not shift monotonically'
        out.append(f'{f:g} Hz: with pressure the range {shift}; dead band '
                   + ' -> '.join(f'{v:.0%}' for v in db) + ', width '
                   + ' -> '.join(f'{v:.0%}' for v in width))
    for j, p in enumerate(duty_map.supply_pressures_pa):
        width = [duty_map.features(i, j).effective_width
                 for i in range(duty_map.pwm_frequencies_hz.size)]
        trend = 'narrows' if np.all(np.diff(width) < 0) else 'does not narrow monotonically'
        out.append(f'{p / 1e5:g} bar: with frequency the range {trend}: width '
                   + ' -> '.join(f'{v:.0%}' for v in width))
    return '\n'.join(out)


class _Progress:
    def __init__(self, quiet: bool) -> None:
        self.quiet = quiet
        self.tty = sys.stderr.isatty()
        self.t0 = time.perf_counter()

    def __call__(self, done: int, total: int, message: str) -> None:
        if self.quiet:
            return
        frac = done / total if total else 1.0
        bar = '#' * int(30 * frac)
        line = f'[{bar:<30}] {frac:6.1%} {time.perf_counter() - self.t0:6.1f} s  {message}'
        if self.tty:
            print('\r' + line[:150].ljust(150), end='', file=sys.stderr, flush=True)
            if done >= total:
                print(file=sys.stderr)
        else:
            print(line, file=sys.stderr, flush=True)


def _figures(duty_map, args, out_dir: Path) -> list[Path]:  # noqa: ANN001
    from valve_model_pkg.maps.plots import plot_frequencies, plot_pressures
    paths = []
    out_dir.mkdir(parents=True, exist_ok=True)
    try:
        paths.append(plot_pressures(duty_map, out_dir / 'fig8_pressures.png',
                                    args.fig8_frequency))
    except KeyError as err:
        print(f'valve_map: Fig. 8 not drawn: {err.args[0]}', file=sys.stderr)
    try:
        paths.append(plot_frequencies(duty_map, out_dir / 'fig9_frequencies.png',
                                      args.fig9_pressure_bar * 1e5))
    except KeyError as err:
        print(f'valve_map: Fig. 9 not drawn: {err.args[0]}', file=sys.stderr)
    return paths


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``valve_map``; returns the exit code."""
    argv = sys.argv[1:] if argv is None else list(argv)
    args = _parser().parse_args(argv)
    args.command = ' '.join(['valve_map'] + argv)
    from valve_model_pkg.maps import MapError, MapGenerationError, load_map
    try:
        if args.show:
            dmap = load_map(args.show)
            out_dir = Path(args.fig_dir) if args.fig_dir else Path(args.show).resolve().parent
        else:
            dmap = _generate(args)
            out_dir = Path(args.fig_dir) if args.fig_dir else \
                Path(args.out).resolve().parent
    except (MapGenerationError, _WriteError) as err:
        print(f'valve_map: error: {err}', file=sys.stderr)
        return 1
    except (MapError, ValueError, OSError) as err:
        # refused input: the parameter file, the grid or the map to show
        print(f'valve_map: error: {err}', file=sys.stderr)
        return 2
    print(summary_table(dmap))
    print()
    print(trend_summary(dmap))
    for note in dmap.notes:
        print(f'note: {note}')
    if not args.no_figures:
        for path in _figures(dmap, args, out_dir):
            print(f'wrote {path}')
    return 0


class _WriteError(Exception):
    """The generated map could not be written (a failure inside, not refused input)."""


def _generate(args: argparse.Namespace):  # noqa: ANN202 - DutyMap
    import dataclasses

    from valve_model_pkg.maps.generation import MapGrid, generate_map
    from valve_model_pkg.maps.steady_state import SteadyStateCriterion
    from valve_model_pkg.model import ElectronicsConfig, load_electronics, load_parameters
    params = load_parameters(args.params or None, allow_implausible=args.allow_implausible)
    base = load_electronics(args.electronics) if args.electronics else ElectronicsConfig()
    electronics = dataclasses.replace(
        base, current_control=base.current_control and not args.no_current_control,
        negative_voltage=base.negative_voltage and not args.no_negative_voltage)
    grid = MapGrid.regular(args.duty_step, [p * 1e5 for p in args.pressures_bar],
                           args.frequencies, args.output_pressure_bar * 1e5)
    criterion = SteadyStateCriterion(tolerance=args.tolerance,
                                     max_periods=max(args.max_periods, 4))
    progress = _Progress(args.quiet)
    dmap, stats = generate_map(params, electronics, grid, criterion=criterion,
                               supply_voltage_v=args.supply_voltage,
                               refine_edges=not args.no_refine,
                               edge_tolerance=args.edge_tolerance, progress=progress,
                               threads=args.workers,
                               generator={'program': 'valve_map',
                                          'params_file': args.params or 'config/valve.yaml',
                                          'electronics_file': args.electronics or 'default',
                                          'command': args.command})
    try:
        path = dmap.save(args.out)
    except OSError as err:
        raise _WriteError(f'cannot write {args.out}: {err}') from err
    print(f'wrote {path}: {grid.n_points} grid points in {stats.wall_s:.2f} s '
          f'({stats.runs} points simulated, {stats.simulated_s:.1f} s of model time, '
          f'{stats.threads} workers; '
          f'{stats.unconverged} unconverged, {stats.subharmonic} sub-harmonic)')
    return dmap


if __name__ == '__main__':
    sys.exit(main())
