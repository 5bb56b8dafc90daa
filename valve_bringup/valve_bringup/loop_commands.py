"""What both loops of ``valve_bench_loop`` do through the suite's console scripts: run a
command and show its output's tail, identify, check that the simulator starts with a
parameter set."""
from __future__ import annotations

import json
import os
import signal
import subprocess
import time
from pathlib import Path

__all__ = ['say', 'run_command', 'identify', 'simulator_starts', 'error_figures']

#: Lines of a command's output shown after it ends.
_OUTPUT_TAIL_LINES = 25
#: How long ``valve_simulator`` runs in :func:`simulator_starts` [s].
SIMULATOR_CHECK_S = 4.0


def say(text: str) -> None:
    """One line of the loop's output."""
    print(f'[{"bench_loop":>18}] {text}', flush=True)


def run_command(argv: list[str]) -> subprocess.CompletedProcess:
    """Run a console script, print the tail of its output; RuntimeError on failure."""
    say('$ ' + ' '.join(argv))
    proc = subprocess.run(argv, text=True, stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    for line in proc.stdout.splitlines()[-_OUTPUT_TAIL_LINES:]:
        print(f'[{Path(argv[0]).name:>18}] {line}', flush=True)
    if proc.returncode != 0:
        raise RuntimeError(f'{argv[0]} failed with exit code {proc.returncode}')
    return proc


def identify(records: list[str], ident: Path, quick: bool, effect: str) -> dict:
    """Run ``valve_identify`` on ``records`` into ``ident``; say the diagnosis and errors.

    Returns the parsed ``report.json``.
    """
    run_command(['valve_identify', *records, '--out', str(ident)]
                + (['--quick'] if quick else []))
    report = json.loads((ident / 'report.json').read_text())
    diag = report['diagnosis']
    say(f'injected effect: {effect}; diagnosis: {diag["effect"]} '
        f'(confidence {diag.get("confidence", "?")})')
    for block_name in ('baseline', 'augmented'):
        for part in ('fit', 'validation'):
            m = report[block_name].get(part) or {}
            if m:
                say(f'{block_name:>9} {part:>10}: IAE {m["iae"]:.4g} A s, RMSE '
                    f'{m["rmse"] * 1e3:.2f} mA, NRMSE {m["nrmse_pct"]:.2f} %')
    return report


def error_figures(block: dict) -> dict:
    """``iae``, ``rmse``, ``nrmse_pct`` of the fit and validation of an identification
    report's ``baseline`` or ``augmented`` block."""
    return {part: {k: block[part][k] for k in ('iae', 'rmse', 'nrmse_pct')
                   if k in block[part]}
            for part in ('fit', 'validation') if block.get(part)}


def simulator_starts(params: Path) -> bool:
    """Start ``valve_simulator`` with ``params`` for a few seconds; True if it simulated."""
    sim = subprocess.Popen(['valve_simulator', '--ros-args', '-p',
                            f'params_file:={params.resolve()}'],
                           stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                           start_new_session=True)
    try:
        time.sleep(SIMULATOR_CHECK_S)   # it runs this long: a wall-clock duration
    finally:
        os.killpg(sim.pid, signal.SIGINT)
        try:
            sim_out, _ = sim.communicate(timeout=20)
        except subprocess.TimeoutExpired:
            os.killpg(sim.pid, signal.SIGKILL)
            sim_out, _ = sim.communicate()
    started = 'simulating' in sim_out
    say(f'valve_simulator with the identified parameters: '
        f'{"started and stopped cleanly" if started else "FAILED"}')
    if not started:
        print(sim_out, flush=True)
    return started
