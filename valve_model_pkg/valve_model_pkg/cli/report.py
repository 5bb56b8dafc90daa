"""valve_report: a Markdown report with plots from a bag recorded from the suite.

    valve_report BAG [-o DIR] [--title TEXT]

Reads the bag with valve_model_pkg.recording.load_bag (no ROS needed) and writes
``DIR/report.md`` with ``DIR/*.png``: piston position and setpoint, chamber pressure,
commanded and achieved mass flow, PWM duty, coil current; a table per position step
(settling time, overshoot, steady-state error); and the message count and sequence
continuity of every topic.

Exit status: 0 written, 2 refused input (no such bag, not a bag of the suite; one line
naming it), 1 a failure inside (writing the report).
"""
from __future__ import annotations

import argparse
import logging
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from valve_model_pkg.interface import (ATMOSPHERIC_PRESSURE_PA, TOPIC_DUTY_COMMAND,
                                       TOPIC_FLOW_COMMAND, TOPIC_JOINT_STATES,
                                       TOPIC_OUTPUT_PRESSURE, TOPIC_POSITION_SETPOINT,
                                       TOPIC_STATE)
from valve_model_pkg.recording import load_bag, sequence_gaps
from valve_model_pkg.errors import RecordingError

__all__ = ['main', 'StepResult', 'step_results', 'write_report']


@dataclass(frozen=True)
class StepResult:
    """How the piston answered one setpoint step."""

    start_s: float
    setpoint_m: float
    final_m: float
    overshoot_m: float
    settling_time_s: float | None   # into +-band and stays; None if it never settles
    steady_error_m: float

    @property
    def settled(self) -> bool:
        """Whether the position entered the band and stayed in it to the end of the window."""
        return self.settling_time_s is not None

    def to_json(self) -> dict:
        """The step as report.json has it (mm, s)."""
        return {'start_s': round(self.start_s, 6), 'setpoint_mm': self.setpoint_m * 1e3,
                'final_mm': self.final_m * 1e3, 'overshoot_mm': self.overshoot_m * 1e3,
                'settling_s': self.settling_time_s, 'steady_error_mm': self.steady_error_m * 1e3,
                'settled': self.settled}


#: Least time the position must stay in the band at the end of a step's window to count as
#: settled [s]: a swing that passes through the band as the window ends is not settled.
MIN_SETTLED_DWELL_S = 0.25


def _times(topic, origin_ns: int) -> np.ndarray:
    ns = topic.stamp_ns if topic.stamp_ns is not None else topic.log_time_ns
    return (ns - origin_ns) * 1e-9


def step_results(t_set: np.ndarray, setpoint: np.ndarray, t_pos: np.ndarray,
                 position: np.ndarray, band_m: float = 1e-3,
                 include_initial: bool = False) -> list[StepResult]:
    """Split the run at setpoint changes and characterise each step.

    Settling time: from the step to the first instant after which the position stays
    within ``band_m`` of the setpoint until the next step, for at least
    ``MIN_SETTLED_DWELL_S`` (or the whole window if it is shorter than twice that);
    otherwise the step is not settled. Steady-state error: mean error over the last 10 %
    of the step. The segment before the first setpoint change (the pre-roll at the initial
    setpoint) is no step and is left out unless ``include_initial``.
    """
    if setpoint.size == 0 or position.size == 0:
        return []
    change = np.flatnonzero(np.abs(np.diff(setpoint)) > 1e-9) + 1
    starts = np.concatenate([[0], change])
    results = []
    for k, i0 in enumerate(starts):
        if k == 0 and not include_initial:
            continue
        t0 = t_set[i0]
        t1 = t_set[starts[k + 1]] if k + 1 < len(starts) else t_pos[-1]
        sp = float(setpoint[i0])
        sel = (t_pos >= t0) & (t_pos < t1)
        if sel.sum() < 5:
            continue
        tt, yy = t_pos[sel], position[sel]
        err = yy - sp
        previous = float(position[np.searchsorted(t_pos, t0) - 1]) if t0 > t_pos[0] else yy[0]
        direction = np.sign(sp - previous) or 1.0
        overshoot = max(0.0, float(np.max(direction * err)))
        outside = np.flatnonzero(np.abs(err) > band_m)
        dwell = min(MIN_SETTLED_DWELL_S, 0.5 * (t1 - t0))
        if outside.size == 0:
            settle = 0.0
        elif outside[-1] + 1 < tt.size and t1 - tt[outside[-1] + 1] >= dwell:
            settle = float(tt[outside[-1] + 1] - t0)
        else:
            settle = None
        tail = tt >= t1 - 0.1 * (t1 - t0)
        results.append(StepResult(float(t0), sp, float(yy[-1]), overshoot, settle,
                                  float(np.mean(err[tail]))))
    return results


