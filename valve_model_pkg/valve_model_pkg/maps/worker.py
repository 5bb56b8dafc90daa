"""Steady states of operating points, computed in child processes that can be stopped.

Each operating point (duty, PWM frequency, supply and output pressure) is simulated with
the model's streaming API, one PWM period at a time from a closed valve at rest, and
stopped as soon as its period averages meet the periodic-steady-state criterion
(:func:`.steady_state.steady_at`). Continuing a run period by period means every point
costs exactly the periods it needs. All points of a request advance together as one
:class:`~valve_model_pkg.model.bank.ValveBank` (one compiled call per round of one period
each), so the Python cost per period is paid once per round, not once per point; each
bank valve gives bit for bit what a ``ValveStepper`` gives (:func:`steady_point`, the
one-point form, used after a hang).

A compiled (numba) model call cannot be interrupted from its own process, so a model call
that never returns would hang ``valve_map`` forever. A :class:`PointWorker` therefore runs
its points in a child process (talking over two private pipes), which reports every
finished point and every round of the bank. The first child is forked from the parent
after the parent has loaded the compiled model, so it starts in milliseconds instead of
importing and loading numba again (about 1 s, more on a loaded machine); a restarted child
is a fresh ``python -m valve_model_pkg.maps.worker`` process. If no report arrives within a
deadline (``min_timeout_s`` plus ``slack`` times the longest the round or point may
legitimately take), the child is killed and restarted, and the unfinished points are run
one at a time; the point a child hangs on then is retried with its duty moved by
``nudge`` (1e-5, far below the map's resolution); after ``max_nudges`` failures the point
is given up (value NaN). Every such event is recorded in :attr:`PointWorker.incidents`
(and in the map file's notes). Several workers run side by side, one per core.
"""
from __future__ import annotations

import dataclasses
import logging
import math
import os
import signal
import subprocess
import sys
from dataclasses import dataclass, field
from multiprocessing.connection import Connection
from typing import Any

import numpy as np

from .steady_state import SteadyState, SteadyStateCriterion, not_converged, steady_at

__all__ = ['PointRequest', 'PointWorker', 'steady_point', 'run_points_in_process']

_LOG = logging.getLogger(__name__)
#: Past a period boundary by this much so the model has closed the period [s].
_PAST_BOUNDARY_S = 1e-9
#: Model time per wall time assumed for deadlines (a slow, loaded machine) [1].
_SLOW_RATE = 20.0


@dataclass(frozen=True)
class PointRequest:
    """Operating points to bring to steady state (everything the child needs, picklable)."""

    params: dict[str, Any]
    electronics: dict[str, Any]
    supply_voltage_v: float
    output_pressure_pa: float
    criterion: dict[str, Any]
    duty: np.ndarray
    pwm_frequency_hz: np.ndarray
    supply_pressure_pa: np.ndarray
    #: One point at a time (ValveStepper) instead of one bank: after a hang, to find it.
    sequential: bool = False

    def subset(self, idx: list[int], duty: np.ndarray | None = None) -> PointRequest:
        sel = np.asarray(idx, dtype=int)
        return dataclasses.replace(
            self, duty=self.duty[sel] if duty is None else np.asarray(duty, dtype=float),
            pwm_frequency_hz=self.pwm_frequency_hz[sel],
            supply_pressure_pa=self.supply_pressure_pa[sel])


def steady_point(params, electronics, supply_voltage_v: float, crit: SteadyStateCriterion,
                 duty: float, pwm_frequency_hz: float, supply_pressure_pa: float,
                 output_pressure_pa: float = 0.0) -> SteadyState:
    """Simulate one point period by period until it is in periodic steady state.

    Returns
    -------
    SteadyState
        Value as a fraction of x_max.
    """
    from valve_model_pkg.model import ValveStepper
    stepper = ValveStepper(params, electronics, supply_voltage_v, duty=float(duty),
                           pwm_frequency_hz=float(pwm_frequency_hz),
                           supply_pressure_pa=float(supply_pressure_pa),
                           output_pressure_pa=float(output_pressure_pa))
    period = 1.0 / float(pwm_frequency_hz)
    stroke = params.stroke_m
    a = np.empty(crit.max_periods)
    for k in range(crit.max_periods):
        stepper.advance_to((k + 1) * period + _PAST_BOUNDARY_S)
        a[k] = stepper.sample().position_avg_m / stroke
        s = steady_at(a, k, crit)
        if s is not None:
            return s
    return not_converged(a)


