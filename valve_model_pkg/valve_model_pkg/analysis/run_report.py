"""The report of a suite run: ``report.md`` with plots, and ``report.json``, from its bag.

``report.md`` is for a person: the run (clock, real-time factor, lockstep timeouts), the
message count and sequence continuity of every topic, a table per position step (settling
time, overshoot, steady-state error), plots (piston position and setpoint, chamber
pressure, commanded and achieved mass flow, PWM duty, coil current, and a close-up of the
valve at its busiest) and a summary of the valve. ``report.json`` holds every figure of
``report.md``, so pages generated from it show the same run.
"""
from __future__ import annotations

import json
import os
import time
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

import numpy as np

from ..errors import RunAnalysisError
from ..interface import (ATMOSPHERIC_PRESSURE_PA, TOPIC_DUTY_COMMAND, TOPIC_FLOW_COMMAND,
                         TOPIC_JOINT_STATES, TOPIC_OUTPUT_PRESSURE, TOPIC_POSITION_SETPOINT,
                         TOPIC_STATE)
from ..recording import TopicData, load_bag, sequence_gaps
from .plots import Line, Panel, Span, moving_mean, plot_panels, with_gaps
from .steps import MIN_SETTLED_DWELL_S, SETTLING_BAND_M, StepResult, step_results, steps_at
from .timebase import RunTimeBase, own_times_s, run_time_base

__all__ = ['RunReport', 'TopicSummary', 'write_run_report', 'topic_summaries',
           'ValveSummary', 'valve_summary']

#: Length of the valve close-up [s]: three 50 Hz PWM periods.
CLOSEUP_S = 0.06
#: Window of the achieved flow's moving mean in the overview [s].
_FLOW_MEAN_S = 0.02
#: Window of the coil current's moving mean when ValveState has no interval mean [s].
_CURRENT_MEAN_S = 1e-3
#: ``ValveState.source`` of the CAN driver.
_SOURCE_CAN = 1


@dataclass(frozen=True)
class TopicSummary:
    """Messages of one topic in a bag.

    Attributes
    ----------
    topic, msgtype : str
    messages : int
    rate_hz : float
        Mean rate over the topic's own times (header stamps, else receive times) [Hz].
    sequence_gaps, lost : int or None
        Gaps in its ``sequence`` field and the messages missing there (None without one).
    """

    topic: str
    msgtype: str
    messages: int
    rate_hz: float
    sequence_gaps: int | None
    lost: int | None

    def to_json(self) -> dict:
        """As report.json has it."""
        return {'topic': self.topic, 'type': self.msgtype, 'messages': self.messages,
                'rate_hz': self.rate_hz, 'sequence_gaps': self.sequence_gaps,
                'lost': self.lost}


def topic_summaries(data: Mapping[str, TopicData], origin_ns: int) -> list[TopicSummary]:
    """Count, rate and sequence continuity of every topic, sorted by name.

    Parameters
    ----------
    data : mapping of str to TopicData
        :func:`valve_model_pkg.recording.load_bag` of the run.
    origin_ns : int
        Time zero of the topics' own times [ns].
    """
    out = []
    for name, topic in sorted(data.items()):
        t = own_times_s(topic, origin_ns)
        rate = (len(topic) - 1) / (t[-1] - t[0]) if len(topic) > 1 and t[-1] > t[0] else 0.0
        gaps = lost = None
        if 'sequence' in topic.fields:
            gaps, lost = sequence_gaps(topic['sequence'])
        out.append(TopicSummary(name, topic.msgtype, len(topic), float(rate), gaps, lost))
    return out


@dataclass(frozen=True)
class ValveSummary:
    """The plotted valve's ``valve/state`` over the run.

    Attributes
    ----------
    messages : int
    rate_hz : float
        Mean rate over its stamps [Hz].
    sequence_gaps, lost : int
    backend : str
        ``'CAN driver'`` or ``'simulator'`` (``source`` of the first message).
    mean_duty_pct : float
    peak_current_a : float
    mean_flow_g_s : float
        Mean ``mass_flow`` [g/s].
    """

    messages: int
    rate_hz: float
    sequence_gaps: int
    lost: int
    backend: str
    mean_duty_pct: float
    peak_current_a: float
    mean_flow_g_s: float


