"""The output folder of a fleet run, and what makes a valve finished (resume).

Layout of ``DIR``::

    DIR/fleet.csv, DIR/fleet.parquet     the table (written at the end of each run)
    DIR/valves/<valve_id>/               one finished valve: report.json, report.md,
                                         params.yaml, PNGs, identify.log, fleet_job.json
    DIR/failed/<valve_id>.txt            why a valve failed (retried by the next run)
    DIR/.lock                            held while a run uses DIR

A valve is *finished* when ``valves/<valve_id>/`` holds a ``report.json`` that parses and a
``fleet_job.json`` whose fingerprint matches the manifest's entry (same records, same
options). The folder is written as ``valves/.<valve_id>.tmp-*`` and renamed into place in
one step, so a run killed at any moment leaves either a whole valve or none; the leftover
temporary folders are removed by the next run.
"""
from __future__ import annotations

import fcntl
import json
import os
import shutil
import uuid
from pathlib import Path
from typing import Any, IO

from .manifest import ValveJob
from ..errors import StoreBusyError

__all__ = ['FleetStore', 'StoreBusyError']


class FleetStore:
    """The output folder ``root`` of a fleet run.

    Parameters
    ----------
    root : str or pathlib.Path
        Output folder (created if missing).
    """

    def __init__(self, root: str | Path) -> None:
        self.root = Path(root)
        self.valves = self.root / 'valves'
        self.failed = self.root / 'failed'
        self._lock: IO[str] | None = None

    # -- lifetime ------------------------------------------------------------------------
    def open(self) -> 'FleetStore':
        """Create the folders, take the lock, remove temporary leftovers of killed runs."""
        self.valves.mkdir(parents=True, exist_ok=True)
        self._lock = open(self.root / '.lock', 'w', encoding='utf-8')
        try:
            # flock is released by the kernel when the holder dies (even by SIGKILL), so a
            # killed run never leaves DIR locked.
            fcntl.flock(self._lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            self._lock.close()
            self._lock = None
            raise StoreBusyError(f'{self.root} is in use by another valve_identify_batch run'
                                 ) from None
        self._lock.write(f'{os.getpid()}\n')
        self._lock.flush()
        for tmp in self.valves.glob('.*.tmp-*'):
            shutil.rmtree(tmp, ignore_errors=True)
        return self

    def close(self) -> None:
        """Release the lock."""
        if self._lock is not None:
            self._lock.close()
            self._lock = None

    def __enter__(self) -> 'FleetStore':
        return self.open()

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- valves --------------------------------------------------------------------------
    def valve_dir(self, valve_id: str) -> Path:
        """Folder of a finished valve."""
        return self.valves / valve_id

    def finished(self, job: ValveJob) -> dict[str, Any] | None:
        """The report and job record of a finished valve, ``None`` if it must be (re)done."""
        d = self.valve_dir(job.valve_id)
        try:
            report = json.loads((d / 'report.json').read_text(encoding='utf-8'))
            record = json.loads((d / 'fleet_job.json').read_text(encoding='utf-8'))
        except (OSError, ValueError):
            return None
        if not isinstance(report, dict) or not {'baseline', 'augmented'} <= set(report):
            return None
        if not isinstance(record, dict) or record.get('fingerprint') != job.fingerprint():
            return None
        return {'report': report, 'record': record}

    def save(self, job: ValveJob, result: dict[str, Any]) -> dict[str, Any]:
        """Write a worker's successful result as the valve's folder, atomically.

        Parameters
        ----------
        job : ValveJob
            The valve.
        result : dict
            :func:`.worker.run_valve`'s return value with status ``ok``.

        Returns
        -------
        dict
            As :meth:`finished`.
        """
        tmp = self.valves / f'.{job.valve_id}.tmp-{os.getpid()}-{uuid.uuid4().hex[:8]}'
        tmp.mkdir()
        try:
            for name, data in result['files'].items():
                (tmp / Path(name).name).write_bytes(data)
            record = {'fingerprint': job.fingerprint(), 'job': job.to_json(),
                      'duration_s': result['duration_s'], 'host': result.get('host'),
                      'pid': result.get('pid')}
            (tmp / 'fleet_job.json').write_text(json.dumps(record, indent=1),
                                                encoding='utf-8')
            self._fsync_files(tmp)
            final = self.valve_dir(job.valve_id)
            old = None
            if final.exists():
                # A stale or outdated folder: moved aside first, because rename() will not
                # replace a non-empty folder; the new one is in place before the old goes.
                old = self.valves / f'.{job.valve_id}.tmp-old-{uuid.uuid4().hex[:8]}'
                final.rename(old)
            tmp.rename(final)
            self._fsync_dir(self.valves)
            if old is not None:
                shutil.rmtree(old, ignore_errors=True)
        except BaseException:
            shutil.rmtree(tmp, ignore_errors=True)
            raise
        (self.failed / f'{job.valve_id}.txt').unlink(missing_ok=True)
        done = self.finished(job)
        if done is None:
            raise OSError(f'{self.valve_dir(job.valve_id)}: written but not readable back')
        return done

    def save_failure(self, job: ValveJob, result: dict[str, Any]) -> None:
        """Keep why a valve failed (``failed/<valve_id>.txt``); its folder is not written."""
        self.failed.mkdir(exist_ok=True)
        text = (f'valve {job.valve_id}: {result["reason"]}\n\n{result.get("detail", "")}\n')
        (self.failed / f'{job.valve_id}.txt').write_text(text, encoding='utf-8')

    @staticmethod
    def _fsync_files(path: Path) -> None:
        """Flush the files of ``path`` before the rename publishes them (power loss)."""
        for p in path.iterdir():
            if p.is_file():
                with open(p, 'rb') as fh:
                    os.fsync(fh.fileno())
        FleetStore._fsync_dir(path)

    @staticmethod
    def _fsync_dir(path: Path) -> None:
        """Flush a folder's entries (the rename itself)."""
        fd = os.open(path, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)
