"""``valve_identify``: identify the valve from measured data and close the loop.

Usage::

    valve_identify --fit FILE... [--validate FILE...] [--params YAML] -o DIR

FILE is a ``step``, ``pwm`` or ``operation`` record of the measured-data format or a
rosbag2 bag directory recorded from the suite (``/valve/state``). ``pwm`` and ``operation``
records and PWM bags run the model's drive electronics from the commands and compare like
with like (interval means); one such record without ``--validate`` has its last 30 % held
out for validation (docs/identification.md). The supply pressure comes from each file.
Progress goes to stderr; DIR receives report.json, report.md with PNG plots and
params.yaml (loadable by valve_simulate / valve_map). Exit status: 0 on success, 2 on
refused input (one line naming file, line and reason), 1 on a failure inside.
"""
from __future__ import annotations

import argparse
import logging
import sys
import time

__all__ = ['main']


class _MapAction(argparse.Action):
    """Collects ``--map`` entries; a malformed one or a role given twice is a usage error."""

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace,
                 values: object, option_string: str | None = None) -> None:
        from ..identification.topic_map import parse_topic_map
        entries = list(getattr(namespace, self.dest) or []) + [str(values)]
        try:
            parse_topic_map(entries)
        except ValueError as err:
            parser.error(f'--map {err}')
        setattr(namespace, self.dest, entries)


def _parser() -> argparse.ArgumentParser:
    from valve_model_pkg.interface import TOPIC_STATE

    p = argparse.ArgumentParser(
        prog='valve_identify',
        description='Identify the valve parameters from measured current (paper Section 4), '
        'study the residual, and add the physical effect the model lacks if the data '
        'prove it.')
    p.add_argument('--fit', nargs='+', required=True, metavar='FILE',
                   help='CSV files or rosbag2 bag directories to fit on')
    p.add_argument('--validate', nargs='+', default=[], metavar='FILE',
                   help='hold-out files for validation and effect selection')
    p.add_argument('--params', metavar='YAML', default=None,
                   help='known parameters (Table 1, orifice); default: the packaged set')
    p.add_argument('--allow-implausible', action='store_true',
                   help='accept parameter values outside their plausible ranges with a '
                        'warning (values beyond the numerically safe range are refused '
                        'anyway)')
    p.add_argument('-o', '--out', required=True, metavar='DIR', help='output directory')
    p.add_argument('--topic', default='/' + TOPIC_STATE, help='valve state topic in bags')
    p.add_argument('--valve', default=None, help='frame_id of the valve in multi-valve bags')
    p.add_argument('--map', action=_MapAction, default=[], metavar='ROLE=TOPIC[.FIELD]',
                   help='read bags from your own topics instead of the suite\'s valve state '
                        '(repeatable): current=/coil/current (a Float32/Float64 data), '
                        'duty=/valve/duty_command.duty (a field, nested with dots); roles: '
                        'current or current_mean with voltage (step) or with duty and '
                        'pwm_frequency (operation), coil_voltage_mean, supply_voltage, '
                        'supply_pressure, output_pressure (the last four and pwm_frequency '
                        'may be numbers)')
    p.add_argument('--no-diagnosis', action='store_true',
                   help='stop after the baseline fit (no effect search)')
    p.add_argument('--quick', action='store_true',
                   help='smaller search effort (for tests and previews)')
    p.add_argument('--no-plots', action='store_true', help='skip the PNG plots')
    p.add_argument('--quiet', action='store_true', help='no progress output')
    from valve_model_pkg.instruments import add_import_options
    add_import_options(p)
    return p


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``valve_identify``."""
    args = _parser().parse_args(argv)
    logging.basicConfig(level=logging.WARNING, format='%(levelname)s: %(message)s')
    from ..errors import IdentificationError, InstrumentFormatError, MeasurementFormatError
    from ..instruments import options_from_args, records_for
    from ..identification.readers import read_measurements
    from ..identification.topic_map import parse_topic_map
    from ..identification.pipeline import IdentifySettings, identify
    from ..identification.report import write_report
    from ..model.parameters import ParameterError, load_parameters

    start = time.perf_counter()

    def progress(msg: str) -> None:
        if not args.quiet:
            print(f'[{time.perf_counter() - start:6.1f} s] {msg}', file=sys.stderr,
                  flush=True)

    try:
        mapping = parse_topic_map(args.map) or None
        imports = options_from_args(args)
        fit = read_measurements(records_for(args.fit, imports, args.out, progress),
                                topic=args.topic, valve=args.valve, mapping=mapping)
        val = read_measurements(records_for(args.validate, imports, args.out, progress),
                                topic=args.topic, valve=args.valve, mapping=mapping)
        for m in fit + val:
            if m.supply_pressure_pa is None:
                raise MeasurementFormatError(
                    m.source, None, 'metadata lacks supply_pressure_pa (gauge, Pa)')
            for note in m.notes:
                progress(f'{m.name}: {note}')
        base = load_parameters(args.params, allow_implausible=args.allow_implausible)
    except (MeasurementFormatError, InstrumentFormatError, ParameterError,
            FileNotFoundError) as err:
        print(f'valve_identify: error: {err}', file=sys.stderr)
        return 2
    settings = IdentifySettings(diagnose=not args.no_diagnosis)
    if args.quick:
        settings = IdentifySettings.quick(diagnose=not args.no_diagnosis)
    try:
        ident = identify(fit, val, base, settings, progress=progress)
        rep = write_report(ident, args.out, plots=not args.no_plots)
    except IdentificationError as err:
        print(f'valve_identify: error: {err}', file=sys.stderr)
        return 1
    d = rep['diagnosis']
    b, a = rep['baseline'], rep['augmented']
    key = 'validation' if b['validation'] else 'fit'
    progress(f'{key} RMSE baseline {1e3 * b[key]["rmse"]:.2f} mA -> augmented '
             f'{1e3 * a[key]["rmse"]:.2f} mA; effect: {d["effect"] if d else "-"}')
    progress(f'wrote {args.out}/report.json, report.md, params.yaml')
    return 0


if __name__ == '__main__':
    sys.exit(main())