def valve_summary(state: TopicData, t_s: np.ndarray) -> ValveSummary:
    """Summary of a ``valve/state`` topic whose stamps are ``t_s`` [s]."""
    n_gaps, n_lost = sequence_gaps(state['sequence']) if 'sequence' in state.fields \
        else (0, 0)
    rate = (len(state) - 1) / (t_s[-1] - t_s[0]) if len(state) > 1 and t_s[-1] > t_s[0] \
        else 0.0
    return ValveSummary(
        messages=int(len(state)), rate_hz=float(rate), sequence_gaps=int(n_gaps),
        lost=int(n_lost),
        backend='CAN driver' if int(state['source'][0]) == _SOURCE_CAN else 'simulator',
        mean_duty_pct=float(np.mean(state['duty']) * 100),
        peak_current_a=float(np.max(state['coil_current'])),
        mean_flow_g_s=float(np.mean(state['mass_flow']) * 1e3))


@dataclass(frozen=True)
class RunReport:
    """Where a run report went, and its figures (``report.json``)."""

    markdown: Path
    json: Path
    summary: dict


def _run_lines(info: Mapping) -> list[str]:
    """The report's ``## Run`` section from the run's information (empty without)."""
    if not info:
        return []
    lines = ['## Run', '']
    rtf = info.get('real_time_factor')
    if 'clock' in info:
        lines.append(f'- clock: {info["clock"]}')
    if rtf is not None:
        lines.append(f'- real-time factor (simulated / wall time): {rtf:.2f}')
    if 'lockstep_timeouts' in info:
        lines.append(f'- lockstep timeouts: {info["lockstep_timeouts"]}'
                     + (f' (last: {info["last_lockstep_timeout"]})'
                        if info.get('last_lockstep_timeout') else
                        ' (every control tick waited for its command: deterministic)'))
    if info.get('clock_note'):
        lines.append(f'- {info["clock_note"]}')
    return lines + ['']


def _topic_lines(topics: list[TopicSummary]) -> list[str]:
    lines = ['## Topics', '', '| topic | type | messages | rate [Hz] | sequence gaps |',
             '|---|---|---|---|---|']
    for s in topics:
        gaps = '' if s.sequence_gaps is None else f'{s.sequence_gaps} ({s.lost} lost)'
        lines.append(f'| `{s.topic}` | {s.msgtype} | {s.messages} | {s.rate_hz:.1f} | '
                     f'{gaps} |')
    return lines + ['']


def _step_lines(steps: list[StepResult]) -> list[str]:
    lines = ['## Position steps', '',
             '| at [s] | setpoint [mm] | final [mm] | overshoot [mm] | '
             'settling (+-1 mm) [s] | steady error [mm] |',
             '|---|---|---|---|---|---|']
    for s in steps:
        settle = f'{s.settling_time_s:.2f}' if s.settled \
            else 'not settled (left the band before the end of the step)'
        lines.append(f'| {s.start_s:.2f} | {s.setpoint_m * 1e3:.1f} | '
                     f'{s.final_m * 1e3:.2f} | {s.overshoot_m * 1e3:.2f} | {settle} | '
                     f'{s.steady_error_m * 1e3:+.2f} |')
    return lines + ['']


class _Position(NamedTuple):
    """The position panel and the steps (None without setpoints)."""

    panel: Panel | None
    steps: list[StepResult] | None


def _position(data: Mapping[str, TopicData], clock: RunTimeBase,
              info: Mapping) -> _Position:
    """Piston position and setpoint; the steps from the setpoints on the run's clock.

    A run that states when its goals took effect (``goal_times_s``: stamp-clock seconds,
    one per entry of ``goals``) has its steps placed there; otherwise each setpoint (no
    header) at the joint state received before it (:class:`RunTimeBase`).
    """
    joints = data.get('/' + TOPIC_JOINT_STATES)
    if joints is None or not len(joints):
        return _Position(None, None)
    tj = own_times_s(joints, clock.origin_ns)
    pos = np.array([p[0] for p in joints['position']], dtype=float)
    lines = [Line(*with_gaps(tj, pos * 1e3), 'position', '-')]
    steps = None
    setp = data.get('/' + TOPIC_POSITION_SETPOINT)
    if setp is not None and len(setp):
        tsp = clock.times_s(setp)
        sp = setp['data'].astype(float)
        lines.append(Line(tsp, sp * 1e3, 'setpoint', '--'))
        known = _goal_steps(info, clock.origin_ns)
        steps = step_results(tsp, sp, tj, pos) if known is None \
            else steps_at(known[0], known[1], tj, pos)
    return _Position(Panel('position [mm]', lines), steps)


