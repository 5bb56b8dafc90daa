"""``valve_identify_batch``: identify a fleet of valves from a manifest, into one table.

Usage::

    valve_identify_batch MANIFEST -o DIR [--workers N] [--scheduler ADDRESS]
                         [--resume | --no-resume] [--quick] [--no-diagnosis] [--no-plots]

MANIFEST (CSV or YAML, docs/fleet.md) lists the valves, each with its fit and validation
records. Each valve is identified as ``valve_identify`` does, one valve a worker process,
on a local process pool (default: one worker a CPU) or on a Dask cluster (``--scheduler``).
DIR receives fleet.csv and fleet.parquet (per valve: parameters with intervals, diagnosis,
errors, status, outlier flag) and valves/<valve_id>/ (report.json, report.md, params.yaml).
A rerun of the same command resumes: finished valves are kept.

Exit status: 0 every valve identified; 2 refused input (manifest, argument: one line naming
the file, line/key and value); 1 a failure inside, or at least one valve failed (the table
is written all the same, with the reason); 130 interrupted (Ctrl-C; rerun to resume).
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from .arguments import positive_int

__all__ = ['main']

PROG = 'valve_identify_batch'


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog=PROG,
        description='Identify many valves (paper Section 4 and the effect diagnosis, as '
        'valve_identify does for one) in parallel, and tabulate them with their fleet '
        'outliers.')
    p.add_argument('manifest', metavar='MANIFEST',
                   help='CSV or YAML list of valves: valve_id, fit, validate, options '
                   '(docs/fleet.md); record paths relative to the manifest')
    p.add_argument('-o', '--out', required=True, metavar='DIR', help='output directory')
    p.add_argument('--workers', type=positive_int, default=None, metavar='N',
                   help='local worker processes (default: one per CPU)')
    p.add_argument('--scheduler', metavar='ADDRESS', default=None,
                   help='run on this Dask scheduler (e.g. tcp://10.0.0.5:8786) instead of '
                   'the local pool; the records must be readable at the same paths there')
    p.add_argument('--resume', action=argparse.BooleanOptionalAction, default=True,
                   help='keep the valves an earlier run into DIR finished (default); '
                   '--no-resume identifies every valve again')
    p.add_argument('--params', metavar='YAML', default=None,
                   help='known parameters for every valve without its own "params"')
    p.add_argument('--quick', action='store_true',
                   help='smaller search effort for every valve without its own "quick"')
    p.add_argument('--no-diagnosis', action='store_true',
                   help='stop after the baseline fit (valves without their own "diagnose")')
    p.add_argument('--no-plots', action='store_true', help='no PNG plots in the valve folders')
    p.add_argument('--outlier-threshold', type=float, default=None, metavar='Z',
                   help='robust |z| above which a parameter is far from the fleet '
                   '(default 3.5)')
    p.add_argument('--quiet', action='store_true', help='no progress output')
    return p


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``valve_identify_batch``."""
    args = _parser().parse_args(argv)
    try:
        return _main(args)
    except KeyboardInterrupt:
        # Whatever was interrupted: the finished valves are saved whole (atomic renames).
        done = len(list(Path(args.out).glob('valves/*/report.json')))
        print(f'{PROG}: interrupted; {done} valves finished in {args.out}/valves; '
              'rerun the same command to go on', file=sys.stderr)
        return 130


def _defaults(args: argparse.Namespace) -> dict[str, object] | str:
    """The manifest's default options from the arguments (the valves' own options win), or
    the reason an argument is refused."""
    defaults: dict[str, object] = {}
    if args.params is not None:
        params = Path(args.params).expanduser()
        if not params.is_file():
            return f'{args.params}: --params: no such file'
        defaults['params'] = str(params.resolve())
    if args.quick:
        defaults['quick'] = True
    if args.no_diagnosis:
        defaults['diagnose'] = False
    if args.no_plots:
        defaults['plots'] = False
    return defaults


def _main(args: argparse.Namespace) -> int:
    from ..fleet import (THRESHOLD, ManifestError, SchedulerError, StoreBusyError, read_manifest,
                         run_fleet)

    start = time.perf_counter()

    def say(msg: str) -> None:
        if not args.quiet:
            print(f'[{time.perf_counter() - start:7.1f} s] {msg}', file=sys.stderr, flush=True)

    def refuse(msg: str) -> int:
        print(f'{PROG}: error: {msg}', file=sys.stderr)
        return 2

    defaults = _defaults(args)
    if isinstance(defaults, str):
        return refuse(defaults)
    threshold = THRESHOLD if args.outlier_threshold is None else args.outlier_threshold
    if not threshold > 0:
        return refuse(f'--outlier-threshold: {args.outlier_threshold} is not above 0')
    try:
        jobs = read_manifest(args.manifest, defaults)
    except ManifestError as err:
        return refuse(str(err))
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        return refuse(f'{args.out}: --out: exists and is not a directory')
    if args.scheduler is not None:
        try:
            import distributed  # noqa: F401
        except ImportError:
            return refuse(f'--scheduler {args.scheduler}: needs dask.distributed '
                          '(pip install -r requirements/python.txt)')
    try:
        res = run_fleet(jobs, str(out), workers=args.workers, scheduler=args.scheduler,
                        resume=args.resume, threshold=threshold, progress=say,
                        show=not args.quiet)
    except StoreBusyError as err:
        return refuse(str(err))
    except ImportError as err:
        print(f'{PROG}: error: {err.name or err}: not installed; {out}/fleet.csv written, '
              'fleet.parquet not (pip install -r requirements/python.txt)', file=sys.stderr)
        return 1
    except SchedulerError as err:
        return refuse(str(err))
    except OSError as err:
        print(f'{PROG}: error: {err}', file=sys.stderr)
        return 1
    flagged = [r['valve_id'] for r in res.rows if r.get('outlier') == 'yes']
    say(f'{len(res.computed)} identified, {len(res.reused)} kept from an earlier run, '
        f'{len(res.failed)} failed in {res.wall_s:.1f} s; outliers: '
        + (', '.join(flagged) if flagged else
           ('cannot tell' if any(r.get('outlier') == 'cannot tell' for r in res.rows)
            else 'none')))
    say(f'wrote {", ".join(res.files)} and {out}/valves/')
    if res.failed:
        print(f'{PROG}: {len(res.failed)} of {len(jobs)} valves failed: '
              f'{", ".join(res.failed)} (reasons in {out}/fleet.csv and {out}/failed/)',
              file=sys.stderr)
        return 1
    return 0


if __name__ == '__main__':
    sys.exit(main())
