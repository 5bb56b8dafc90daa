"""The compiled kernel beside a plain C loop of the same scheme, in one run.

The C yardstick (``$VALVE_REFERENCE_DIR``, default the nearest ``shared/reference/``
above the checkout: ``valve_rk4_elec.c``) integrates the paper's model with the same electronics,
step policy and event handling as the kernel; its currents agree with the kernel's to about
1e-13 A (checked here on every case). It is compiled into a temporary directory with the
system C compiler (``cc -O2``); without a compiler or the source the C figures are skipped
with a note and the kernel's times are still recorded.

Cases (paper parameters, 4 bar supply, h_free 10 us, h_stop 100 us):

* 1 s of 50 Hz, duty 0.4 PWM through the electronics, output at 1 kHz and at 100 kHz:
  the kernel's entries ``derive_parameters``, ``new_drive_state``, ``advance`` (with the
  output buffer's allocation), one thread;
* a 20 ms 24 V step of the bare coil at 100 kHz output: the same entries, and the public
  ``simulate_step`` call (its validation and result building included);
* a batch of 1000 such 10 ms steps at 50 kHz output through ``step_batch`` on the
  machine's cores, against 1000 times the C loop's single run on one core;
* cold start: a fresh ``python -c "import valve_model_pkg.model as m;
  m.simulate_step(m.load_parameters())"`` on the ahead-of-time kernel, beside the same on
  the numba jit (its cache warm).

The figure of each record (``value``) is CPU time per run: kernel and C alternate (C,
kernel, C, kernel, ...) in rounds of 2 s of simulated time each, and each side's best
round (mean CPU per run within it) is compared. On a shared machine the CPU clock is
little disturbed by other processes, where a wall time longer than a time slice is not;
the best walls and their ratio are in each record too (``wall_s``,
``reference_wall_s``). Each record carries the load average (/proc/loadavg) before and
after its measurement (``load``) and the machine's at the end (``load_average``).

Run: ``python benchmarks/bench_kernel_c.py`` (about a minute); writes
benchmarks/results/kernel_c.json.
"""
from __future__ import annotations

import dataclasses
import math
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from common import record as _record, write_results  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / 'valve_model_pkg'))

from valve_model_pkg.model import (  # noqa: E402
    ElectronicsConfig, load_parameters, simulate_step,
)
from valve_model_pkg.model import kernel as K  # noqa: E402

REFERENCE_ENV = 'VALVE_REFERENCE_DIR'
C_SOURCE = 'valve_rk4_elec.c'
H_FREE_S, H_STOP_S = 1e-5, 1e-4
P_SUP_PA, V_S = 4e5, 24.0
ROUNDS = 5              # alternations of C and kernel
SIM_PER_ROUND_S = 2.0   # simulated time per side and round


@dataclasses.dataclass(frozen=True)
class Case:
    """One workload, as the C program's command line names it."""

    name: str
    mode: str           # 'pwm' or 'step'
    duty: float
    freq_hz: float
    duration_s: float
    electronics: bool
    sample_dt_s: float
    label: str

    def c_args(self, reps: int) -> list[str]:
        return [self.mode, repr(V_S), repr(self.duty), repr(self.freq_hz),
                repr(self.duration_s), repr(P_SUP_PA), '1' if self.electronics else '0',
                repr(H_FREE_S), repr(H_STOP_S), repr(self.sample_dt_s), str(reps)]


CASES = (
    Case('kernel_pwm_1s_1khz', 'pwm', 0.4, 50.0, 1.0, True, 1e-3,
         '1 s of 50 Hz, duty 0.4 PWM with the electronics, 1 kHz output'),
    Case('kernel_pwm_1s_100khz', 'pwm', 0.4, 50.0, 1.0, True, 1e-5,
         '1 s of 50 Hz, duty 0.4 PWM with the electronics, 100 kHz output'),
    Case('kernel_step_20ms', 'step', 1.0, 1.0, 0.02, False, 1e-5,
         '20 ms 24 V step of the bare coil, 100 kHz output'),
)
BATCH_CASE = Case('kernel_step_batch_1000', 'step', 1.0, 1.0, 0.01, False, 2e-5,
                  '1000 runs of a 10 ms 24 V step of the bare coil, 50 kHz output')
