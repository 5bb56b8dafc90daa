"""The fleet output folder: what counts as a finished valve, atomic saves, the lock."""
from __future__ import annotations

import json
from pathlib import Path

import pytest

from valve_model_pkg.fleet import FleetStore, StoreBusyError, ValveJob

JOB = ValveJob('V1', ('/data/fit.csv',), ('/data/val.csv',), {'quick': True})
REPORT = {'baseline': {}, 'augmented': {}, 'diagnosis': None}


def _result(report: dict | None = None) -> dict:
    return {'valve_id': 'V1', 'status': 'ok', 'reason': '', 'duration_s': 1.5,
            'host': 'h', 'pid': 1,
            'files': {'report.json': json.dumps(report or REPORT).encode(),
                      'params.yaml': b'x: 1\n'}}


def test_a_saved_valve_is_finished_only_whole_and_for_the_same_job(tmp_path: Path) -> None:
    with FleetStore(tmp_path) as store:
        assert store.finished(JOB) is None
        done = store.save(JOB, _result())
        assert done['report'] == REPORT and done['record']['duration_s'] == 1.5
        d = store.valve_dir('V1')
        assert sorted(p.name for p in d.iterdir()) == ['fleet_job.json', 'params.yaml',
                                                       'report.json']
        assert not list(store.valves.glob('.*'))           # no temporary folder left
        # Other options: not the same valve run, so not finished.
        assert store.finished(ValveJob('V1', JOB.fit, JOB.validate, {})) is None
        # A truncated report is not finished either.
        (d / 'report.json').write_text('{"baseline": {', encoding='utf-8')
        assert store.finished(JOB) is None
        # Saving again replaces the folder.
        store.save(JOB, _result({**REPORT, 'again': 1}))
        assert store.finished(JOB)['report']['again'] == 1
        (d / 'report.json').unlink()
        assert store.finished(JOB) is None


def test_leftovers_of_a_killed_run_are_removed_and_failures_kept(tmp_path: Path) -> None:
    stale = tmp_path / 'valves' / '.V1.tmp-123-abcd'
    stale.mkdir(parents=True)
    (stale / 'report.json').write_text('{}', encoding='utf-8')
    with FleetStore(tmp_path) as store:
        assert not stale.exists()
        store.save_failure(JOB, {'reason': 'refused input: bad', 'detail': 'trace'})
        assert 'refused input: bad' in (tmp_path / 'failed' / 'V1.txt').read_text()
        store.save(JOB, _result())
        assert not (tmp_path / 'failed' / 'V1.txt').exists()


def test_one_run_at_a_time_per_output_folder(tmp_path: Path) -> None:
    with FleetStore(tmp_path):
        with pytest.raises(StoreBusyError, match='in use'):
            FleetStore(tmp_path).open()
    with FleetStore(tmp_path):                             # released on close
        pass
