"""Run the model's batch API in a child process that can be stopped if it never returns.

The map generator simulates thousands of operating points, some of them at the edges of
the effective range where the valve model's event handling is most delicate. A compiled
(numba) kernel cannot be interrupted from its own process, so a model call that never
returns would hang ``valve_map`` forever. The :class:`BatchWorker` runs every batch in a
spawned child process and waits for it with a deadline derived from the throughput seen so
far. If the deadline passes, the child is killed and restarted, the batch is split in
halves until the run that does not return is isolated, and that run is retried with its
duty moved by ``nudge`` (1e-5, far below the map's resolution); after ``max_nudges``
failures its value is reported as NaN. Every such event is recorded in
:attr:`BatchWorker.incidents` (and in the map file's notes).
"""
from __future__ import annotations

import logging
import os
import subprocess
import sys
import time
from multiprocessing.connection import Connection
from dataclasses import dataclass, field
from typing import Any

import numpy as np

__all__ = ['BatchWorker', 'BatchRequest', 'run_batch_in_process']

_LOG = logging.getLogger(__name__)


@dataclass(frozen=True)
class BatchRequest:
    """One call of ``simulate_pwm_batch`` (everything the child needs, picklable)."""

    params: dict[str, Any]
    electronics: dict[str, Any]
    supply_voltage_v: float
    output_pressure_pa: float
    n_periods: int
    duty: np.ndarray
    pwm_frequency_hz: np.ndarray
    supply_pressure_pa: np.ndarray
    threads: int | None = None


def run_batch_in_process(req: BatchRequest) -> np.ndarray:
    """Period averages [m], shape (n_runs, n_periods), computed in this process."""
    from valve_model_pkg.model import ElectronicsConfig, ValveParameters, simulate_pwm_batch
    if req.threads is not None:
        import numba
        numba.set_num_threads(int(req.threads))
    res = simulate_pwm_batch(ValveParameters.from_dict(req.params),
                             ElectronicsConfig.from_dict(req.electronics),
                             duty=req.duty, pwm_frequency_hz=req.pwm_frequency_hz,
                             supply_pressure_pa=req.supply_pressure_pa,
                             output_pressure_pa=req.output_pressure_pa,
                             n_periods=req.n_periods, supply_voltage_v=req.supply_voltage_v,
                             validate=False)
    return np.asarray(res.position_avg_m)


def _serve(fd_in: int, fd_out: int) -> None:  # pragma: no cover - runs in the child
    import numba

    import valve_model_pkg.model  # noqa: F401 - load the compiled kernels before 'ready'
    rx = Connection(fd_in, readable=True, writable=False)
    tx = Connection(fd_out, readable=False, writable=True)
    tx.send(('ready', numba.get_num_threads()))
    while True:
        try:
            req = rx.recv()
        except EOFError:
            return
        if req is None:
            return
        try:
            tx.send(('ok', run_batch_in_process(req)))
        except Exception as err:  # noqa: BLE001 - reported to the parent, which raises
            tx.send(('error', f'{type(err).__name__}: {err}'))


