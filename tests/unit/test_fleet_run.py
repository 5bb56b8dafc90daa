"""valve_identify_batch on generated records: local pool, resume, Dask cluster.

Four valves from the test-data generator (``none`` case, seeds 1-4: four valve instances
within +-10 % of Table 2) with 20 ms records, identified with the reduced effort and without
the effect search (a few seconds each), plus one valve whose record is malformed.
"""
from __future__ import annotations

import csv
import json
import queue
import threading
import time
from pathlib import Path

import pytest

from datagen.generate import generate_case
from valve_model_pkg.cli.identify_batch import main
from valve_model_pkg.fleet import read_manifest, run_fleet

GOOD = ('V01', 'V02', 'V03', 'V04')
OPTS = ['--quick', '--no-diagnosis', '--no-plots', '--workers', '2']


@pytest.fixture(scope='module')
def manifest(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp('fleet-data')
    lines = ['valve_id,fit,validate']
    for k, vid in enumerate(GOOD, start=1):
        truth = generate_case(root / vid, 'none', seed=k, step_duration_s=0.02)
        rel = [str(Path(f).relative_to(root)) for f in truth['fit'] + truth['validate']]
        lines.append(f'{vid},{rel[0]},{rel[1]}')
    bad = root / 'V05' / 'fit.csv'
    bad.parent.mkdir()
    bad.write_text('# supply_pressure_pa: 4e5\nt,voltage,current\n0,0,0\n1,x,0\n',
                   encoding='utf-8')
    lines.append('V05,V05/fit.csv,')
    path = root / 'fleet.csv'
    path.write_text('\n'.join(lines) + '\n', encoding='utf-8')
    return path


def _table(out: Path) -> dict[str, dict[str, str]]:
    with open(out / 'fleet.csv', newline='', encoding='utf-8') as fh:
        return {r['valve_id']: r for r in csv.DictReader(fh)}


def _check_table(out: Path) -> dict[str, dict[str, str]]:
    rows = _table(out)
    assert list(rows) == [*GOOD, 'V05']
    for vid in GOOD:
        r = rows[vid]
        assert r['status'] == 'ok' and r['reason'] == ''
        for col in ('coil_resistance_ohm', 'stroke_m', 'fit_rmse_a', 'validation_rmse_a'):
            assert float(r[col]) > 0, (vid, col)
        lo, hi = float(r['coil_resistance_ohm_ci95_low']), float(
            r['coil_resistance_ohm_ci95_high'])
        assert lo < float(r['coil_resistance_ohm']) < hi
        assert float(r['fit_rmse_a']) < 0.05                    # a few mA of noise
        assert r['outlier'] == 'cannot tell'                    # 4 identified valves < 5
        rep = json.loads((out / 'valves' / vid / 'report.json').read_text())
        assert float(r['stroke_m']) == rep['augmented']['parameters']['stroke_m']
        assert (out / 'valves' / vid / 'params.yaml').is_file()
    bad = rows['V05']
    assert bad['status'] == 'failed' and 'refused input' in bad['reason']
    assert 'fit.csv:4' in bad['reason'] and bad['outlier'] == ''
    assert not (out / 'valves' / 'V05').exists()
    assert 'fit.csv:4' in (out / 'failed' / 'V05.txt').read_text()
    pq = pytest.importorskip('pyarrow.parquet')
    table = pq.read_table(out / 'fleet.parquet')
    assert table.column('valve_id').to_pylist() == [*GOOD, 'V05']
    assert table.column('status').to_pylist() == ['ok'] * 4 + ['failed']
    return rows


@pytest.mark.slow
def test_local_pool_then_resume_redoes_only_the_missing_valve(
        manifest: Path, tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    out = tmp_path / 'out'
    # One valve failed: the table is written, exit 1 names it.
    assert main([str(manifest), '-o', str(out), *OPTS]) == 1
    err = capsys.readouterr().err
    assert 'V05' in err.splitlines()[-1] and '1 of 5 valves failed' in err
    assert 'Traceback' not in err
    _check_table(out)
    mtimes = {v: (out / 'valves' / v / 'report.json').stat().st_mtime_ns for v in GOOD}
    # Interrupted run stand-in: one valve's output is gone, a half-written one left over.
    import shutil
    shutil.rmtree(out / 'valves' / 'V03')
    (out / 'valves' / '.V02.tmp-99-dead').mkdir()
    jobs = read_manifest(manifest, {'quick': True, 'diagnose': False, 'plots': False})
    res = run_fleet(jobs, str(out), workers=2, show=False)
    assert res.reused == ['V01', 'V02', 'V04']
    assert sorted(res.computed) == ['V03'] and res.failed == ['V05']   # failures are retried
    for vid in ('V01', 'V02', 'V04'):
        assert (out / 'valves' / vid / 'report.json').stat().st_mtime_ns == mtimes[vid]
    assert (out / 'valves' / 'V03' / 'report.json').stat().st_mtime_ns > mtimes['V04']
    assert not (out / 'valves' / '.V02.tmp-99-dead').exists()
    _check_table(out)
    # The same command again: nothing left to identify but the failing valve.
    assert main([str(manifest), '-o', str(out), *OPTS]) == 1
    err = capsys.readouterr().err
    assert 'resume: 4 of 5 valves finished earlier, kept; 1 to identify' in err
    # Other options are another run: --no-resume (or a changed option) redoes all.
    res = run_fleet(jobs[:1], str(out), workers=1, resume=False, show=False)
    assert res.computed == ['V01'] and res.reused == []


@pytest.mark.slow
def test_dask_local_cluster(manifest: Path, tmp_path: Path,
                            capsys: pytest.CaptureFixture) -> None:
    distributed = pytest.importorskip('distributed')
    out = tmp_path / 'out'
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                  dashboard_address=None) as cluster:
        rc = main([str(manifest), '-o', str(out), '--scheduler', cluster.scheduler_address,
                   '--quick', '--no-diagnosis', '--no-plots'])
    err = capsys.readouterr().err
    assert rc == 1, err                                      # V05's record is malformed
    assert 'on Dask scheduler tcp://' in err and 'Traceback' not in err
    _check_table(out)
    pids = {json.loads((out / 'valves' / v / 'fleet_job.json').read_text())['pid']
            for v in GOOD}
    assert len(pids) == 2                                    # both cluster workers worked


def test_an_unreachable_scheduler_is_refused_and_nothing_written(
        manifest: Path, tmp_path: Path, capsys: pytest.CaptureFixture,
        monkeypatch: pytest.MonkeyPatch) -> None:
    pytest.importorskip('distributed')
    from valve_model_pkg.fleet import runner
    monkeypatch.setattr(runner, 'CONNECT_TIMEOUT_S', 1.0)
    out = tmp_path / 'out'
    assert main([str(manifest), '-o', str(out), '--scheduler', 'tcp://127.0.0.1:9',
                 '--quiet']) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith('valve_identify_batch: error: --scheduler')
    assert not out.exists()


def _pump(stream: object, sink: 'queue.Queue[str]') -> None:
    """Every line of ``stream`` into ``sink``, until it ends."""
    for line in stream:
        sink.put(line)


def _wait_for_line(lines: 'queue.Queue[str]', marker: str, timeout_s: float) -> list[str]:
    """Lines from ``lines`` up to the first one holding ``marker``; fails after
    ``timeout_s`` naming the last lines seen."""
    said: list[str] = []
    deadline = time.monotonic() + timeout_s
    while not said or marker not in said[-1]:
        left = deadline - time.monotonic()
        try:
            said.append(lines.get(timeout=max(left, 0.0)))
        except queue.Empty:
            raise AssertionError(f'no line with {marker!r} in {timeout_s:g} s; last lines: '
                                 f'{said[-5:]}') from None
    return said


@pytest.mark.slow
@pytest.mark.parametrize('sig', ['SIGINT', 'SIGKILL'])
def test_an_interrupted_run_resumes_with_the_same_command(manifest: Path, tmp_path: Path,
                                                          sig: str) -> None:
    import os
    import signal
    import subprocess
    import sys

    from suite_paths import REPO_ROOT

    out = tmp_path / 'out'
    cmd = [sys.executable, '-m', 'valve_model_pkg.cli.identify_batch', str(manifest), '-o',
           str(out), *OPTS]
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(
        [str(REPO_ROOT / 'valve_model_pkg'), os.environ.get('PYTHONPATH', '')]))
    proc = subprocess.Popen(cmd, stderr=subprocess.PIPE, stdout=subprocess.DEVNULL, text=True,
                            env=env, start_new_session=True)   # own group, as a terminal has
    lines: queue.Queue[str] = queue.Queue()
    reader = threading.Thread(target=_pump, args=(proc.stderr, lines), daemon=True)
    reader.start()
    said = _wait_for_line(lines, ' ok in ', timeout_s=120)   # a valve saved, then said
    if sig == 'SIGINT':
        os.killpg(proc.pid, signal.SIGINT)                 # Ctrl-C reaches the whole group
    else:
        os.kill(proc.pid, signal.SIGKILL)                  # the main process only
    proc.wait(timeout=60)
    reader.join(timeout=60)       # stderr ends once the workers let go of it too
    assert not reader.is_alive(), 'the workers still hold stderr 60 s after the stop'
    err = ''.join(said + list(lines.queue))
    # a finished valve as the store defines it: renamed into place; a SIGKILL during a
    # save leaves a hidden valves/.<id>.tmp-* folder (with its report.json) that the next
    # run removes (pathlib's '*' matches hidden names, so they are left out here)
    finished = sorted(p.parent.name for p in out.glob('valves/*/report.json')
                      if not p.parent.name.startswith('.'))
    if sig == 'SIGINT':
        assert proc.returncode == 130, err
        assert 'Traceback' not in err and 'interrupted' in err.splitlines()[-1]
        assert not list((out / 'valves').glob('.*'))       # no half-written valve
    rerun = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=300)
    assert rerun.returncode == 1, rerun.stderr               # V05 still malformed
    kept = len(finished)
    assert (f'resume: {kept} of 5 valves finished earlier, kept; {5 - kept} to identify'
            in rerun.stderr)
    _check_table(out)