def _with_gaps(t: np.ndarray, y: np.ndarray, sequence: np.ndarray | None = None
               ) -> tuple[np.ndarray, np.ndarray]:
    """Insert NaN where samples are missing (a sequence gap, or more than 2.5 periods), so
    a plot draws lost samples as gaps instead of a line across them."""
    if t.size < 3:
        return t, y
    dt = float(np.median(np.diff(t)))
    broken = np.diff(t) > 2.5 * dt
    if sequence is not None and sequence.size == t.size:
        broken |= np.diff(sequence.astype(np.int64)) != 1
    idx = np.flatnonzero(broken) + 1
    if idx.size == 0:
        return t, y
    return (np.insert(t.astype(float), idx, np.nan),
            np.insert(np.asarray(y, dtype=float), idx, np.nan))


def _plot(path: Path, t0_s: float, series: list[tuple[str, list[tuple]]],
          title: str, span: tuple[float, float, str] | None = None) -> None:
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(len(series), 1, figsize=(11, 2.3 * len(series)), sharex=True)
    axes = np.atleast_1d(axes)
    for ax, (ylabel, lines) in zip(axes, series):
        for t, y, label, style in lines:
            ax.plot(t - t0_s, y, style, label=label, linewidth=1.0)
        if span is not None:  # where the close-up is, in every panel of the overview
            ax.axvspan(span[0] - t0_s, span[1] - t0_s, color='tab:orange', alpha=0.25,
                       label=span[2])
        ax.set_ylabel(ylabel)
        ax.grid(True, alpha=0.3)
        if len(lines) > 1 or span is not None:
            ax.legend(loc='upper right', fontsize=8)
    axes[-1].set_xlabel('time [s]')
    axes[0].set_title(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _period_mean(t: np.ndarray, y: np.ndarray, window_s: float) -> np.ndarray:
    """Moving mean over ``window_s`` (the achieved flow, smoothed over a PWM period)."""
    if t.size < 2:
        return y
    dt = float(np.median(np.diff(t)))
    n = max(1, int(round(window_s / dt)))
    kernel = np.ones(n) / n
    return np.convolve(y, kernel, mode='same')


def _sim_time_map(data: dict, origin: int):
    """For a bag on simulation time: log time -> stamp time, from cylinder/joint_states.

    A message without a header (cylinder/position_setpoint, std_msgs/Float64) has only the
    recorder's receive time (wall clock). On simulation time that is another time base;
    it gets the stamp of the last joint state received before it (the tick it belongs to:
    in lockstep the controller publishes it while the simulation waits for its answer).
    Returns None for a bag on wall-clock time.
    """
    joints = data.get('/' + TOPIC_JOINT_STATES)
    if joints is None or len(joints) < 2 or joints.stamp_ns is None:
        return None
    if abs(int(joints.log_time_ns[0]) - int(joints.stamp_ns[0])) < 3_600 * 10**9:
        return None  # stamps and receive times agree: wall clock
    log = np.asarray(joints.log_time_ns, dtype=np.int64)
    stamp = np.asarray(joints.stamp_ns, dtype=np.int64)
    order = np.argsort(log, kind='stable')
    log, stamp = log[order], np.maximum.accumulate(stamp[order])

    def to_stamp(topic) -> np.ndarray:
        i = np.searchsorted(log, np.asarray(topic.log_time_ns, dtype=np.int64), 'right') - 1
        return (stamp[np.clip(i, 0, None)] - origin) * 1e-9
    return to_stamp


def _current_line(ts: np.ndarray, state) -> tuple:
    """The current panel: the interval-mean current if ValveState carries it (a finite
    value), else a 1 ms moving mean of the sampled current, labelled as such."""
    for name in state.fields:
        if 'current' in name and ('mean' in name or 'avg' in name) \
                and np.isfinite(np.asarray(state[name], dtype=float)).any():
            return (ts, state[name], f'{name} (interval mean)', '-')
    return (ts, _period_mean(ts, state['coil_current'], 1e-3),
            'coil current, 1 ms moving mean of the valve/state samples (no interval mean '
            'in ValveState)', '-')


def write_report(bag: Path, out: Path, title: str = 'valve suite run',
                 run_info: dict | None = None, valve: str = '') -> Path:
    """Write ``out/report.md``, ``out/report.json`` and the plots from ``bag``.

    ``run_info`` (from the demo: clock, real-time factor, lockstep timeouts, backend ...)
    goes into both. ``valve`` is the namespace of the valve whose topics are plotted
    ('' = none; the double cylinder's ``cap``). Returns the report path.
    """
    def vtopic(name: str) -> str:
        return f'/{valve}/{name}' if valve else '/' + name
    data = load_bag(bag)
    out.mkdir(parents=True, exist_ok=True)
    state = data.get(vtopic(TOPIC_STATE))
    if state is None or len(state) == 0:
        raise ValueError(f'{bag}: no {vtopic(TOPIC_STATE)} messages; is it a bag of the '
                         'suite?')
    origin = int(state.stamp_ns[0])
    ts = _times(state, origin)
    lines = [f'# {title}', '', f'Bag: `{bag}`', '']
    info = dict(run_info or {})
    summary = {'title': title, 'bag': str(bag), **info}
    if info:
        lines += ['## Run', '']
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
        lines.append('')
    sim_map = _sim_time_map(data, origin)

    # --- topics -----------------------------------------------------------------------
    lines += ['## Topics', '', '| topic | type | messages | rate [Hz] | sequence gaps |',
              '|---|---|---|---|---|']
    for name, topic in sorted(data.items()):
        t = _times(topic, origin)
        rate = (len(topic) - 1) / (t[-1] - t[0]) if len(topic) > 1 and t[-1] > t[0] else 0.0
        gaps = ''
        if 'sequence' in topic.fields:
            n_gaps, lost = sequence_gaps(topic['sequence'])
            gaps = f'{n_gaps} ({lost} lost)'
        lines.append(f'| `{name}` | {topic.msgtype} | {len(topic)} | {rate:.1f} | {gaps} |')
    lines.append('')

    # --- position steps ---------------------------------------------------------------
    joints = data.get('/' + TOPIC_JOINT_STATES)
    setp = data.get('/' + TOPIC_POSITION_SETPOINT)
    plots: list[tuple[str, list[tuple]]] = []
    steps: list[StepResult] = []
    if joints is not None and len(joints):
        tj = _times(joints, origin)
        pos = np.array([p[0] for p in joints['position']], dtype=float)
        pos_lines = [(*_with_gaps(tj, pos * 1e3), 'position', '-')]
        if setp is not None and len(setp):
            tsp = sim_map(setp) if sim_map is not None else _times(setp, origin)
            sp = setp['data'].astype(float)
            pos_lines.append((tsp, sp * 1e3, 'setpoint', '--'))
            steps = step_results(tsp, sp, tj, pos)
            lines += ['## Position steps', '',
                      '| at [s] | setpoint [mm] | final [mm] | overshoot [mm] | '
                      'settling (+-1 mm) [s] | steady error [mm] |',
                      '|---|---|---|---|---|---|']
            for s in steps:
                settle = f'{s.settling_time_s:.2f}' if s.settled \
                    else 'not settled (left the band before the end of the step)'
                lines.append(f'| {s.start_s:.2f} | {s.setpoint_m * 1e3:.1f} | '
                             f'{s.final_m * 1e3:.2f} | {s.overshoot_m * 1e3:.2f} | {settle} | '
                             f'{s.steady_error_m * 1e3:+.2f} |')
            lines.append('')
        plots.append(('position [mm]', pos_lines))
    pressure = data.get(vtopic(TOPIC_OUTPUT_PRESSURE))
    if pressure is not None and len(pressure):
        plots.append(('chamber pressure\n[bar gauge]', [
            (_times(pressure, origin),
             (pressure['fluid_pressure'] - ATMOSPHERIC_PRESSURE_PA) / 1e5, 'chamber', '-')]))
    flow_lines = []
    flow_cmd = data.get(vtopic(TOPIC_FLOW_COMMAND))
    if flow_cmd is not None and len(flow_cmd):
        flow_lines.append((_times(flow_cmd, origin), flow_cmd['mass_flow'] * 1e3,
                           'commanded', '-'))
    seq = state['sequence'] if 'sequence' in state.fields else None
    flow_lines.append((*_with_gaps(ts, _period_mean(ts, state['mass_flow'], 0.02) * 1e3, seq),
                       'achieved (valve/state, 20 ms mean)', '-'))
    plots.append(('mass flow [g/s]', flow_lines))
    duty_lines = [(*_with_gaps(ts, state['duty'] * 100.0, seq), 'in force (valve/state)',
                   '-')]
    duty_cmd = data.get(vtopic(TOPIC_DUTY_COMMAND))
    if duty_cmd is not None and len(duty_cmd):
        duty_lines.insert(0, (_times(duty_cmd, origin), duty_cmd['duty'] * 100.0,
                              'commanded', '.'))
    plots.append(('duty [%]', duty_lines))
    t_cur, y_cur, label_cur, style_cur = _current_line(ts, state)
    plots.append(('coil current [A]', [(*_with_gaps(t_cur, y_cur, seq), label_cur,
                                        style_cur)]))

    # A close-up of three PWM periods of current, position and voltage, at the busiest
    # time; the overview marks where it is.
    mid = int(np.argmax(state['duty'] * (state['duty'] < 1.0))) if len(state) else 0
    sel = (ts >= ts[mid]) & (ts < ts[mid] + 0.06)
    overview = out / 'overview.png'
    _plot(overview, 0.0, plots, title,
          span=(float(ts[mid]), float(ts[mid]) + 0.06,
                f'close-up at {ts[mid]:.2f} s (closeup.png)'))
    closeup = out / 'closeup.png'
    _plot(closeup, float(ts[mid]), [
        ('voltage [V]', [(*_with_gaps(ts[sel], state['coil_voltage'][sel]), 'voltage', '-')]),
        ('current [A]', [(*_with_gaps(ts[sel], state['coil_current'][sel]),
                          'current (instantaneous samples)', '-')]),
        ('spool position\n[mm]', [(*_with_gaps(ts[sel], state['spool_position'][sel] * 1e3),
                                   'x', '-'),
                                  (*_with_gaps(ts[sel], state['spool_position_avg'][sel] * 1e3),
                                   'x averaged over the PWM period', '--')]),
    ], f'valve close-up: 60 ms from t = {ts[mid]:.2f} s (shaded in the overview)')
    lines += ['## Plots', '', f'![overview]({overview.name})', '',
              f'![close-up]({closeup.name})', '']
    lines += ['## Valve', '',
              f'- state messages: {len(state)}, backend: '
              f'{"CAN driver" if int(state["source"][0]) == 1 else "simulator"}',
              f'- mean duty {np.mean(state["duty"]) * 100:.1f} %, peak current '
              f'{np.max(state["coil_current"]):.3f} A, mean flow '
              f'{np.mean(state["mass_flow"]) * 1e3:.3f} g/s', '']
    report = out / 'report.md'
    report.write_text('\n'.join(lines) + '\n')
    n_gaps, n_lost = sequence_gaps(seq) if seq is not None else (0, 0)
    summary.update(
        steps=[s.to_json() for s in steps],
        all_settled=bool(steps) and all(s.settled for s in steps),
        valve_state={'messages': int(len(state)),
                     'rate_hz': float((len(state) - 1) / (ts[-1] - ts[0]))
                     if len(state) > 1 and ts[-1] > ts[0] else 0.0,
                     'sequence_gaps': int(n_gaps), 'lost': int(n_lost)})
    import json
    (out / 'report.json').write_text(json.dumps(summary, indent=2, default=str) + '\n')
    return report


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``valve_report``."""
    parser = argparse.ArgumentParser(prog='valve_report', description=__doc__.split('\n')[0])
    parser.add_argument('bag', type=Path, help='bag directory recorded from the suite')
    parser.add_argument('-o', '--out', type=Path, default=None,
                        help='output directory (default: BAG_report)')
    parser.add_argument('--title', default='valve suite run')
    args = parser.parse_args(argv)
    out = args.out or args.bag.with_name(args.bag.name + '_report')
    # The reader's warnings (a killed or damaged bag read as far as it goes) are held back:
    # printed after a written report, dropped when the bag is refused (one line then).
    held = _HeldWarnings()
    recording_log = logging.getLogger('valve_model_pkg.recording')
    recording_log.addHandler(held)
    propagate, recording_log.propagate = recording_log.propagate, False
    try:
        report = write_report(args.bag, out, args.title)
    except (RecordingError, ValueError) as err:  # the bag: refused input
        print(f'valve_report: error: {_one_line(err)}', file=sys.stderr)
        return 2
    except OSError as err:  # writing the report
        print(f'valve_report: error: {_one_line(err)}', file=sys.stderr)
        return 1
    finally:
        recording_log.removeHandler(held)
        recording_log.propagate = propagate
    for message in held.messages:
        print(f'valve_report: warning: {message}', file=sys.stderr)
    print(f'valve_report: wrote {report}')
    return 0


class _HeldWarnings(logging.Handler):
    """Keeps the warnings of the bag reader until the outcome is known."""

    def __init__(self) -> None:
        super().__init__(logging.WARNING)
        self.messages: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.messages.append(_one_line(record.getMessage()))


def _one_line(text: object) -> str:
    return ' '.join(str(text).split())


if __name__ == '__main__':
    sys.exit(main())