@dataclass
class BatchWorker:
    """A child process running model batches, restarted if a batch never returns.

    Parameters
    ----------
    threads : int, optional
        numba threads in the child (default: all cores).
    min_timeout_s : float
        Smallest deadline for one batch [s].
    slack : float
        Deadline = ``min_timeout_s`` + ``slack`` x the expected time (from the throughput of
        earlier batches, in simulated seconds per wall second).
    nudge : float
        Duty offset for a run that did not return.
    max_nudges : int
        Retries of such a run before giving up on it (NaN).
    """

    threads: int | None = None
    min_timeout_s: float = 5.0
    slack: float = 20.0
    nudge: float = 1e-5
    max_nudges: int = 3
    incidents: list[str] = field(default_factory=list)
    child_threads: int = 0
    _proc: Any = None
    _tx: Any = None
    _rx: Any = None
    _rate: float = 0.0   # simulated s per wall s, running estimate
    # (duty, frequency, supply pressure) of runs that did not return -> duty used instead
    _substitutes: dict[tuple[float, float, float], float] = field(default_factory=dict)
    _given_up: set[tuple[float, float, float]] = field(default_factory=set)

    # --- process management -------------------------------------------------------------
    def start(self) -> None:
        """Start the child (idempotent); waits until it has imported the model.

        The child is ``python -m valve_model_pkg.maps.worker`` talking over two private
        pipes (not stdin/stdout, so nothing it prints can corrupt the channel).
        """
        if self._proc is not None and self._proc.poll() is None:
            return
        req_r, req_w = os.pipe()
        res_r, res_w = os.pipe()
        env = dict(os.environ)
        if self.threads is not None:
            env['NUMBA_NUM_THREADS'] = str(int(self.threads))
        # the child must import this very package (source tree or install)
        pkg_root = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
        env['PYTHONPATH'] = pkg_root + os.pathsep + env.get('PYTHONPATH', '')
        try:
            self._proc = subprocess.Popen(
                [sys.executable, '-m', 'valve_model_pkg.maps.worker', str(req_r), str(res_w)],
                pass_fds=(req_r, res_w), stdin=subprocess.DEVNULL, env=env)
        finally:
            os.close(req_r)
            os.close(res_w)
        self._tx = Connection(req_w, readable=False, writable=True)
        self._rx = Connection(res_r, readable=True, writable=False)
        if not self._rx.poll(120.0):
            self._kill()
            raise RuntimeError('the batch worker process did not start within 120 s')
        try:
            _, self.child_threads = self._rx.recv()
        except EOFError as err:
            self._kill()
            raise RuntimeError('the batch worker process exited while starting') from err

    def close(self) -> None:
        """Stop the child (idempotent)."""
        if self._tx is not None:
            try:
                self._tx.send(None)
            except (OSError, ValueError):
                pass
        if self._proc is not None:
            try:
                self._proc.wait(timeout=2.0)
            except subprocess.TimeoutExpired:
                self._proc.kill()
                self._proc.wait()
        self._proc = None
        self._close_pipes()

    def _close_pipes(self) -> None:
        for conn in (self._tx, self._rx):
            if conn is not None:
                conn.close()
        self._tx = self._rx = None

    def __enter__(self) -> BatchWorker:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __del__(self) -> None:
        try:
            self.close()
        except Exception:  # noqa: BLE001 - best effort at interpreter exit
            pass

    def _kill(self) -> None:
        if self._proc is not None:
            self._proc.kill()
            self._proc.wait()
            self._proc = None
        self._close_pipes()

    # --- batches --------------------------------------------------------------------------
    def _deadline(self, req: BatchRequest) -> float:
        sim_s = float(np.sum(req.n_periods / req.pwm_frequency_hz))
        expected = sim_s / self._rate if self._rate > 0.0 else 10.0
        return self.min_timeout_s + self.slack * expected

    def _try(self, req: BatchRequest) -> np.ndarray | None:
        """Result, or None if the child did not answer in time (it is then restarted)."""
        self.start()
        t0 = time.perf_counter()
        self._tx.send(req)
        if not self._rx.poll(self._deadline(req)):
            self._kill()
            return None
        try:
            status, payload = self._rx.recv()
        except EOFError:
            code = self._proc.poll() if self._proc is not None else None
            self._kill()
            raise RuntimeError(f'the batch worker process died (exit code {code})') from None
        if status != 'ok':
            raise RuntimeError(f'model batch failed in the worker: {payload}')
        wall = max(time.perf_counter() - t0, 1e-6)
        rate = float(np.sum(req.n_periods / req.pwm_frequency_hz)) / wall
        self._rate = rate if self._rate == 0.0 else 0.7 * self._rate + 0.3 * rate
        return payload

    def run(self, req: BatchRequest) -> np.ndarray:
        """Period averages [m], shape (n_runs, n_periods); NaN rows for runs given up."""
        keys = list(zip(req.duty.tolist(), req.pwm_frequency_hz.tolist(),
                        req.supply_pressure_pa.tolist()))
        if self._given_up:
            ok = np.array([k not in self._given_up for k in keys], dtype=bool)
            if not ok.all():
                out = np.full((req.duty.size, req.n_periods), np.nan)
                if ok.any():
                    out[ok] = self.run(self._subset(req, np.nonzero(ok)[0]))
                return out
        if self._substitutes:
            duty = np.array([self._substitutes.get(k, k[0]) for k in keys])
            req = self._subset(req, np.arange(req.duty.size), duty)
        out = self._try(req)
        if out is not None:
            return out
        return self._isolate(req)

    def _subset(self, req: BatchRequest, idx: np.ndarray, duty: np.ndarray | None = None
                ) -> BatchRequest:
        return BatchRequest(req.params, req.electronics, req.supply_voltage_v,
                            req.output_pressure_pa, req.n_periods,
                            req.duty[idx] if duty is None else duty,
                            req.pwm_frequency_hz[idx], req.supply_pressure_pa[idx],
                            req.threads)

    def _isolate(self, req: BatchRequest) -> np.ndarray:
        n = req.duty.size
        out = np.full((n, req.n_periods), np.nan)
        if n == 1:
            base = float(req.duty[0])
            for k in range(1, self.max_nudges + 1):
                duty = min(max(base + k * self.nudge * (1 if base < 0.5 else -1), 0.0), 1.0)
                res = self._try(self._subset(req, np.array([0]), np.array([duty])))
                if res is not None:
                    self._substitutes[(base, float(req.pwm_frequency_hz[0]),
                                       float(req.supply_pressure_pa[0]))] = duty
                    self._note(f'model did not return for duty {base:.6g} at '
                               f'{req.pwm_frequency_hz[0]:g} Hz, '
                               f'{req.supply_pressure_pa[0]:g} Pa ({req.n_periods} periods); '
                               f'simulated at duty {duty:.6g} instead (from now on)')
                    return res
            self._given_up.add((base, float(req.pwm_frequency_hz[0]),
                                float(req.supply_pressure_pa[0])))
            self._note(f'model did not return for duty {base:.6g} at '
                       f'{req.pwm_frequency_hz[0]:g} Hz, {req.supply_pressure_pa[0]:g} Pa '
                       f'even after {self.max_nudges} nudges; point left out')
            return out
        half = n // 2
        for idx in (np.arange(half), np.arange(half, n)):
            # run() applies what earlier isolations found (substitutes, given-up runs)
            out[idx] = self.run(self._subset(req, idx))
        return out

    def _note(self, text: str) -> None:
        _LOG.warning('%s', text)
        self.incidents.append(text)


if __name__ == '__main__':  # pragma: no cover - the child process
    _serve(int(sys.argv[1]), int(sys.argv[2]))