N_BATCH = 1000


def load() -> list[float]:
    """The 1, 5 and 15 min load averages (/proc/loadavg)."""
    return [round(v, 2) for v in os.getloadavg()]


def load_note(before: list[float], after: list[float]) -> str:
    return (f'load average {before[0]:.1f} before, {after[0]:.1f} after (1 min) on '
            f'{os.cpu_count()} CPUs')


# --------------------------------------------------------------------------------------
# The C yardstick
# --------------------------------------------------------------------------------------
def reference_dir() -> Path:
    """``$VALVE_REFERENCE_DIR``, else the nearest ``shared/reference`` above the checkout."""
    env = os.environ.get(REFERENCE_ENV)
    if env:
        return Path(env)
    for parent in ROOT.parents:
        if (parent / 'shared' / 'reference' / C_SOURCE).is_file():
            return parent / 'shared' / 'reference'
    return ROOT.parent / 'shared' / 'reference'


def build_c(tmp: Path) -> tuple[Path | None, str]:
    """Compile the C yardstick into ``tmp``: (executable or None, why not)."""
    src = reference_dir() / C_SOURCE
    if not src.is_file():
        return None, f'no C yardstick at {src} (set ${REFERENCE_ENV})'
    cc = shutil.which(os.environ.get('CC', 'cc')) or shutil.which('gcc')
    if cc is None:
        return None, 'no C compiler (cc) on this machine'
    exe = tmp / 'valve_rk4_elec'
    done = subprocess.run([cc, '-O2', '-o', str(exe), str(src), '-lm'], capture_output=True,
                          text=True)
    if done.returncode != 0:
        return None, f'{cc} failed: {done.stderr.strip()[:200]}'
    return exe, f'{Path(cc).name} -O2 {src}'


def _children_cpu_s() -> float:
    use = resource.getrusage(resource.RUSAGE_CHILDREN)
    return use.ru_utime + use.ru_stime


@dataclasses.dataclass
class Timing:
    """Best wall time of one run and best per-round mean CPU time per run of one side, s.

    A round runs a case many times in a row; its CPU time per run (the process's or
    thread's CPU clock) is little disturbed by other processes, and the best round is the
    one least disturbed by what they do to the caches.
    """

    wall_s: float = math.inf
    cpu_s: float = math.inf
    runs: int = 0

    def add(self, wall_s: float, cpu_s: float, runs: int) -> None:
        self.wall_s = min(self.wall_s, wall_s)
        self.cpu_s = min(self.cpu_s, cpu_s / runs)
        self.runs += runs


class CLoop:
    """The compiled C program: runs a case, reports its best wall and CPU per run."""

    def __init__(self, exe: Path) -> None:
        self.exe = exe
        # the program's own start (loader, printf) in CPU time, taken off every measurement
        self.start_cpu_s = min(self._cpu_of([str(exe)] + CASES[0].c_args(0))
                               for _ in range(5))

    def _cpu_of(self, args: list[str]) -> float:
        before = _children_cpu_s()
        subprocess.run(args, capture_output=True, check=True)
        return _children_cpu_s() - before

    def run(self, case: Case, reps: int, into: Timing | None = None,
            outfile: Path | None = None) -> int:
        """Run ``reps`` times (adding to ``into``); returns the RK4 steps of one run."""
        args = [str(self.exe)] + case.c_args(reps) + ([str(outfile)] if outfile else [])
        before = _children_cpu_s()
        text = subprocess.run(args, capture_output=True, text=True, check=True).stdout
        cpu = _children_cpu_s() - before - self.start_cpu_s
        line = next(ln for ln in text.splitlines() if ln.startswith('RESULT'))
        fields = dict(w.split('=', 1) for w in line.split() if '=' in w)
        if into is not None:
            into.add(float(fields['best_wall']), max(cpu, 0.0), reps)
        return int(fields['steps'])


