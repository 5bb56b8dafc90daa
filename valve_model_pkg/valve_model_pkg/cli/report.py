"""valve_report: a Markdown report with plots from a bag recorded from the suite.

    valve_report BAG [-o DIR] [--title TEXT]

Writes ``DIR/report.md`` with ``DIR/*.png`` and ``DIR/report.json``
(:func:`valve_model_pkg.analysis.write_run_report`): piston position and setpoint, chamber
pressure, commanded and achieved mass flow, PWM duty, coil current; a table per position
step (settling time, overshoot, steady-state error); and the message count and sequence
continuity of every topic. No ROS needed.

Exit status: 0 written, 2 refused input (no such bag, not a bag of the suite; one line
naming it), 1 a failure inside (writing the report).
"""
from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

from valve_model_pkg.analysis import write_run_report
from valve_model_pkg.errors import RecordingError

__all__ = ['main']


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``valve_report``."""
    parser = argparse.ArgumentParser(prog='valve_report', description=__doc__.split('\n')[0])
    parser.add_argument('bag', type=Path, help='bag directory recorded from the suite')
    parser.add_argument('-o', '--out', type=Path, default=None,
                        help='output directory (default: BAG_report)')
    parser.add_argument('--title', default='valve suite run')
    args = parser.parse_args(argv)
    out = args.out or args.bag.with_name(args.bag.name + '_report')
    # The reader's warnings (a killed or damaged bag read as far as it goes) are held back:
    # printed after a written report, dropped when the bag is refused (one line then).
    held = _HeldWarnings()
    recording_log = logging.getLogger('valve_model_pkg.recording')
    recording_log.addHandler(held)
    propagate, recording_log.propagate = recording_log.propagate, False
    try:
        report = write_run_report(args.bag, out, args.title).markdown
    except (RecordingError, ValueError) as err:  # the bag: refused input
        print(f'valve_report: error: {_one_line(err)}', file=sys.stderr)
        return 2
    except OSError as err:  # writing the report
        print(f'valve_report: error: {_one_line(err)}', file=sys.stderr)
        return 1
    finally:
        recording_log.removeHandler(held)
        recording_log.propagate = propagate
    for message in held.messages:
        print(f'valve_report: warning: {message}', file=sys.stderr)
    print(f'valve_report: wrote {report}')
    return 0


class _HeldWarnings(logging.Handler):
    """Keeps the warnings of the bag reader until the outcome is known."""

    def __init__(self) -> None:
        super().__init__(logging.WARNING)
        self.messages: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.messages.append(_one_line(record.getMessage()))


def _one_line(text: object) -> str:
    return ' '.join(str(text).split())


if __name__ == '__main__':
    sys.exit(main())