def _goal_steps(info: Mapping, origin_ns: int) -> tuple[np.ndarray, np.ndarray] | None:
    """Start times [s from ``origin_ns``] and setpoints [m] of the run's goals, from
    ``goal_times_s`` and ``goals``; None when the run does not state them."""
    times, goals = info.get('goal_times_s'), info.get('goals')
    if not times or not goals or len(times) != len(goals):
        return None
    start_ns = np.round(np.asarray(times, dtype=float) * 1e9).astype(np.int64) - origin_ns
    return start_ns * 1e-9, np.array([g['position_mm'] * 1e-3 for g in goals], dtype=float)


def _valve_panels(data: Mapping[str, TopicData], vtopic, state: TopicData, ts: np.ndarray,
                  origin_ns: int) -> list[Panel]:
    """Chamber pressure, mass flow, duty and coil current of the plotted valve."""
    panels = []
    pressure = data.get(vtopic(TOPIC_OUTPUT_PRESSURE))
    if pressure is not None and len(pressure):
        panels.append(Panel('chamber pressure\n[bar gauge]', [
            Line(own_times_s(pressure, origin_ns),
                 (pressure['fluid_pressure'] - ATMOSPHERIC_PRESSURE_PA) / 1e5, 'chamber', '-')]))
    flow_lines = []
    flow_cmd = data.get(vtopic(TOPIC_FLOW_COMMAND))
    if flow_cmd is not None and len(flow_cmd):
        flow_lines.append(Line(own_times_s(flow_cmd, origin_ns), flow_cmd['mass_flow'] * 1e3,
                               'commanded', '-'))
    seq = state['sequence'] if 'sequence' in state.fields else None
    flow_lines.append(Line(*with_gaps(ts, moving_mean(ts, state['mass_flow'], _FLOW_MEAN_S)
                                      * 1e3, seq), 'achieved (valve/state, 20 ms mean)', '-'))
    panels.append(Panel('mass flow [g/s]', flow_lines))
    duty_lines = [Line(*with_gaps(ts, state['duty'] * 100.0, seq), 'in force (valve/state)',
                       '-')]
    duty_cmd = data.get(vtopic(TOPIC_DUTY_COMMAND))
    if duty_cmd is not None and len(duty_cmd):
        duty_lines.insert(0, Line(own_times_s(duty_cmd, origin_ns), duty_cmd['duty'] * 100.0,
                                  'commanded', '.'))
    panels.append(Panel('duty [%]', duty_lines))
    t_cur, y_cur, label_cur = _current_line(ts, state)
    panels.append(Panel('coil current [A]', [Line(*with_gaps(t_cur, y_cur, seq), label_cur,
                                                  '-')]))
    return panels


def _current_line(ts: np.ndarray, state: TopicData) -> tuple[np.ndarray, np.ndarray, str]:
    """The interval-mean current if ValveState carries it (a finite value), else a 1 ms
    moving mean of the sampled current, labelled as such."""
    for name in state.fields:
        if 'current' in name and ('mean' in name or 'avg' in name) \
                and np.isfinite(np.asarray(state[name], dtype=float)).any():
            return ts, state[name], f'{name} (interval mean)'
    return (ts, moving_mean(ts, state['coil_current'], _CURRENT_MEAN_S),
            'coil current, 1 ms moving mean of the valve/state samples (no interval mean '
            'in ValveState)')


def _closeup(out: Path, state: TopicData, ts: np.ndarray, mid: int) -> Path:
    """Voltage, current and spool position over CLOSEUP_S from sample ``mid``."""
    sel = (ts >= ts[mid]) & (ts < ts[mid] + CLOSEUP_S)
    path = out / 'closeup.png'
    plot_panels(path, float(ts[mid]), [
        Panel('voltage [V]', [Line(*with_gaps(ts[sel], state['coil_voltage'][sel]), 'voltage',
                                   '-')]),
        Panel('current [A]', [Line(*with_gaps(ts[sel], state['coil_current'][sel]),
                                   'current (instantaneous samples)', '-')]),
        Panel('spool position\n[mm]', [
            Line(*with_gaps(ts[sel], state['spool_position'][sel] * 1e3), 'x', '-'),
            Line(*with_gaps(ts[sel], state['spool_position_avg'][sel] * 1e3),
                 'x averaged over the PWM period', '--')]),
    ], f'valve close-up: 60 ms from t = {ts[mid]:.2f} s (shaded in the overview)')
    return path