def _objects(req: PointRequest):
    from valve_model_pkg.model import ElectronicsConfig, ValveParameters
    return (ValveParameters.from_dict(req.params), ElectronicsConfig.from_dict(req.electronics),
            SteadyStateCriterion.from_dict(req.criterion))


def run_points_in_process(req: PointRequest, report=None, heartbeat=None
                          ) -> list[SteadyState]:
    """Steady states of all points of ``req`` in this process (``report(i, state)``).

    As one bank (``heartbeat(n_active, longest_period_s)`` before every round), or one
    point after the other if ``req.sequential``; the results are the same.
    """
    params, electronics, crit = _objects(req)
    if not req.sequential and req.duty.size > 1:
        return _run_bank(req, params, electronics, crit, report, heartbeat)
    out = []
    for i, (d, f, p) in enumerate(zip(req.duty, req.pwm_frequency_hz,
                                      req.supply_pressure_pa)):
        s = steady_point(params, electronics, req.supply_voltage_v, crit, d, f, p,
                         req.output_pressure_pa)
        out.append(s)
        if report is not None:
            report(i, s)
    return out


def _run_bank(req: PointRequest, params, electronics, crit: SteadyStateCriterion, report,
              heartbeat) -> list[SteadyState]:
    """All points as one ValveBank, one period per round; same results as steady_point."""
    from valve_model_pkg.model.bank import ValveBank
    n = req.duty.size
    freq = np.asarray(req.pwm_frequency_hz, dtype=float)
    bank = ValveBank(params, electronics, req.supply_voltage_v, n_valves=n,
                     duty=[float(v) for v in req.duty], pwm_frequency_hz=freq.tolist(),
                     supply_pressure_pa=[float(v) for v in req.supply_pressure_pa],
                     output_pressure_pa=float(req.output_pressure_pa))
    period = 1.0 / freq
    stroke = params.stroke_m
    a = np.empty((n, crit.max_periods))
    out: list[SteadyState | None] = [None] * n
    active = np.arange(n)
    target = np.zeros(n)
    first = max(crit.min_periods - 1, crit.window)  # steady_at is None before this period
    for k in range(crit.max_periods):
        if heartbeat is not None:
            heartbeat(active.size, float(np.max(period[active])))
        # a finished valve keeps target 0 (it is past it): the bank leaves it alone
        target[active] = (k + 1) * period[active] + _PAST_BOUNDARY_S
        bank.advance_to(target)
        a[active, k] = bank.position_avg_m()[active] / stroke
        if k < first:
            continue
        keep = []
        for i in active.tolist():
            s = steady_at(a[i], k, crit)
            if s is None:
                keep.append(i)
                continue
            out[i] = s
            target[i] = 0.0
            if report is not None:
                report(i, s)
        active = np.asarray(keep, dtype=int)
        if not active.size:
            break
    for i in active.tolist():
        out[i] = not_converged(a[i])
        if report is not None:
            report(i, out[i])
    return out


def _warm_up() -> None:
    """Load (or compile) the compiled model functions the points use."""
    from valve_model_pkg.model import ElectronicsConfig, ValveStepper, load_parameters
    from valve_model_pkg.model.bank import ValveBank
    ValveStepper(load_parameters(), ElectronicsConfig(), duty=0.5).advance_to(0.03)
    bank = ValveBank(load_parameters(), ElectronicsConfig(), n_valves=2, duty=0.5)
    bank.advance_to(np.array([0.03, 0.02]))
    bank.position_avg_m()


def _serve(fd_in: int, fd_out: int) -> None:  # pragma: no cover - runs in the child
    _warm_up()  # nothing to do in a child forked from a warmed-up parent
    rx = Connection(fd_in, readable=True, writable=False)
    tx = Connection(fd_out, readable=False, writable=True)
    tx.send(('ready',))
    while True:
        try:
            req = rx.recv()
        except EOFError:
            return
        if req is None:
            return
        try:
            run_points_in_process(
                req, lambda i, s: tx.send(('point', i, tuple(dataclasses.astuple(s)))),
                lambda n, longest: tx.send(('round', n, longest)))
            tx.send(('done',))
        except Exception as err:  # noqa: BLE001 - reported to the parent, which raises
            tx.send(('error', f'{type(err).__name__}: {err}'))