# --------------------------------------------------------------------------------------
# The kernel on the same work
# --------------------------------------------------------------------------------------
class KernelRun:
    """One case through the kernel's entries (derive, drive state, advance)."""

    def __init__(self, case: Case) -> None:
        self.case = case
        self.raw = load_parameters().to_vector()
        elec = ElectronicsConfig() if case.electronics else ElectronicsConfig.off()
        self.e = elec.to_vector()
        if case.mode == 'step':
            self.duty, self.period = 1.0, 2.0 * case.duration_s + 1.0
        else:
            self.duty, self.period = case.duty, 1.0 / case.freq_hz
        self.n = int(math.floor(case.duration_s / case.sample_dt_s + 1e-9)) + 1
        self.n_per = int(case.duration_s / self.period) + 2

    def __call__(self) -> tuple[np.ndarray, np.ndarray]:
        c = self.case
        p = K.derive_parameters(self.raw)
        d = K.new_drive_state(V_S, self.duty, self.period, 0.0, P_SUP_PA, 0.0,
                              c.sample_dt_s, 0.0)
        y = np.zeros(K.N_Y)
        out = np.zeros((self.n, K.N_OUT))
        avg = np.zeros(self.n_per)
        K.advance(p, self.e, y, d, (self.n - 1) * c.sample_dt_s, H_FREE_S, H_STOP_S, out,
                  avg)
        return out, d


def time_runs(fn, reps: int, into: Timing, cpu_clock=time.thread_time) -> None:
    """Run ``fn`` ``reps`` times, adding its best wall and its CPU time to ``into``."""
    best = math.inf
    cpu0 = cpu_clock()
    for _ in range(reps):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    into.add(best, cpu_clock() - cpu0, reps)


def agreement(c_loop: CLoop, case: Case, run: KernelRun, tmp: Path
              ) -> tuple[float, int, int]:
    """(max |i_kernel - i_C| over the samples in A, kernel steps, C steps)."""
    path = tmp / f'{case.name}.txt'
    c_steps = c_loop.run(case, 1, outfile=path)
    c_out = np.loadtxt(path, ndmin=2)
    out, d = run()
    n = min(len(c_out), len(out))
    return (float(np.max(np.abs(out[:n, K.O_I] - c_out[:n, 1]))), int(d[K.D_N_STEPS]),
            c_steps)


def _figures(kernel: Timing, c: Timing | None) -> str:
    text = (f'kernel: best wall {kernel.wall_s * 1e3:.3f} ms, CPU {kernel.cpu_s * 1e3:.3f} ms '
            f'per run ({kernel.runs} runs)')
    if c is not None:
        text += (f'; C: best wall {c.wall_s * 1e3:.3f} ms, CPU {c.cpu_s * 1e3:.3f} ms per run '
                 f'({c.runs} runs); wall ratio {kernel.wall_s / c.wall_s:.2f}')
    return text


def _kernel_record(name: str, kernel: Timing, c: Timing | None, target: str,
                   limit: float | None, notes: str, before: list[float],
                   after: list[float]) -> dict:
    """A record of CPU time per run (the figure a loaded machine disturbs least)."""
    c_cpu = None if c is None else c.cpu_s
    passed = None if c_cpu is None or limit is None else kernel.cpu_s / c_cpu <= limit
    rec = _record(name, kernel.cpu_s, 's', None if c is None else 'C loop of the same scheme',
                  c_cpu, target, passed,
                  f'{notes}; {_figures(kernel, c)}; {load_note(before, after)}')
    rec['wall_s'] = kernel.wall_s
    rec['reference_wall_s'] = None if c is None else c.wall_s
    rec['load'] = {'before': before, 'after': after}
    return rec


