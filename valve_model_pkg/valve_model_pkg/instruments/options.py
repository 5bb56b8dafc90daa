"""The import's command-line options (shared by ``valve_import`` and ``valve_identify``)
and the two entries the commands call: :func:`import_export` and :func:`records_for`.
"""
from __future__ import annotations

import argparse
import os
from collections.abc import Sequence
from pathlib import Path

from ..cli.arguments import finite_float
from ..errors import InstrumentFormatError
from .capture import CaptureHeader
from .detect import detect, is_suite_record, open_export, read_capture, read_head
from .record import EXPERIMENTS, ImportedRecord, ImportOptions, build_record, write_record

__all__ = ['add_import_options', 'options_from_args', 'import_export', 'records_for',
           'group_captures']


def _decimate(text: str) -> int | None:
    if text.strip().casefold() == 'auto':
        return None
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected 'auto' or a whole number >= 1, got "
                                         f'{text!r}') from None
    if value < 1:
        raise argparse.ArgumentTypeError(f'must be at least 1, got {value}')
    return value


def add_import_options(parser: argparse.ArgumentParser, *, required: bool = False
                       ) -> argparse._ArgumentGroup:
    """Add the instrument-export options as one group (``valve_import``, ``valve_identify``).

    Parameters
    ----------
    parser : argparse.ArgumentParser
    required : bool
        Whether ``--current`` and ``--voltage`` are required (``valve_import``); for
        ``valve_identify`` they are needed only when a file is an instrument export.
    """
    g = parser.add_argument_group(
        'instrument exports', 'oscilloscope and DAQ files (Tektronix, Rigol, Keysight, '
        'PicoScope CSV/MAT, NI TDMS, plain CSV), detected from their content; channels '
        'named as the file names them (CH2, 2, Channel B, B, group/channel), any case')
    g.add_argument('--voltage', metavar='CH', required=required,
                   help='channel of the coil voltage (step) or main PWM input (pwm, operation)')
    g.add_argument('--current', metavar='CH', required=required,
                   help='channel of the coil current')
    g.add_argument('--time', metavar='COLUMN', default=None,
                   help='time column of a plain CSV (default: the one named t or time), or '
                        'time channel of a TDMS file without waveform properties')
    g.add_argument('--current-scale', metavar='A_PER_UNIT', type=finite_float, default=None,
                   help='current probe factor, applied after the file\'s units are '
                        'converted (needed when the current channel is in V)')
    g.add_argument('--voltage-scale', metavar='V_PER_UNIT', type=finite_float, default=None,
                   help='voltage probe or divider factor, applied after the file\'s units')
    g.add_argument('--experiment', choices=EXPERIMENTS, default='step',
                   help='what the capture shows (default: step)')
    g.add_argument('--supply-pressure-pa', metavar='PA', type=finite_float, default=None,
                   help='supply pressure, gauge [Pa] (identification needs it)')
    g.add_argument('--output-pressure-pa', metavar='PA', type=finite_float, default=None,
                   help='output port pressure, gauge [Pa] (default 0)')
    g.add_argument('--start', metavar='S', type=finite_float, default=None,
                   help='window start in the file\'s time [s] (trigger at 0)')
    g.add_argument('--stop', metavar='S', type=finite_float, default=None,
                   help='window end in the file\'s time [s]')
    g.add_argument('--decimate', metavar='auto|N', type=_decimate, default=None,
                   help='block means of N samples; auto (default) keeps the step\'s '
                        'dynamics (interval <= min(20 us, current rise / 100)); 1 keeps all')
    return g


def options_from_args(args: argparse.Namespace) -> ImportOptions | None:
    """The import options given on a command line; ``None`` when no channel was named."""
    if args.current is None and args.voltage is None:
        return None
    return ImportOptions(
        current=args.current, voltage=args.voltage, time=args.time,
        voltage_scale=args.voltage_scale, current_scale=args.current_scale,
        experiment=args.experiment, supply_pressure_pa=args.supply_pressure_pa,
        output_pressure_pa=args.output_pressure_pa, start_s=args.start, stop_s=args.stop,
        decimate=args.decimate)


