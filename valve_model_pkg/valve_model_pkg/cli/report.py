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
from valve_model_pkg.recording.errors import RecordingError

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


def _times(topic, origin_ns: int) -> np.ndarray:
    ns = topic.stamp_ns if topic.stamp_ns is not None else topic.log_time_ns
    return (ns - origin_ns) * 1e-9


def step_results(t_set: np.ndarray, setpoint: np.ndarray, t_pos: np.ndarray,
                 position: np.ndarray, band_m: float = 1e-3) -> list[StepResult]:
    """Split the run at setpoint changes and characterise each step.

    Settling time: from the step to the first instant after which the position stays
    within ``band_m`` of the setpoint until the next step. Steady-state error: mean error
    over the last 10 % of the step.
    """
    if setpoint.size == 0 or position.size == 0:
        return []
    change = np.flatnonzero(np.abs(np.diff(setpoint)) > 1e-9) + 1
    starts = np.concatenate([[0], change])
    results = []
    for k, i0 in enumerate(starts):
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
        if outside.size == 0:
            settle = 0.0
        elif outside[-1] + 1 < tt.size:
            settle = float(tt[outside[-1] + 1] - t0)
        else:
            settle = None
        tail = tt >= t1 - 0.1 * (t1 - t0)
        results.append(StepResult(float(t0), sp, float(yy[-1]), overshoot, settle,
                                  float(np.mean(err[tail]))))
    return results


def _plot(path: Path, t0_s: float, series: list[tuple[str, list[tuple]]],
          title: str) -> None:
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(len(series), 1, figsize=(11, 2.3 * len(series)), sharex=True)
    axes = np.atleast_1d(axes)
    for ax, (ylabel, lines) in zip(axes, series):
        for t, y, label, style in lines:
            ax.plot(t - t0_s, y, style, label=label, linewidth=1.0)
        ax.set_ylabel(ylabel)
        ax.grid(True, alpha=0.3)
        if len(lines) > 1:
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


def write_report(bag: Path, out: Path, title: str = 'valve suite run') -> Path:
    """Write ``out/report.md`` and its plots from ``bag``; returns the report path."""
    data = load_bag(bag)
    out.mkdir(parents=True, exist_ok=True)
    state = data.get('/' + TOPIC_STATE)
    if state is None or len(state) == 0:
        raise ValueError(f'{bag}: no /{TOPIC_STATE} messages; is it a bag of the suite?')
    origin = int(state.stamp_ns[0])
    ts = _times(state, origin)
    lines = [f'# {title}', '', f'Bag: `{bag}`', '']

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
    if joints is not None and len(joints):
        tj = _times(joints, origin)
        pos = np.array([p[0] for p in joints['position']], dtype=float)
        pos_lines = [(tj, pos * 1e3, 'position', '-')]
        if setp is not None and len(setp):
            tsp = _times(setp, origin)
            sp = setp['data'].astype(float)
            pos_lines.append((tsp, sp * 1e3, 'setpoint', '--'))
            steps = step_results(tsp, sp, tj, pos)
            lines += ['## Position steps', '',
                      '| at [s] | setpoint [mm] | final [mm] | overshoot [mm] | '
                      'settling (+-1 mm) [s] | steady error [mm] |',
                      '|---|---|---|---|---|---|']
            for s in steps:
                settle = f'{s.settling_time_s:.2f}' if s.settling_time_s is not None \
                    else 'not settled'
                lines.append(f'| {s.start_s:.2f} | {s.setpoint_m * 1e3:.1f} | '
                             f'{s.final_m * 1e3:.2f} | {s.overshoot_m * 1e3:.2f} | {settle} | '
                             f'{s.steady_error_m * 1e3:+.2f} |')
            lines.append('')
        plots.append(('position [mm]', pos_lines))
    pressure = data.get('/' + TOPIC_OUTPUT_PRESSURE)
    if pressure is not None and len(pressure):
        plots.append(('chamber pressure\n[bar gauge]', [
            (_times(pressure, origin),
             (pressure['fluid_pressure'] - ATMOSPHERIC_PRESSURE_PA) / 1e5, 'chamber', '-')]))
    flow_lines = []
    flow_cmd = data.get('/' + TOPIC_FLOW_COMMAND)
    if flow_cmd is not None and len(flow_cmd):
        flow_lines.append((_times(flow_cmd, origin), flow_cmd['mass_flow'] * 1e3,
                           'commanded', '-'))
    flow_lines.append((ts, _period_mean(ts, state['mass_flow'], 0.02) * 1e3,
                       'achieved (valve/state, 20 ms mean)', '-'))
    plots.append(('mass flow [g/s]', flow_lines))
    duty_lines = [(ts, state['duty'] * 100.0, 'in force (valve/state)', '-')]
    duty_cmd = data.get('/' + TOPIC_DUTY_COMMAND)
    if duty_cmd is not None and len(duty_cmd):
        duty_lines.insert(0, (_times(duty_cmd, origin), duty_cmd['duty'] * 100.0,
                              'commanded', '.'))
    plots.append(('duty [%]', duty_lines))
    plots.append(('coil current [A]', [(ts, state['coil_current'], 'current', '-')]))
    overview = out / 'overview.png'
    _plot(overview, 0.0, plots, title)

    # A close-up of two PWM periods of current, position and voltage, at the busiest time.
    mid = int(np.argmax(state['duty'] * (state['duty'] < 1.0))) if len(state) else 0
    sel = (ts >= ts[mid]) & (ts < ts[mid] + 0.06)
    closeup = out / 'closeup.png'
    _plot(closeup, float(ts[mid]), [
        ('voltage [V]', [(ts[sel], state['coil_voltage'][sel], 'voltage', '-')]),
        ('current [A]', [(ts[sel], state['coil_current'][sel], 'current', '-')]),
        ('spool position\n[mm]', [(ts[sel], state['spool_position'][sel] * 1e3, 'x', '-'),
                                  (ts[sel], state['spool_position_avg'][sel] * 1e3,
                                   'x averaged over the PWM period', '--')]),
    ], 'valve close-up (60 ms)')
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