@dataclass
class PointWorker:
    """A child process computing steady states, restarted if a model call never returns.

    Parameters
    ----------
    min_timeout_s : float
        Smallest wait for the next point or round [s].
    slack : float
        The wait is ``min_timeout_s`` + ``slack`` x (what the round or point simulates at a
        slow 20 s of model time per second: one period of every unfinished point of a
        bank, or ``max_periods`` periods of a single point).
    nudge : float
        Duty offset for a point the model did not return for.
    max_nudges : int
        Retries of such a point before giving it up (NaN).
    """

    min_timeout_s: float = 5.0
    slack: float = 3.0
    nudge: float = 1e-5
    max_nudges: int = 3
    incidents: list[str] = field(default_factory=list)
    #: Fork the first child from this (warmed-up) process where the OS can.
    fork: bool = True
    _proc: Any = None
    _forked_once: bool = False
    _tx: Any = None
    _rx: Any = None
    # (duty, frequency, supply pressure) of points that hung -> duty used instead
    _substitutes: dict[tuple[float, float, float], float] = field(default_factory=dict)

    # --- process management -------------------------------------------------------------
    def start(self) -> None:
        """Start the child (idempotent); returns when it has loaded the model."""
        if self._proc is not None and self._proc.poll() is None:
            return
        req_r, req_w = os.pipe()
        res_r, res_w = os.pipe()
        if self.fork and not self._forked_once and hasattr(os, 'fork'):
            # The first child: a fork of this process with the model already loaded
            # (_warm_up), so it needs no import and no numba cache load. A restart (after
            # a hang, in a parent that may run threads by then) is a fresh interpreter.
            self._forked_once = True
            _warm_up()
            pid = os.fork()
            if pid == 0:  # pragma: no cover - the child
                code = 0
                try:
                    os.close(req_w)
                    os.close(res_r)
                    _serve(req_r, res_w)
                except BaseException:  # noqa: BLE001 - the parent sees the pipe close
                    code = 1
                finally:
                    os._exit(code)
            os.close(req_r)
            os.close(res_w)
            self._proc = _ForkedChild(pid)
            self._tx = Connection(req_w, readable=False, writable=True)
            self._rx = Connection(res_r, readable=True, writable=False)
            return
        env = dict(os.environ)
        env['NUMBA_NUM_THREADS'] = '1'        # one worker per core instead
        # the child imports this very package (source tree or install)
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

    def wait_ready(self, timeout_s: float = 120.0) -> None:
        """Block until the child has loaded the model."""
        if not self._rx.poll(timeout_s):
            self._kill()
            raise RuntimeError(f'the map worker process did not start within {timeout_s:g} s')
        try:
            self._rx.recv()
        except EOFError as err:
            self._kill()
            raise RuntimeError('the map worker process exited while starting') from err

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

    def _kill(self) -> None:
        if self._proc is not None:
            self._proc.kill()
            self._proc.wait()
            self._proc = None
        self._close_pipes()

    def __del__(self) -> None:
        try:
            self.close()
        except Exception:  # noqa: BLE001 - best effort at interpreter exit
            pass

    # --- points ---------------------------------------------------------------------------
    def steady(self, req: PointRequest) -> list[SteadyState]:
        """Steady states of all points; a point given up has value NaN."""
        n = req.duty.size
        results: list[SteadyState | None] = [None] * n
        attempts: dict[int, int] = {}
        pending = list(range(n))
        max_periods = int(req.criterion.get('max_periods', 400))
        if n > 1 and not req.sequential:
            pending = self._steady_bank(req, results)
        req = dataclasses.replace(req, sequential=True)
        while pending:
            keys = [(float(req.duty[i]), float(req.pwm_frequency_hz[i]),
                     float(req.supply_pressure_pa[i])) for i in pending]
            duty = np.array([self._substitutes.get(k, k[0]) for k in keys])
            sub = req.subset(pending, duty)
            if self._proc is None or self._proc.poll() is not None:
                self.start()
                self.wait_ready()
            self._tx.send(sub)
            done = -1
            finished = False
            while True:
                i_next = pending[min(done + 1, len(pending) - 1)]
                wait = self.min_timeout_s + self.slack * max_periods / (
                    float(req.pwm_frequency_hz[i_next]) * _SLOW_RATE)
                if not self._rx.poll(wait):
                    break
                try:
                    msg = self._rx.recv()
                except EOFError:
                    code = self._proc.poll() if self._proc is not None else None
                    self._kill()
                    raise RuntimeError(f'the map worker process died (exit code {code})') \
                        from None
                if msg[0] == 'point':
                    done = int(msg[1])
                    results[pending[done]] = SteadyState(*msg[2])
                elif msg[0] == 'round':
                    continue
                elif msg[0] == 'done':
                    finished = True
                    break
                else:
                    raise RuntimeError(f'model failed in the map worker: {msg[1]}')
            if finished:
                break
            # the child is stuck on point pending[done + 1]: restart, nudge it, go on
            self._kill()
            hung = pending[done + 1]
            key = keys[done + 1]
            attempts[hung] = attempts.get(hung, 0) + 1
            where = (f'duty {key[0]:.6g} at {key[1]:g} Hz, {key[2]:g} Pa '
                     f'(no answer within {wait:.0f} s)')
            if attempts[hung] > self.max_nudges:
                results[hung] = SteadyState(False, 0, 0, math.nan)
                self._note(f'model did not return for {where} even after {self.max_nudges} '
                           'nudges; point left out')
                pending = pending[done + 2:]
            else:
                sign = 1.0 if key[0] < 0.5 else -1.0
                new = min(max(key[0] + sign * attempts[hung] * self.nudge, 0.0), 1.0)
                self._substitutes[key] = new
                self._note(f'model did not return for {where}; simulated at duty {new:.6g} '
                           'instead')
                pending = pending[done + 1:]
        return [s if s is not None else SteadyState(False, 0, 0, math.nan) for s in results]

    def _steady_bank(self, req: PointRequest, results: list) -> list[int]:
        """All points as one bank in the child; returns those left by a hang (else [])."""
        if self._proc is None or self._proc.poll() is not None:
            self.start()
            self.wait_ready()
        self._tx.send(req)
        freq = np.asarray(req.pwm_frequency_hz, dtype=float)
        # until the first round report: one period of every point
        wait = self.min_timeout_s + self.slack * float(np.sum(1.0 / freq)) / _SLOW_RATE
        while True:
            if not self._rx.poll(wait):
                break
            try:
                msg = self._rx.recv()
            except EOFError:
                code = self._proc.poll() if self._proc is not None else None
                self._kill()
                raise RuntimeError(f'the map worker process died (exit code {code})') \
                    from None
            if msg[0] == 'point':
                results[int(msg[1])] = SteadyState(*msg[2])
            elif msg[0] == 'round':
                # the next round simulates one period of each of msg[1] points
                wait = self.min_timeout_s + self.slack * msg[1] * msg[2] / _SLOW_RATE
            elif msg[0] == 'done':
                return []
            else:
                raise RuntimeError(f'model failed in the map worker: {msg[1]}')
        # no report within the deadline: the bank is stuck on one of its unfinished
        # points; run them one at a time to find it (and nudge it)
        self._kill()
        left = [i for i, r in enumerate(results) if r is None]
        self._note(f'model did not return within {wait:.0f} s for a bank of {len(left)} '
                   'unfinished point(s); running them one at a time')
        return left

    def _note(self, text: str) -> None:
        _LOG.warning('%s', text)
        self.incidents.append(text)


class _ForkedChild:
    """The ``poll``/``wait``/``kill`` of :class:`subprocess.Popen` for a forked child."""

    def __init__(self, pid: int) -> None:
        self.pid = pid
        self.returncode: int | None = None

    def poll(self) -> int | None:
        if self.returncode is None:
            pid, status = os.waitpid(self.pid, os.WNOHANG)
            if pid == self.pid:
                self.returncode = os.waitstatus_to_exitcode(status)
        return self.returncode

    def wait(self, timeout: float | None = None) -> int:
        import time
        end = None if timeout is None else time.monotonic() + timeout
        while self.poll() is None:
            if end is not None and time.monotonic() > end:
                raise subprocess.TimeoutExpired(f'forked map worker {self.pid}', timeout)
            time.sleep(0.005)
        return self.returncode

    def kill(self) -> None:
        if self.poll() is None:
            try:
                os.kill(self.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass


if __name__ == '__main__':  # pragma: no cover - the child process
    _serve(int(sys.argv[1]), int(sys.argv[2]))