def bench_case(case: Case, c_loop: CLoop | None, c_note: str, tmp: Path) -> list[dict]:
    run = KernelRun(case)
    run()  # loads or compiles the kernel
    # 2 s of simulated time per side and round: the C program's start is small beside it
    reps = max(2, round(SIM_PER_ROUND_S / case.duration_s))
    before = load()
    kernel, c = Timing(), Timing()
    for _ in range(ROUNDS):
        if c_loop is not None:
            c_loop.run(case, reps, c)
        time_runs(run, reps, kernel)
    after = load()
    notes = (f'{case.label}; paper parameters, {P_SUP_PA / 1e5:g} bar, h_free '
             f'{H_FREE_S:g} s, h_stop {H_STOP_S:g} s; kernel entries derive_parameters + '
             f'new_drive_state + advance (output buffer included), one thread; value: CPU '
             f'time per run, kernel and C alternating in {ROUNDS} rounds')
    if c_loop is None:
        notes += f'; C yardstick skipped: {c_note}'
    else:
        diff, k_steps, c_steps = agreement(c_loop, case, run, tmp)
        notes += (f'; C: {c_note}; current agreement max {diff:.1e} A, RK4 steps kernel '
                  f'{k_steps}, C {c_steps}')
    pwm = case.mode == 'pwm'
    records = [_kernel_record(case.name, kernel, None if c_loop is None else c,
                              '<= 1.3 x C' if pwm else '<= 2 x C', 1.3 if pwm else 2.0,
                              notes, before, after)]
    if not pwm:
        records.append(bench_simulate_step(case, None if c_loop is None else c))
    return records


def bench_simulate_step(case: Case, c: Timing | None) -> dict:
    params = load_parameters()

    def call() -> None:
        simulate_step(params, V_S, case.duration_s, P_SUP_PA,
                      sample_rate_hz=1.0 / case.sample_dt_s)

    call()
    before = load()
    kernel = Timing()
    for _ in range(ROUNDS):
        time_runs(call, max(2, round(SIM_PER_ROUND_S / case.duration_s)), kernel)
    after = load()
    return _kernel_record(
        'kernel_simulate_step_20ms', kernel, c, 'informative', None,
        'the public simulate_step of the same 20 ms step (parameter vector, validation, '
        'result arrays and moving average included); C: the figures of kernel_step_20ms',
        before, after)


def bench_batch(c_loop: CLoop | None, c_note: str) -> dict:
    case = BATCH_CASE
    raw = np.tile(load_parameters().to_vector(), (N_BATCH, 1))
    e = ElectronicsConfig.off().to_vector()
    n_s = int(math.floor(case.duration_s / case.sample_dt_s + 1e-9)) + 1
    volts = np.full(N_BATCH, V_S)
    p_sup = np.full(N_BATCH, P_SUP_PA)
    p_out = np.zeros(N_BATCH)

    def call() -> None:
        K.step_batch(raw, e, volts, p_sup, p_out, (n_s - 1) * case.sample_dt_s, 0.0,
                     case.sample_dt_s, n_s, H_FREE_S, H_STOP_S)

    call()
    before = load()
    kernel, c = Timing(), Timing()
    for _ in range(3):
        if c_loop is not None:
            c_loop.run(case, 100, c)
        time_runs(call, 1, kernel, cpu_clock=time.process_time)
    after = load()
    scaled = None
    if c_loop is not None:  # the C loop's single run, 1000 times
        scaled = Timing(N_BATCH * c.wall_s, N_BATCH * c.cpu_s, 1)
    notes = (f'{case.label}, all with the paper parameters (the C loop\'s work); kernel: '
             f'step_batch on the machine\'s {os.cpu_count()} cores, CPU of all threads; ')
    notes += (f'C skipped: {c_note}' if c_loop is None else
              f'C: {N_BATCH} x its single run on one core')
    return _kernel_record(case.name, kernel, scaled, 'informative', None, notes, before,
                          after)


