"""The simulators' real-time loop: model time follows the clock on a grid of sample instants.

``valve_simulator`` (one :class:`~valve_model_pkg.model.ValveStepper`) and
``valve_bank_simulator`` (a :class:`~valve_model_pkg.model.bank.ValveBank`) run the same
loop; each gives it three actions: advance the model to a model time, publish the state
at a clock stamp, restart the model at t = 0. Rules, one per tick (:meth:`TickLoop.tick`):

* **Sample grid.** States are published on an exact grid of model time, one per
  ``period_s``, each stamped with the clock time of that instant (the clock time of model
  time 0 plus the grid time). A tick that comes late publishes the grid points it missed,
  so the stream stays complete and evenly stamped when the executor is held up.
* **Bounded work.** If the clock is more than ``max_advance_s`` ahead of the next grid
  point (a stalled process, a jump in simulated time), the grid points beyond the bound are
  skipped: the model moves on to the clock without integrating the gap (model time 0 is
  moved forward by the skipped time), and the tick is reported as fallen behind.
* **Clock going backwards** (a replayed bag looping): the model restarts at t = 0 at the
  new clock time.
* A clock at 0 (``use_sim_time`` before the first ``/clock``) is no tick.

The loop is free of ROS: clock times are integer nanoseconds, wall times seconds.
"""
from __future__ import annotations

import time
from collections.abc import Callable

__all__ = ['TickLoop']


class TickLoop:
    """The real-time loop of a simulator node, with its statistics.

    Parameters
    ----------
    period_s : float
        Sample period, s (1 / publish rate).
    max_advance_s : float
        Most model time integrated in one tick, s.
    advance_to : callable(float)
        Integrates the model to a model time, s.
    publish : callable(int)
        Publishes the model's state, stamped with a clock time, ns.
    restart : callable()
        The clock went backwards: reset the model to t = 0 (and say so).
    samples_label : str
        Names the samples in the "took longer than their period" reason.
    wall_clock : callable() -> float
        Monotonic wall time, s.

    Attributes
    ----------
    ticks, behind_ticks, late_samples : int
        Ticks run, ticks that fell behind, samples published by a tick after their time.
    skipped_model_s : float
        Model time skipped without integration, s.
    last_behind_reason : str
        Why the last tick that fell behind did.
    max_tick_compute_s : float
        Longest tick since :meth:`close_window`, s.
    achieved_rate_hz : float
        Samples per wall second over the last closed window.
    """

    def __init__(self, period_s: float, max_advance_s: float, *,
                 advance_to: Callable[[float], None], publish: Callable[[int], None],
                 restart: Callable[[], None], samples_label: str = 'sample(s)',
                 wall_clock: Callable[[], float] = time.monotonic) -> None:
        self.period_s = float(period_s)
        self.max_advance_s = float(max_advance_s)
        self._advance_to = advance_to
        self._publish = publish
        self._restart = restart
        self._samples_label = samples_label
        self._wall = wall_clock
        self._t0_ns: int | None = None        # clock time at model time 0
        self._last_now_ns: int | None = None
        self._last_tick_wall: float | None = None
        self._next_sample = 0                 # index of the next sample-grid instant
        self.ticks = 0
        self.behind_ticks = 0
        self.late_samples = 0
        self.skipped_model_s = 0.0
        self.last_behind_reason = ''
        self.max_tick_compute_s = 0.0
        self.achieved_rate_hz = 0.0
        self._window_start_wall = self._wall()
        self._window_samples = 0

    def tick(self, now_ns: int) -> str:
        """Advance the model to the clock ``now_ns``, publishing every grid instant passed.

        Returns
        -------
        str
            Why this tick fell behind ('' if it did not).
        """
        wall_start = self._wall()
        if now_ns == 0:  # use_sim_time and no /clock yet
            return ''
        if self._t0_ns is None or (self._last_now_ns is not None
                                   and now_ns < self._last_now_ns):
            if self._t0_ns is not None:
                self._restart()
            self._t0_ns = now_ns
            self._next_sample = 0
        self._last_now_ns = now_ns
        target_s = (now_ns - self._t0_ns) * 1e-9
        reasons = []
        if self._last_tick_wall is not None:
            gap = wall_start - self._last_tick_wall
            if gap > 2.0 * self.period_s:
                reasons.append(f'tick came {gap * 1e3:.2f} ms after the previous one '
                               f'(period {self.period_s * 1e3:.3g} ms)')
        self._last_tick_wall = wall_start
        skip_reason, target_s = self._bound_lag(target_s)
        if skip_reason:
            reasons.append(skip_reason)
        published = self._publish_grid(target_s)
        compute = self._wall() - wall_start
        self.max_tick_compute_s = max(self.max_tick_compute_s, compute)
        if compute > self.period_s * max(1, published):
            reasons.append(f'tick took {compute * 1e3:.2f} ms for {published} '
                           f'{self._samples_label}, longer than their period')
        self.ticks += 1
        self._window_samples += published
        if not reasons:
            return ''
        self.behind_ticks += 1
        self.last_behind_reason = '; '.join(reasons)
        return self.last_behind_reason

    def _bound_lag(self, target_s: float) -> tuple[str, float]:
        """Skip the grid points beyond ``max_advance_s``: (reason or '', new target)."""
        lag = target_s - self._next_sample * self.period_s
        if lag <= self.max_advance_s:
            return '', target_s
        skip = int((lag - self.max_advance_s) / self.period_s) + 1
        skipped = skip * self.period_s
        self.skipped_model_s += skipped
        self._t0_ns += int(round(skipped * 1e9))
        return (f'model {lag * 1e3:.1f} ms behind the clock; '
                f'{skipped * 1e3:.1f} ms skipped without integration'), target_s - skipped

    def _publish_grid(self, target_s: float) -> int:
        """Advance to and publish every grid instant up to ``target_s``; how many."""
        published = 0
        while self._next_sample * self.period_s <= target_s + 1e-12:
            t_sample = self._next_sample * self.period_s
            self._advance_to(t_sample)
            self._publish(self._t0_ns + int(round(t_sample * 1e9)))
            self._next_sample += 1
            published += 1
        if published > 1:
            self.late_samples += published - 1
        return published

    def close_window(self) -> None:
        """End a diagnostics window: set :attr:`achieved_rate_hz` from its samples."""
        wall = self._wall()
        elapsed = wall - self._window_start_wall
        if elapsed > 0:
            self.achieved_rate_hz = self._window_samples / elapsed
        self._window_start_wall, self._window_samples = wall, 0
