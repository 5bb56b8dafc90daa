"""What the simulator nodes report on ``/diagnostics`` for one simulated valve.

``valve_simulator`` and ``valve_bank_simulator`` publish the same status per valve: the
real-time loop's statistics (:class:`~valve_model_pkg.nodes.tick_loop.TickLoop`), the
commands received and rejected, and the model's state; the level is WARN while the loop
fell behind, commands were lost or messages were rejected since the node started.
"""
from __future__ import annotations

from diagnostic_msgs.msg import KeyValue

from valve_model_pkg.model import ValveSample
from valve_model_pkg.model.aot import backend as kernel_backend
from valve_model_pkg.nodes.common import DiagnosticLevel, key_values
from valve_model_pkg.nodes.inputs import InputGuard, SequenceTracker
from valve_model_pkg.nodes.tick_loop import TickLoop

__all__ = ['valve_summary', 'valve_values']


def valve_summary(loop: TickLoop, commands: SequenceTracker,
                  inputs: InputGuard) -> tuple[int, str]:
    """Level and one-line message of a valve's periodic status."""
    problems = []
    if loop.behind_ticks:
        problems.append(f'{loop.behind_ticks} tick(s) fell behind; last: '
                        f'{loop.last_behind_reason}')
    if commands.lost:
        problems.append(f'{commands.lost} duty command(s) lost (sequence gaps)')
    if inputs.total:
        problems.append(f'{inputs.total} message(s) rejected; last: {inputs.last_reason}')
    if problems:
        return DiagnosticLevel.WARN, '; '.join(problems)
    return DiagnosticLevel.OK, 'running in real time'


def valve_values(loop: TickLoop, sample: ValveSample, *, rate_hz: float, sequence: int,
                 commands: SequenceTracker, inputs: InputGuard, params_file: str,
                 **extra: object) -> list[KeyValue]:
    """The key/value pairs of a valve's status (``extra`` appended as given)."""
    return key_values(
        ticks=loop.ticks, ticks_behind=loop.behind_ticks, late_samples=loop.late_samples,
        skipped_model_time_s=loop.skipped_model_s, achieved_rate_hz=loop.achieved_rate_hz,
        target_rate_hz=rate_hz, samples_published=sequence,
        max_tick_compute_s=loop.max_tick_compute_s, rejected_commands=inputs.total,
        last_rejection=inputs.last_reason, **commands.diagnostic_values('duty_commands'),
        duty_commands_rejected=inputs.count('duty_command'), **inputs.diagnostic_values(),
        model_time_s=sample.t_s, duty=sample.duty, pwm_frequency_hz=sample.pwm_frequency_hz,
        supply_pressure_pa=sample.supply_pressure_pa, params_file=params_file,
        kernel=kernel_backend().name, **extra)