def _start(code: str, env: dict) -> tuple[float, float]:
    """(wall, CPU) of a fresh ``python -c code``, s (CPU: the child's user + system)."""
    before = _children_cpu_s()
    t0 = time.perf_counter()
    subprocess.run([sys.executable, '-c', code], env=env, check=True, capture_output=True)
    return time.perf_counter() - t0, _children_cpu_s() - before


def bench_cold_start() -> dict:
    """A fresh process's first simulate_step on the ahead-of-time kernel and on the jit."""
    code = 'import valve_model_pkg.model as m; m.simulate_step(m.load_parameters())'
    env = dict(os.environ)
    env['PYTHONPATH'] = str(ROOT / 'valve_model_pkg') + (
        os.pathsep + env['PYTHONPATH'] if env.get('PYTHONPATH') else '')
    env.pop('PYTHONDONTWRITEBYTECODE', None)  # a start as a user's: with the .pyc files
    jit_env = dict(env, VALVE_KERNEL_AOT_DIR='off')
    probe = subprocess.run(
        [sys.executable, '-c', code + '; import sys; from valve_model_pkg.model import aot; '
         'print(aot.backend_name(), "numba" in sys.modules)'],
        env=env, check=True, capture_output=True, text=True).stdout.split()
    _start(code, jit_env)  # numba's cache is filled, as for any later start
    before = load()
    aot_runs = [_start(code, env) for _ in range(5)]
    jit_runs = [_start(code, jit_env) for _ in range(3)]
    bare = min(_start('import numpy', env)[1] for _ in range(3))
    after = load()
    cpu = min(r[1] for r in aot_runs)
    wall = min(r[0] for r in aot_runs)
    jit_cpu = min(r[1] for r in jit_runs)
    rec = _record('kernel_cold_start', cpu, 's', 'the same on the numba jit (warm cache)',
                  jit_cpu, '<= 0.3 s', cpu <= 0.3,
                  f'fresh process: python -c "{code}" (interpreter start included), CPU '
                  f'time, best of 5; its wall {wall:.3f} s; kernel backend {probe[0]}, numba '
                  f'imported: {probe[1]}; on the jit (VALVE_KERNEL_AOT_DIR=off, numba cache '
                  f'warm) {jit_cpu:.3f} s CPU, {min(r[0] for r in jit_runs):.3f} s wall; '
                  f'python -c "import numpy" alone {bare:.3f} s CPU; '
                  f'{load_note(before, after)}')
    rec['wall_s'] = wall
    rec['reference_wall_s'] = min(r[0] for r in jit_runs)
    rec['load'] = {'before': before, 'after': after}
    return rec


def main() -> int:
    records = []
    with tempfile.TemporaryDirectory(prefix='valve_c_') as tmp_name:
        tmp = Path(tmp_name)
        exe, c_note = build_c(tmp)
        c_loop = None if exe is None else CLoop(exe)
        if exe is None:
            print(f'bench_kernel_c: {c_note}; kernel times only', file=sys.stderr)
        for case in CASES:
            print(f'bench_kernel_c: {case.label}', file=sys.stderr)
            records += bench_case(case, c_loop, c_note, tmp)
        print('bench_kernel_c: batch of 1000', file=sys.stderr)
        records.append(bench_batch(c_loop, c_note))
    print('bench_kernel_c: cold start', file=sys.stderr)
    records.append(bench_cold_start())
    write_results('kernel_c', records)
    for r in records:
        ratio = f'{r["ratio"]:.2f}' if r['ratio'] is not None else '-'
        ref = f'{r["reference_value"] * 1e3:.3f} ms' if r['reference_value'] else '-'
        print(f'{r["name"]:28s} CPU {r["value"] * 1e3:9.3f} ms  ref {ref:>11s}  ratio '
              f'{ratio:>5s}  wall {r["wall_s"] * 1e3:9.3f} ms  load '
              f'{r["load"]["before"][0]:.1f}/{r["load"]["after"][0]:.1f}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