def _check(options: ImportOptions, first: str) -> None:
    missing = [f'--{role}' for role in ('voltage', 'current')
               if getattr(options, role) is None]
    if missing:
        raise InstrumentFormatError(first, None, f'give {" and ".join(missing)} CH: which '
                                    'channel is which is never guessed')
    if options.start_s is not None and options.stop_s is not None \
            and options.stop_s <= options.start_s:
        raise InstrumentFormatError(first, None, f'--stop {options.stop_s} is not after '
                                    f'--start {options.start_s}')


def import_export(paths: Sequence[str | os.PathLike[str]], options: ImportOptions,
                  out: str | os.PathLike[str]) -> ImportedRecord:
    """Import one capture (one or several files) and write it in the measured-data format.

    Parameters
    ----------
    paths : sequence of path-like
        The capture's files (Tektronix TDS-style: one per channel).
    options : ImportOptions
    out : path-like
        The record to write (written only when the import succeeds).

    Returns
    -------
    ImportedRecord

    Raises
    ------
    InstrumentFormatError
        One line naming the file, the row and what was expected.
    """
    _check(options, str(paths[0]))
    capture = read_capture([str(p) for p in paths], options.channels(), options.time)
    record = build_record(capture, options)
    Path(out).parent.mkdir(parents=True, exist_ok=True)
    write_record(out, record)
    return record


def _is_export(path: str) -> bool:
    """True for an existing file that is an instrument export (not the suite's format)."""
    if os.path.isdir(path) or not os.path.isfile(path):
        return False
    if path.endswith(('.mcap', '.db3')):
        return False
    head = read_head(path)
    if head.lines and is_suite_record(head):
        return False
    detect(head)
    return True


def group_captures(headers: Sequence[CaptureHeader]) -> list[list[CaptureHeader]]:
    """Consecutive Tektronix TDS-style files of one time base form one capture."""
    groups: list[list[CaptureHeader]] = []
    for h in headers:
        last = groups[-1][-1] if groups else None
        if (last is not None and h.format == last.format == 'tektronix-tds'
                and h.n_samples == last.n_samples
                and h.sample_interval_s == last.sample_interval_s
                and h.stated.get('trigger point') == last.stated.get('trigger point')
                and {c.name for c in h.channels}.isdisjoint(
                    c.name for g in groups[-1] for c in g.channels)):
            groups[-1].append(h)
        else:
            groups.append([h])
    return groups


def records_for(paths: Sequence[str], options: ImportOptions | None, out_dir: str,
                log=None) -> list[str]:  # noqa: ANN001 - a callable(str)
    """Files for ``valve_identify``: instrument exports imported, everything else as given.

    Records of the measured-data format, bag directories and missing paths pass through
    untouched (their readers report on them). Instrument exports are imported with the
    options into ``out_dir/imported/<name>.csv``; consecutive TDS-style files of one time
    base form one capture.

    Raises
    ------
    InstrumentFormatError
        An export given without ``--voltage``/``--current``, or one that cannot be read.
    """
    exports = [str(p) for p in paths if _is_export(str(p))]
    if not exports:
        return [str(p) for p in paths]
    if options is None:
        header = open_export(exports[0])
        raise InstrumentFormatError(exports[0], None, f'is a {header.reader.title} export; '
                                    f'give --voltage CH and --current CH (channels: '
                                    f'{header.channel_list()})')
    headers = {p: open_export(p) for p in exports}
    out: list[str] = []
    pending: list[CaptureHeader] = []
    for p in [str(p) for p in paths] + [None]:
        if p is not None and p in headers:
            pending.append(headers[p])
            continue
        for group in group_captures(pending):
            target = Path(out_dir) / 'imported' / (Path(group[0].path).stem + '.csv')
            import_export([h.path for h in group], options, target)
            if log is not None:
                log(f'imported {", ".join(h.path for h in group)} -> {target}')
            out.append(str(target))
        pending = []
        if p is not None:
            out.append(p)
    return out
