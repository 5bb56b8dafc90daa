"""``valve_identify``: identify the valve from measured data and close the loop.

Usage::

    valve_identify --fit FILE... [--validate FILE...] [--params YAML] -o DIR
                   [--quick] [--no-diagnosis] [--effects EFFECT...] [--seed N]
                   [--route auto|mean-voltage|electronics]
                   [--threads N] [--no-plots] [--topic TOPIC] [--valve NAME]
                   [--map ROLE=TOPIC[.FIELD]...] [--voltage CH --current CH ...]
                   [--electronics YAML [--fit-electronics]
                    | --choose-electronics [auto|always|never]]

FILE is a ``step``, ``pwm`` or ``operation`` record of the measured-data format, a
rosbag2 bag directory (the suite's ``/valve/state``, or a user's own topics with
``--map``) or an instrument export (imported with the options of ``valve_import`` into
``DIR/imported/``). ``pwm`` and ``operation``
records and PWM bags run the model's drive electronics from the commands and compare like
with like (interval means); when every such record carries the mean coil voltage
(``coil_voltage_mean``), the valve may be fitted around the electronics through it
instead: the data choose the route that describes the records better (``--route`` forces
one), and the report says which route was taken, why, and the other route's error. One
such record without ``--validate`` has its last 30 % held out for validation
(docs/identification.md). The supply pressure comes from each file.
Progress goes to stderr; DIR receives report.json, report.md with PNG plots and
params.yaml (loadable by valve_simulate / valve_map), and for records through the drive
electronics electronics.yaml (the electronics identified with it, for ``--electronics``).
Without ``--electronics`` the electronics have the suite's own form with their constants
fitted, and the form (peak end, hold, release) is chosen by the data when the model
through the suite's form misses the record by three times the noise or more
(``--choose-electronics always`` chooses it every time, ``never`` keeps the suite's form);
with it, the file's form and constants are used as given (``--fit-electronics``: its
constants are start values of their fit). Exit status: 0 on success, 2 on
refused input (one line naming file, line and reason), 1 on a failure inside.

The options are parsed into one :class:`~valve_model_pkg.identification.IdentifySettings`
(:func:`settings_from_args`) and handed to
:func:`~valve_model_pkg.identification.identify`, as a Python user would.
"""
from __future__ import annotations

import argparse
import logging
import sys
import time
from typing import TYPE_CHECKING

from .arguments import positive_int

if TYPE_CHECKING:
    from ..identification import IdentifySettings

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
    from valve_model_pkg.identification.mean_voltage import ROUTE_CHOICES
    from valve_model_pkg.interface import TOPIC_STATE
    from valve_model_pkg.model.parameters import EFFECTS

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
    p.add_argument('--effects', nargs='+', default=None, metavar='EFFECT',
                   choices=list(EFFECTS),
                   help='candidate effects (default: all of ' + ', '.join(EFFECTS) + ')')
    p.add_argument('--quick', action='store_true',
                   help='smaller search effort (for tests and previews)')
    p.add_argument('--route', choices=ROUTE_CHOICES, default='auto',
                   help='how records through the drive electronics are fitted: auto (the '
                        'data choose when they carry both the mean coil voltage and the PWM '
                        'commands), mean-voltage (around the electronics through '
                        'coil_voltage_mean) or electronics (through the model of the drive '
                        'electronics); default auto')
    p.add_argument('--seed', type=int, default=0,
                   help='seed of the baseline search\'s global stage (default 0)')
    p.add_argument('--threads', type=positive_int, default=None, metavar='N',
                   help='threads of the identification (default: one per CPU)')
    p.add_argument('--no-plots', action='store_true', help='skip the PNG plots')
    p.add_argument('--electronics', metavar='YAML', default=None,
                   help='drive electronics of operation/pwm records (the description file '
                        'valve_simulate, valve_map and the emulator take): its form and '
                        'constants are used as given; default: the paper\'s driver\'s form, '
                        'its constants fitted')
    p.add_argument('--fit-electronics', action='store_true',
                   help='with --electronics: its constants are start values, fitted within '
                        'bounds (the form stays)')
    p.add_argument('--choose-electronics', nargs='?', const='always', default='auto',
                   choices=tuple(_CHOICE), metavar='auto|always|never',
                   help='without --electronics: when the data choose the form (peak end, '
                        'hold, release) with its constants: auto (default) when the model '
                        'through the paper\'s driver\'s form misses the record by 3x the '
                        'noise or more (the identification runs again through the chosen '
                        'form), always (the flag alone), never (docs/identification.md)')
    p.add_argument('--quiet', action='store_true', help='no progress output')
    from valve_model_pkg.instruments import add_import_options
    add_import_options(p)
    return p


#: ``--choose-electronics`` values and :attr:`IdentifySettings.choose_electronics`.
_CHOICE = {'auto': None, 'always': True, 'never': False}


def settings_from_args(args: argparse.Namespace) -> 'IdentifySettings':
    """The :class:`~valve_model_pkg.identification.IdentifySettings` of the arguments."""
    from ..identification import IdentifySettings
    return IdentifySettings(
        params_file=args.params, allow_implausible=args.allow_implausible, topic=args.topic,
        valve=args.valve, topic_map=tuple(args.map), diagnose=not args.no_diagnosis,
        effects=tuple(args.effects) if args.effects is not None else None, quick=args.quick,
        seed=args.seed, threads=args.threads, electronics=args.electronics,
        electronics_fixed=not args.fit_electronics,
        choose_electronics=_CHOICE[args.choose_electronics], route=args.route)


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``valve_identify``."""
    parser = _parser()
    args = parser.parse_args(argv)
    if args.fit_electronics and args.electronics is None:
        parser.error('--fit-electronics needs --electronics FILE')
    if args.choose_electronics != 'auto' and args.electronics is not None:
        parser.error(f'--choose-electronics {args.choose_electronics} and --electronics '
                     'exclude each other')
    logging.basicConfig(level=logging.WARNING, format='%(levelname)s: %(message)s')
    from ..errors import IdentificationError, InstrumentFormatError, MeasurementFormatError
    from ..errors import ParameterError
    from ..identification import identify, write_report
    from ..instruments import options_from_args, records_for

    start = time.perf_counter()

    def progress(msg: str) -> None:
        if not args.quiet:
            print(f'[{time.perf_counter() - start:6.1f} s] {msg}', file=sys.stderr,
                  flush=True)

    try:
        imports = options_from_args(args)
        fit = records_for(args.fit, imports, args.out, progress)
        val = records_for(args.validate, imports, args.out, progress)
        ident = identify(fit, val, settings_from_args(args), progress=progress)
        rep = write_report(ident, args.out, plots=not args.no_plots)
    except (MeasurementFormatError, InstrumentFormatError, ParameterError,
            FileNotFoundError) as err:
        print(f'valve_identify: error: {err}', file=sys.stderr)
        return 2
    except IdentificationError as err:
        print(f'valve_identify: error: {err}', file=sys.stderr)
        return 1
    d = rep['diagnosis']
    b, a = rep['baseline'], rep['augmented']
    key = 'validation' if b['validation'] else 'fit'
    progress(f'{key} RMSE baseline {1e3 * b[key]["rmse"]:.2f} mA -> augmented '
             f'{1e3 * a[key]["rmse"]:.2f} mA; effect: {d["effect"] if d else "-"}')
    progress(f'wrote {args.out}/report.json, report.md, params.yaml'
             + (', electronics.yaml' if rep.get('electronics_form') else ''))
    return 0


if __name__ == '__main__':
    sys.exit(main())
