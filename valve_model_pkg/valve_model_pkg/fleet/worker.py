"""One valve's identification, run inside a worker process (local pool or Dask worker).

:func:`run_valve` does what ``valve_identify`` does for one valve (the same front door:
``identify`` with the :class:`IdentifySettings` of its options, ``write_report``) in a
private temporary folder and returns the files it wrote as bytes. The caller (the fleet
runner, in the main process) alone writes into the output folder, so a worker never leaves
half a valve there and a remote Dask worker needs no write access to it.

This module imports nothing heavy at the top: the pool's initializer must set the thread
limits before numba and numpy start their thread pools.
"""
from __future__ import annotations

import contextlib
import os
import signal
import tempfile
import threading
import time
import traceback
from pathlib import Path
from typing import TYPE_CHECKING, Any, Iterator

if TYPE_CHECKING:
    from ..identification import IdentifySettings

__all__ = ['init_worker', 'limit_threads', 'run_valve', 'settings_from_options',
           'single_thread_env']

#: thread-pool sizes of the numeric libraries: one valve uses one core of its worker, so N
#: workers keep to N cores instead of N x cores threads fighting over them
_THREAD_ENV = ('NUMBA_NUM_THREADS', 'OMP_NUM_THREADS', 'OPENBLAS_NUM_THREADS',
               'MKL_NUM_THREADS')


@contextlib.contextmanager
def single_thread_env() -> Iterator[None]:
    """While active, processes started by this one inherit the one-thread limits.

    A spawned worker imports numpy (and with it BLAS) while it unpickles its first task,
    before any initializer could set the limits; the inherited environment is in force
    from its first instruction. This process's own libraries are already loaded and keep
    their sizes; the variables are restored on exit.
    """
    saved = {name: os.environ.get(name) for name in _THREAD_ENV}
    os.environ.update({name: '1' for name in _THREAD_ENV})
    try:
        yield
    finally:
        for name, value in saved.items():
            if value is None:
                os.environ.pop(name, None)
            else:
                os.environ[name] = value


def limit_threads() -> None:
    """One thread for numba's parallel loops (and BLAS, if not loaded yet) in this process.

    Environment variables act if the libraries are not loaded yet (a fresh pool worker);
    in a Dask worker that has numba loaded already, ``numba.set_num_threads`` limits the
    calling thread (the identification's BLAS work is small: its pool is left alone).
    """
    for name in _THREAD_ENV:
        os.environ[name] = '1'
    import sys
    if 'numba' in sys.modules:
        import numba
        numba.set_num_threads(1)


def init_worker() -> None:
    """Initializer of the local pool's processes.

    Ctrl-C goes to the whole process group; the main process handles it (and ends the
    workers), so a worker ignores it instead of printing a traceback of its own.
    """
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    limit_threads()
    # A main process killed outright (SIGKILL, OOM) cannot end its pool; the workers would
    # stay, idle or finishing a valve no one saves. They go when their parent goes.
    parent = os.getppid()

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(1.0)
        os._exit(1)

    threading.Thread(target=watch, name='parent-watch', daemon=True).start()


def _first_line(err: BaseException) -> str:
    text = str(err).strip().splitlines()
    return f'{type(err).__name__}: {text[0]}' if text else type(err).__name__


def settings_from_options(opts: dict[str, Any]) -> 'IdentifySettings':
    """The :class:`~valve_model_pkg.identification.IdentifySettings` of a valve's manifest
    options (:data:`~.manifest.OPTION_KEYS`); what the manifest does not name keeps
    ``valve_identify``'s default."""
    from ..identification import IdentifySettings
    kw: dict[str, Any] = {k: opts[k] for k in ('topic', 'valve', 'route', 'electronics')
                          if k in opts}
    if 'map' in opts:
        kw['topic_map'] = tuple(e for e in opts['map'].split(';') if e)
    return IdentifySettings(params_file=opts.get('params'), quick=bool(opts.get('quick')),
                            diagnose=bool(opts.get('diagnose', True)),
                            electronics_fixed=not opts.get('fit_electronics', False),
                            choose_electronics=opts.get('choose_electronics'), **kw)


def run_valve(job: dict[str, Any]) -> dict[str, Any]:
    """Identify one valve.

    Parameters
    ----------
    job : dict
        :meth:`ValveJob.to_json` form: ``valve_id``, ``fit``, ``validate`` (absolute paths)
        and ``options``.

    Returns
    -------
    dict
        ``valve_id``; ``status`` (``ok`` or ``failed``); ``reason`` (one line, empty when
        ok); ``detail`` (traceback or message of a failure); ``files`` (name -> bytes of
        report.json, report.md, params.yaml, the PNGs and identify.log); ``duration_s``
        (wall time in the worker); ``host`` and ``pid`` of the worker.
    """
    limit_threads()
    import socket
    start = time.perf_counter()
    out: dict[str, Any] = {'valve_id': job['valve_id'], 'status': 'failed', 'reason': '',
                           'detail': '', 'files': {}, 'duration_s': 0.0,
                           'host': socket.gethostname(), 'pid': os.getpid()}
    log: list[str] = []

    def progress(msg: str) -> None:
        log.append(f'[{time.perf_counter() - start:6.1f} s] {msg}')

    opts = job.get('options', {})
    try:
        from ..errors import IdentificationError, MeasurementFormatError, ParameterError
        from ..identification import identify, write_report
        try:
            ident = identify(job['fit'], job['validate'], settings_from_options(opts),
                             progress=progress)
            with tempfile.TemporaryDirectory(prefix='valve-fleet-') as tmp:
                write_report(ident, tmp, plots=bool(opts.get('plots', True)))
                out['files'] = {p.name: p.read_bytes() for p in sorted(Path(tmp).iterdir())
                                if p.is_file()}
        except (MeasurementFormatError, ParameterError, FileNotFoundError) as err:
            out['reason'] = f'refused input: {err}'.splitlines()[0]
            out['detail'] = str(err)
            return out
        except IdentificationError as err:
            out['reason'] = f'identification failed: {_first_line(err)}'
            out['detail'] = traceback.format_exc()
            return out
    except Exception as err:  # noqa: BLE001 - one valve's bug must not stop the fleet
        out['reason'] = f'internal error: {_first_line(err)}'
        out['detail'] = traceback.format_exc()
        return out
    finally:
        out['duration_s'] = time.perf_counter() - start
        log.append(f'[{out["duration_s"]:6.1f} s] done on {out["host"]} pid {out["pid"]}')
        if out['files']:
            out['files']['identify.log'] = ('\n'.join(log) + '\n').encode('utf-8')
    out['status'] = 'ok'
    return out