def _machine() -> dict:
    """When and on what the report was written: local time, load average, cores."""
    try:
        load = [float(v) for v in Path('/proc/loadavg').read_text().split()[:3]]
    except (OSError, ValueError):
        load = None
    return {'written_at': time.strftime('%Y-%m-%dT%H:%M:%S%z'), 'load_average': load,
            'cpu_count': os.cpu_count()}


def write_run_report(bag: str | Path, out: str | Path, title: str = 'valve suite run',
                     run_info: Mapping | None = None, valve: str = '') -> RunReport:
    """Write ``out/report.md``, ``out/report.json`` and the plots from a suite bag.

    Parameters
    ----------
    bag : str or pathlib.Path
        A bag recorded from the suite (at least ``valve/state``).
    out : str or pathlib.Path
        Output directory (created).
    title : str
        The report's title.
    run_info : mapping, optional
        What the run knows beyond the bag (the demo: clock, real-time factor, lockstep
        timeouts, backend, goals, ...): shown in ``## Run`` and copied into report.json.
        With ``goal_times_s`` (the stamp-clock time [s] each of ``goals`` took effect)
        the steps start there instead of at the recorded setpoints.
    valve : str
        Namespace of the valve whose topics are plotted ('' = none; the double
        cylinder's ``cap``).

    Returns
    -------
    RunReport

    Raises
    ------
    RunAnalysisError
        The bag has no ``valve/state`` of that valve.
    BagFormatError
        The path is not a readable bag.
    """
    def vtopic(name: str) -> str:
        return f'/{valve}/{name}' if valve else '/' + name
    bag, out = Path(bag), Path(out)
    data = load_bag(bag)
    out.mkdir(parents=True, exist_ok=True)
    state = data.get(vtopic(TOPIC_STATE))
    if state is None or len(state) == 0:
        raise RunAnalysisError(f'{bag}: no {vtopic(TOPIC_STATE)} messages; is it a bag of the '
                               'suite?')
    origin = int(state.stamp_ns[0])
    ts = own_times_s(state, origin)
    info = dict(run_info or {})
    topics = topic_summaries(data, origin)
    position = _position(data, run_time_base(data, origin), info)
    steps = position.steps or []
    lines = [f'# {title}', '', f'Bag: `{bag}`', '', *_run_lines(info), *_topic_lines(topics)]
    if position.steps is not None:
        lines += _step_lines(steps)
    panels = ([position.panel] if position.panel else []) \
        + _valve_panels(data, vtopic, state, ts, origin)
    # the close-up at the busiest time (the largest duty below 100 %); the overview marks it
    mid = int(np.argmax(state['duty'] * (state['duty'] < 1.0)))
    overview = out / 'overview.png'
    plot_panels(overview, 0.0, panels, title,
                span=Span(float(ts[mid]), float(ts[mid]) + CLOSEUP_S,
                          f'close-up at {ts[mid]:.2f} s (closeup.png)'))
    closeup = _closeup(out, state, ts, mid)
    vs = valve_summary(state, ts)
    lines += ['## Plots', '', f'![overview]({overview.name})', '',
              f'![close-up]({closeup.name})', '',
              '## Valve', '', f'- state messages: {vs.messages}, backend: {vs.backend}',
              f'- mean duty {vs.mean_duty_pct:.1f} %, peak current {vs.peak_current_a:.3f} A, '
              f'mean flow {vs.mean_flow_g_s:.3f} g/s', '']
    report = out / 'report.md'
    report.write_text('\n'.join(lines) + '\n')
    summary = {
        'title': title, 'bag': str(bag), **info,
        'steps': [s.to_json() for s in steps],
        'all_settled': bool(steps) and all(s.settled for s in steps),
        'valve_state': {'messages': vs.messages, 'rate_hz': vs.rate_hz,
                        'sequence_gaps': vs.sequence_gaps, 'lost': vs.lost},
        'settling_band_mm': SETTLING_BAND_M * 1e3,
        'min_settled_dwell_s': MIN_SETTLED_DWELL_S,
        'valve': {'namespace': valve, 'backend': vs.backend,
                  'mean_duty_pct': vs.mean_duty_pct, 'peak_current_a': vs.peak_current_a,
                  'mean_flow_g_s': vs.mean_flow_g_s},
        'topics': [s.to_json() for s in topics],
        'plots': {'overview': overview.name, 'closeup': closeup.name,
                  'closeup_start_s': float(ts[mid])},
        **_machine(),
    }
    path = out / 'report.json'
    path.write_text(json.dumps(summary, indent=2, default=str) + '\n')
    return RunReport(report, path, summary)
