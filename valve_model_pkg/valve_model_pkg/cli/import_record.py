"""``valve_import``: an oscilloscope or DAQ export into a record of the measured-data format.

Usage::

    valve_import FILES... --voltage CH --current CH -o OUT.csv [--current-scale A_PER_UNIT]
        [--voltage-scale V_PER_UNIT] [--experiment step|pwm|operation]
        [--supply-pressure-pa PA] [--output-pressure-pa PA] [--start S] [--stop S]
        [--decimate auto|N] [--time COLUMN]

FILES are one capture: one file, or one file per channel (Tektronix TDS-style). The format
is detected from the content (docs/bench.md lists them and how each instrument exports).
The record's header states the source files, instrument, channels, units, factors, sample
interval, window, the step found, the decimation and the vertical resolution found in the
samples. Exit status: 0 written, 2 refused input (one line naming the file, the row and
what was expected; nothing written), 1 a failure inside.
"""
from __future__ import annotations

import argparse
import sys
import time

__all__ = ['main', 'build_parser']


def build_parser() -> argparse.ArgumentParser:
    from ..instruments import add_import_options

    p = argparse.ArgumentParser(
        prog='valve_import',
        description='Import an oscilloscope or DAQ export (Tektronix TDS/MSO, Rigol, '
        'Keysight, PicoScope CSV/MAT, NI TDMS, plain CSV) as a record of the '
        'measured-data format, for valve_identify.')
    p.add_argument('files', nargs='+', metavar='FILES',
                   help='the export files of one capture')
    p.add_argument('-o', '--out', required=True, metavar='OUT.csv',
                   help='the record to write')
    p.add_argument('--quiet', action='store_true', help='no summary on stderr')
    add_import_options(p, required=True)
    return p


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``valve_import``."""
    args = build_parser().parse_args(argv)
    from ..errors import InstrumentFormatError
    from ..instruments import import_export, options_from_args

    start = time.perf_counter()
    try:
        record = import_export(args.files, options_from_args(args), args.out)
    except InstrumentFormatError as err:
        print(f'valve_import: error: {err}', file=sys.stderr)
        return 2
    except OSError as err:
        print(f'valve_import: error: cannot write {args.out}: {err.strerror}', file=sys.stderr)
        return 1
    if not args.quiet:
        meta = record.metadata
        print(f'valve_import: {meta["instrument"]} ({meta["export_format"]}), voltage '
              f'{meta["voltage_channel"]}, current {meta["current_channel"]}: '
              f'{record.n_rows} rows at {float(meta.get("sample_rate_hz", "nan")):.6g} Hz, '
              f'decimation {meta["decimation"].split(" ")[0]}, '
              f'{meta["time_note"]} -> {args.out} '
              f'({time.perf_counter() - start:.1f} s)', file=sys.stderr)
        for note in record.notes:
            print(f'valve_import: note: {note}', file=sys.stderr)
        if 'supply_pressure_pa' not in meta:
            print('valve_import: note: no --supply-pressure-pa: valve_identify needs '
                  'supply_pressure_pa in the header', file=sys.stderr)
    return 0


if __name__ == '__main__':
    sys.exit(main())
