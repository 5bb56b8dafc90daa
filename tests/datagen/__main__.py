"""Command line of the test-data generator.

Examples
--------
Every case into ``/tmp/valve-data`` (one sub-directory per case)::

    python -m tests.datagen --out /tmp/valve-data

Only friction and the undeclared effect, another valve draw, with the long files::

    python -m tests.datagen --out /tmp/d --case coulomb_friction --case supply_ripple \
        --seed 7 --long

Then, for instance::

    valve_identify --fit /tmp/d/coulomb_friction/fit_*.csv \
        --validate /tmp/d/coulomb_friction/validate_*.csv --out /tmp/d/report
"""
from __future__ import annotations

import argparse
import sys
import time

from .generate import CASES, generate_case


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog='python -m tests.datagen',
        description='Write valve measurement data sets (shared CSV format) from an '
        'independent truth model with one effect per case.')
    parser.add_argument('--out', required=True, help='output directory (one folder per case)')
    parser.add_argument('--case', action='append', choices=CASES,
                        help='case to write (repeatable); default: all')
    parser.add_argument('--seed', type=int, default=1, help='valve instance and noise seed')
    parser.add_argument('--long', action='store_true',
                        help='also write the multi-second files for every case')
    parser.add_argument('--step-duration', type=float, default=None, metavar='S',
                        help='length of the step files in seconds (default 0.04)')
    args = parser.parse_args(argv)
    for case in args.case or CASES:
        start = time.perf_counter()
        truth = generate_case(args.out, case, seed=args.seed, long=args.long or None,
                              step_duration_s=args.step_duration)
        print(f'{case}: {len(truth["fit"])} fit + {len(truth["validate"])} validation files '
              f'in {time.perf_counter() - start:.1f} s -> {args.out}/{case}', file=sys.stderr)
    return 0


if __name__ == '__main__':
    sys.exit(main())
