"""Schedule a fleet's identifications: local process pool or Dask cluster, with resume.

:func:`run_fleet` skips the valves finished by an earlier run (see :mod:`.store`), sends
the others to the workers one valve a task, saves each result as it comes back, and writes
the table at the end. On Ctrl-C it ends the workers and raises ``KeyboardInterrupt``; what
was saved stays, and the same command resumes.
"""
from __future__ import annotations

import multiprocessing
import os
import sys
import time
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from dataclasses import dataclass, field
from typing import Any, Callable, Iterator, Sequence

from .manifest import ValveJob
from .outliers import MIN_VALVES, THRESHOLD
from .store import FleetStore
from .table import failed_row, fleet_rows, valve_row, write_table
from .worker import init_worker, run_valve, single_thread_env
from ..errors import SchedulerError

__all__ = ['FleetResult', 'SchedulerError', 'default_workers', 'run_fleet']


#: how long to keep trying to reach a Dask scheduler before giving up, s
CONNECT_TIMEOUT_S = 15.0


def default_workers() -> int:
    """The CPUs this process may use (one valve each)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:          # not on Linux
        return max(1, os.cpu_count() or 1)


@dataclass
class FleetResult:
    """Outcome of :func:`run_fleet`.

    Attributes
    ----------
    rows : list of dict
        The table rows, in manifest order.
    computed : list of str
        Valve ids identified by this run (not reused from an earlier one).
    reused : list of str
        Valve ids finished by an earlier run and kept.
    failed : list of str
        Valve ids whose identification failed.
    wall_s : float
        Wall time of the run, s.
    files : list of str
        Table files written.
    """

    rows: list[dict[str, Any]] = field(default_factory=list)
    computed: list[str] = field(default_factory=list)
    reused: list[str] = field(default_factory=list)
    failed: list[str] = field(default_factory=list)
    wall_s: float = 0.0
    files: list[str] = field(default_factory=list)


class _Progress:
    """A tqdm bar if tqdm is installed and stderr is a terminal, else one line a valve."""

    def __init__(self, total: int, say: Callable[[str], None], enabled: bool) -> None:
        self.total, self.done, self.say, self.enabled = total, 0, say, enabled
        self.bar = None
        if enabled and total and sys.stderr.isatty():
            try:
                from tqdm import tqdm
            except ImportError:
                pass
            else:
                self.bar = tqdm(total=total, unit='valve', file=sys.stderr)

    def step(self, line: str) -> None:
        self.done += 1
        if self.bar is not None:
            self.bar.update(1)
            self.bar.set_postfix_str(line[:40])
        elif self.enabled:
            self.say(f'[{self.done:{len(str(self.total))}d}/{self.total}] {line}')

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


def _local(jobs: Sequence[ValveJob], workers: int) -> Iterator[tuple[ValveJob, dict]]:
    """Results of the local process pool, as they finish."""
    # spawn: a fresh interpreter per worker (no copy of the parent's threads or locks); the
    # initializer sets the thread limits before numba loads, and the compiled kernels come
    # from numba's on-disk cache, so a worker starts in about a second.
    ctx = multiprocessing.get_context('spawn')
    pool = ProcessPoolExecutor(max_workers=workers, mp_context=ctx, initializer=init_worker)
    pending: dict[Future, ValveJob] = {}
    try:
        with single_thread_env():
            # The pool starts its processes as tasks are submitted: all within this block.
            for job in jobs:
                pending[pool.submit(run_valve, job.to_json())] = job
        while pending:
            done, _ = wait(pending, return_when=FIRST_COMPLETED)
            for fut in done:
                job = pending.pop(fut)
                try:
                    result = fut.result()
                except Exception as err:    # noqa: BLE001 - a worker died (e.g. OOM kill)
                    result = {'valve_id': job.valve_id, 'status': 'failed',
                              'reason': f'worker failed: {type(err).__name__}: {err}',
                              'detail': repr(err), 'files': {}, 'duration_s': 0.0}
                yield job, result
    except BaseException:
        # Ctrl-C (or an error saving a result): end the workers now instead of letting the
        # pool finish every queued valve at interpreter exit.
        for proc in list(getattr(pool, '_processes', {}).values()):
            proc.terminate()
        pool.shutdown(wait=False, cancel_futures=True)
        raise
    pool.shutdown(wait=True)


def _dask(jobs: Sequence[ValveJob], client: Any) -> Iterator[tuple[ValveJob, dict]]:
    """Results of a Dask cluster (``distributed.Client``), as they finish."""
    from distributed import as_completed

    futures = {}
    try:
        for job in jobs:
            # pure=False: a rerun of the same valve is a new task, not a cached result.
            fut = client.submit(run_valve, job.to_json(), pure=False,
                                key=f'valve-identify-{job.valve_id}-{os.getpid()}-'
                                f'{time.monotonic_ns()}')
            futures[fut.key] = (fut, job)
        for fut in as_completed([f for f, _ in futures.values()]):
            job = futures[fut.key][1]
            try:
                result = fut.result()
            except Exception as err:    # noqa: BLE001 - a worker died or was lost
                result = {'valve_id': job.valve_id, 'status': 'failed',
                          'reason': f'worker failed: {type(err).__name__}: {err}',
                          'detail': repr(err), 'files': {}, 'duration_s': 0.0}
            yield job, result
    finally:
        # On Ctrl-C the cluster stops working on this run's valves; it keeps running.
        client.cancel([f for f, _ in futures.values()], force=True)


def run_fleet(jobs: Sequence[ValveJob], out_dir: str, *, workers: int | None = None,
              scheduler: str | None = None, resume: bool = True,
              threshold: float = THRESHOLD, min_valves: int = MIN_VALVES,
              progress: Callable[[str], None] | None = None, show: bool = True,
              parquet: bool = True) -> FleetResult:
    """Identify every valve of ``jobs`` and write the fleet table into ``out_dir``.

    Parameters
    ----------
    jobs : sequence of ValveJob
        From :func:`.manifest.read_manifest`.
    out_dir : str
        Output folder (see :mod:`.store` for its layout).
    workers : int, optional
        Local worker processes (default: the CPUs this process may use); ignored with
        ``scheduler``.
    scheduler : str, optional
        Address of a Dask scheduler (``tcp://host:8786``); the valves run there.
    resume : bool
        Keep the valves an earlier run finished (same records and options).
    threshold, min_valves
        Outlier rule (see :mod:`.outliers`).
    progress : callable, optional
        Receives progress lines.
    show : bool
        Progress per valve (a tqdm bar on a terminal when tqdm is installed).
    parquet : bool
        Also write fleet.parquet (needs pyarrow).

    Returns
    -------
    FleetResult

    Raises
    ------
    KeyboardInterrupt
        Ctrl-C; the workers are ended, finished valves stay saved.
    .store.StoreBusyError
        Another run holds ``out_dir``.
    """
    say = progress or (lambda s: None)
    start = time.perf_counter()
    client = None
    if scheduler:
        from distributed import Client

        # Connected before anything is written: an unreachable scheduler leaves no trace.
        try:
            client = Client(scheduler, timeout=f'{CONNECT_TIMEOUT_S}s')
        except (OSError, ValueError, TypeError) as err:
            raise SchedulerError(f'--scheduler {scheduler}: cannot reach the Dask scheduler '
                                 f'({err})') from None
    try:
        return _run(jobs, out_dir, workers, client, scheduler, resume, threshold, min_valves,
                    say, show, parquet, start)
    finally:
        if client is not None:
            client.close()


def _run(jobs: Sequence[ValveJob], out_dir: str, workers: int | None, client: Any,
         scheduler: str | None, resume: bool, threshold: float, min_valves: int,
         say: Callable[[str], None], show: bool, parquet: bool, start: float
         ) -> FleetResult:
    res = FleetResult()
    rows: dict[str, dict[str, Any]] = {}
    with FleetStore(out_dir) as store:
        todo = []
        for job in jobs:
            done = store.finished(job) if resume else None
            if done is None:
                todo.append(job)
                continue
            rows[job.valve_id] = valve_row(job, done['report'],
                                           float(done['record'].get('duration_s', 0.0)))
            res.reused.append(job.valve_id)
        if res.reused:
            say(f'resume: {len(res.reused)} of {len(jobs)} valves finished earlier, kept; '
                f'{len(todo)} to identify')
        where = (f'Dask scheduler {scheduler}' if scheduler else
                 f'{min(workers or default_workers(), max(1, len(todo)))} local workers')
        if todo:
            say(f'identifying {len(todo)} valves on {where}')
        bar = _Progress(len(todo), say, show)
        stream = (_dask(todo, client) if client is not None
                  else _local(todo, min(workers or default_workers(), max(1, len(todo)))))
        try:
            for job, result in (stream if todo else ()):
                if result['status'] == 'ok':
                    done = store.save(job, result)
                    rows[job.valve_id] = valve_row(job, done['report'], result['duration_s'])
                    res.computed.append(job.valve_id)
                    d = done['report'].get('diagnosis') or {}
                    line = (f'{job.valve_id} ok in {result["duration_s"]:.1f} s, effect '
                            f'{d.get("effect", "-")} ({d.get("confidence", "-")})')
                else:
                    store.save_failure(job, result)
                    rows[job.valve_id] = failed_row(job, result['reason'],
                                                    result['duration_s'])
                    res.failed.append(job.valve_id)
                    line = f'{job.valve_id} FAILED: {result["reason"]}'
                bar.step(line)
        finally:
            # Closing the generator now (not at garbage collection) ends the workers at
            # once when the loop is left by Ctrl-C or an error.
            stream.close()
            bar.close()
        res.rows = fleet_rows([rows[j.valve_id] for j in jobs], threshold=threshold,
                              min_valves=min_valves)
        res.files = [str(p) for p in write_table(res.rows, out_dir, parquet=parquet)]
    res.wall_s = time.perf_counter() - start
    return res
