"""A user's own topics as a measurement: ``ROLE=TOPIC[.FIELD]`` (or ``ROLE=VALUE``).

A bag from ``ros2 bag record`` in which the user's firmware publishes the coil current on
a topic of its own is read by naming, for each role, the topic and field that carry it
(:func:`parse_topic_map`): ``current=/coil/current`` (a ``std_msgs/msg/Float64``'s
``data``), ``duty=/valve/duty_command.duty``, ``current=/drive/telemetry.coil.current``
(nested fields with dots). The roles (:data:`ROLES`) make one of two records:

* a **step** record: ``voltage`` and ``current``: the bare coil driven by the voltage;
* an **operation** record: ``duty``, ``pwm_frequency`` and ``current`` (instantaneous) or
  ``current_mean`` (interval means since the previous message): the drive electronics run
  from the commands in force; the drive supply is ``supply_voltage``, else the largest
  interval-mean coil voltage (``coil_voltage_mean``: the boost applies the supply), else
  the suite's 24 V. A mapped ``coil_voltage_mean`` is also carried into the measurement,
  so the valve is fitted around the electronics (:mod:`.mean_voltage`).

``supply_pressure`` and ``output_pressure`` (gauge, Pa) come from a topic or a number;
``pwm_frequency`` and ``supply_voltage`` may be numbers too. The current's messages are
the samples: every other role is taken as in force at each of them (its latest message at
or before), and the record starts when every role has a value. Each topic is timed by its
header stamps where its type has a header, else by the receive times; the notes say which.
"""
from __future__ import annotations

import logging
import math
from collections.abc import Iterable, Mapping
from pathlib import Path

import numpy as np

from ..errors import MeasurementFormatError, RecordingError
from ..recording import FieldRecord, FieldSeries, FieldSpec, read_fields
from .measurement import (MIN_SAMPLES, Measurement, check_excitation, check_time_axis,
                          mean_voltage_column, median_pressure, refused_bag)
from .pwm_grid import operation_measurement

__all__ = ['CONSTANT_ROLES', 'DEFAULT_SUPPLY_V', 'FieldSpecOrValue', 'ROLES',
           'parse_topic_map', 'read_mapped_bag']

_LOG = logging.getLogger(__name__)

#: A role's target: a topic field, or a number for :data:`CONSTANT_ROLES`.
FieldSpecOrValue = FieldSpec | float

#: The roles a mapping names, and what each carries (SI units).
ROLES: dict[str, str] = {
    'current': 'coil current, instantaneous [A]',
    'current_mean': 'coil current, mean since the previous message [A]',
    'voltage': 'coil voltage [V]',
    'duty': 'main PWM duty in force [1]',
    'pwm_frequency': 'main PWM frequency in force [Hz]',
    'coil_voltage_mean': 'coil voltage, mean since the previous message [V]',
    'supply_voltage': 'drive supply voltage [V]',
    'supply_pressure': 'supply pressure, gauge [Pa]',
    'output_pressure': 'output pressure, gauge [Pa]',
}
#: Roles that may be given as a number instead of a topic.
CONSTANT_ROLES = ('pwm_frequency', 'supply_voltage', 'supply_pressure', 'output_pressure')
#: Drive supply voltage assumed when the mapping gives neither it nor the mean coil
#: voltage [V] (the suite's).
DEFAULT_SUPPLY_V = 24.0
#: Below this rate a record is coarse for identification (the stroke lasts under 1 ms)
#: [Hz].
_COARSE_RATE_HZ = 10e3


def _entry(text: str) -> tuple[str, FieldSpecOrValue]:
    role, eq, target = text.partition('=')
    role, target = role.strip(), target.strip()
    if not eq or not role or not target:
        raise ValueError(f'{text!r} is not ROLE=TOPIC[.FIELD]; roles: {", ".join(ROLES)}')
    if role not in ROLES:
        raise ValueError(f'{text!r}: unknown role {role!r}; roles: {", ".join(ROLES)}')
    try:
        value = float(target)
    except ValueError:
        return role, FieldSpec.parse(target)
    if role not in CONSTANT_ROLES or not math.isfinite(value):
        raise ValueError(f'{text!r}: {role} must be a topic (ROLE=TOPIC[.FIELD]); only '
                         f'{", ".join(CONSTANT_ROLES)} may be finite numbers')
    return role, value


def parse_topic_map(entries: Iterable[str]) -> dict[str, FieldSpecOrValue]:
    """Parse ``ROLE=TOPIC[.FIELD]`` (or ``ROLE=NUMBER``) entries.

    Parameters
    ----------
    entries : iterable of str
        ``current=/coil/current``, ``duty=/valve/duty_command.duty``,
        ``supply_pressure=400000``.

    Returns
    -------
    dict of str to FieldSpec or float
        By role.

    Raises
    ------
    ValueError
        An entry of another form, an unknown role, a role given twice, or a number for a
        role that must be a topic (the message repeats the entry).
    """
    out: dict[str, FieldSpecOrValue] = {}
    for text in entries:
        role, target = _entry(text)
        if role in out:
            raise ValueError(f'{text!r}: role {role!r} is given twice')
        out[role] = target
    return out


def _roles_of(spath: str, mapping: Mapping[str, FieldSpecOrValue]) -> tuple[str, str]:
    """(``step`` or ``operation``, the current's role) the mapping makes."""
    currents = [r for r in ('current', 'current_mean') if r in mapping]
    if len(currents) != 1:
        raise MeasurementFormatError(spath, None, 'the mapping needs exactly one of current '
                                     f'(instantaneous) and current_mean; it has {currents}')
    if 'duty' in mapping:
        if 'pwm_frequency' not in mapping:
            raise MeasurementFormatError(spath, None, 'the mapping gives duty but no '
                                         'pwm_frequency (a topic or a number in Hz)')
        return 'operation', currents[0]
    if 'voltage' in mapping:
        return 'step', currents[0]
    raise MeasurementFormatError(spath, None, 'the mapping needs voltage (a step record) or '
                                 'duty and pwm_frequency (an operation record)')


def _on_base(base: FieldSeries, other: FieldSeries) -> np.ndarray:
    """``other``'s value in force at each message of ``base`` (its latest at or before;
    ``nan`` before its first), shape (n,)."""
    if other.spec.topic == base.spec.topic:
        return other.values
    order = np.argsort(other.time_ns, kind='stable')
    times, values = other.time_ns[order], other.values[order]
    k = np.searchsorted(times, base.time_ns, side='right') - 1
    return np.where(k >= 0, values[np.clip(k, 0, None)], np.nan)


def _columns(spath: str, record: FieldRecord, current_role: str,
             mapping: Mapping[str, FieldSpecOrValue], notes: list[str]
             ) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Time axis [s] and every role's values on the current's samples, from the first
    sample at which every role has a value."""
    base = record.series[current_role]
    cols = {role: _on_base(base, s) for role, s in record.series.items()}
    for role, value in mapping.items():
        if not isinstance(value, FieldSpec):
            cols[role] = np.full(len(base), float(value))
    late = [role for role, s in record.series.items() if s.time_ns.min() > base.time_ns[0]
            and s.spec.topic != base.spec.topic]
    start = 0
    if late:
        first = max(record.series[r].time_ns.min() for r in late)
        start = int(np.searchsorted(base.time_ns, first, side='left'))
        notes.append(f'the record starts at the first {current_role} sample after the first '
                     f'message of {", ".join(late)} ({start} earlier samples left out)')
    if len(base) - start < MIN_SAMPLES:
        raise MeasurementFormatError(
            spath, None, f'{base.spec} has {len(base) - start} messages where every mapped '
            f'topic has a value; at least {MIN_SAMPLES} are needed')
    t = (base.time_ns[start:] - base.time_ns[start]) * 1e-9
    try:
        check_time_axis(spath, t, None)
    except MeasurementFormatError as err:
        raise MeasurementFormatError(spath, None, f'{current_role} on {base.spec} (timed by '
                                     f'its {base.time_source}): {err.reason}') from err
    return t, {role: v[start:] for role, v in cols.items()}


def _finite(spath: str, role: str, where: str, values: np.ndarray) -> None:
    bad = np.flatnonzero(~np.isfinite(values))
    if bad.size:
        raise MeasurementFormatError(spath, None, f'{role} from {where} is {values[bad[0]]!r} '
                                     f'at sample {int(bad[0])}; expected a finite number')


def _pressures(spath: str, cols: dict[str, np.ndarray], notes: list[str]
               ) -> tuple[float, float]:
    if 'supply_pressure' not in cols:
        raise MeasurementFormatError(spath, None, 'the mapping gives no supply_pressure: map '
                                     'supply_pressure=TOPIC[.FIELD] or supply_pressure=PA '
                                     '(gauge, Pa)')
    supply = median_pressure(cols['supply_pressure'], 'supply_pressure', None, notes)
    if supply is None:
        raise MeasurementFormatError(spath, None, 'supply_pressure has no finite value')
    output = median_pressure(cols.get('output_pressure'), 'output_pressure', 0.0, notes)
    return supply, output


def _rate_note(t: np.ndarray, notes: list[str]) -> float:
    rate = 1.0 / float(np.median(np.diff(t)))
    if rate < _COARSE_RATE_HZ:
        notes.append(f'samples at {rate:.0f} Hz are coarse for identification (the stroke '
                     'lasts under 1 ms); fitted on what there is')
    return rate


def _step(spath: str, t: np.ndarray, cols: dict[str, np.ndarray], current_role: str,
          mapping: Mapping[str, FieldSpecOrValue], notes: list[str]) -> Measurement:
    """The bare coil driven by the mapped voltage."""
    voltage, current = cols['voltage'], cols[current_role]
    _finite(spath, 'voltage', str(mapping['voltage']), voltage)
    check_excitation(spath, voltage, None)
    n_missing = int(np.count_nonzero(~np.isfinite(current)))
    if n_missing:
        notes.append(f'{n_missing} samples with a non-finite {current_role}; kept, excluded')
    supply, output = _pressures(spath, cols, notes)
    rate = _rate_note(t, notes)
    on = voltage > 0.5 * float(np.max(voltage))
    pulses = int(np.count_nonzero(on[1:] & ~on[:-1]) + (1 if on[0] else 0))
    experiment = 'pwm' if pulses > 4 else 'step'
    notes.append(f'{experiment} record: the bare coil model is driven by the mapped voltage '
                 f'(held between samples) and compared with the {current_role}')
    metadata = {'experiment': experiment, 'supply_pressure_pa': f'{supply:g}',
                'output_pressure_pa': f'{output:g}', 'sample_rate_hz': f'{rate:g}',
                **{f'{role}_source': str(v) for role, v in mapping.items()}}
    for note in notes:
        _LOG.info('%s: %s', spath, note)
    return Measurement(
        source=spath, t_s=t, voltage_v=voltage.copy(), current_a=current.copy(),
        supply_pressure_pa=supply, output_pressure_pa=output, experiment=experiment,
        metadata=metadata, notes=tuple(notes), n_missing_values=n_missing,
        sampling='interval_mean' if current_role == 'current_mean' else 'instant')


def _supply_voltage(cols: dict[str, np.ndarray], notes: list[str]) -> float:
    if 'supply_voltage' in cols:
        ok = cols['supply_voltage'][np.isfinite(cols['supply_voltage'])]
        if ok.size:
            return float(np.median(ok))
    mean_v = cols.get('coil_voltage_mean')
    if mean_v is not None and np.any(np.isfinite(mean_v) & (mean_v > 0.0)):
        supply_v = float(np.nanmax(mean_v))
        notes.append(f'drive supply voltage {supply_v:.3g} V: the largest interval-mean coil '
                     'voltage (an interval within the boost, which applies the supply)')
        return supply_v
    notes.append(f'the mapping gives neither supply_voltage nor coil_voltage_mean: '
                 f'{DEFAULT_SUPPLY_V:g} V (the suite\'s drive supply) is assumed')
    return DEFAULT_SUPPLY_V


def _operation(spath: str, t: np.ndarray, cols: dict[str, np.ndarray], current_role: str,
               mapping: Mapping[str, FieldSpecOrValue], notes: list[str]) -> Measurement:
    """The drive electronics run from the mapped duty and frequency in force."""
    supply, output = _pressures(spath, cols, notes)
    supply_v = _supply_voltage(cols, notes)
    how = ('interval means' if current_role == 'current_mean'
           else 'instantaneous samples')
    v_mean = mean_voltage_column(cols.get('coil_voltage_mean'),
                                 f'coil_voltage_mean ({mapping.get("coil_voltage_mean")})',
                                 notes) if 'coil_voltage_mean' in cols else None
    return operation_measurement(
        spath, t, cols['duty'].copy(), cols['pwm_frequency'].copy(),
        cols[current_role].copy(), supply_v=supply_v, supply_pa=supply, output_pa=output,
        notes=notes, n_gaps=0, interval_means=current_role == 'current_mean',
        described=f'from the mapped topics: the model runs the drive electronics from duty '
        f'({mapping["duty"]}) and pwm_frequency ({mapping["pwm_frequency"]}) and is compared '
        f'with {current_role} ({mapping[current_role]}, {how})',
        metadata={'experiment': 'operation',
                  **{f'{role}_source': str(v) for role, v in mapping.items()}},
        coil_voltage_mean=v_mean)


def read_mapped_bag(path: str | Path, mapping: Mapping[str, FieldSpecOrValue]) -> Measurement:
    """A measurement from a user's own topics, named by role.

    Parameters
    ----------
    path : str or pathlib.Path
        Any bag :func:`valve_model_pkg.recording.load_bag` reads.
    mapping : mapping of str to FieldSpec or float
        By role (:data:`ROLES`, :func:`parse_topic_map`): ``voltage`` and ``current`` (or
        ``current_mean``) make a step record; ``duty``, ``pwm_frequency`` and ``current``
        (or ``current_mean``) an operation record; ``supply_pressure`` is required.

    Returns
    -------
    Measurement
        Time from the current's first usable message [s]; the notes say how each topic
        is timed (header stamps or receive times) and what was assumed.

    Raises
    ------
    MeasurementFormatError
        The bag cannot be read; a topic is missing or empty, a field missing or not a
        number, a value not finite; the roles do not make a record (one line naming the
        bag, the topic and field, and what was expected).
    """
    spath = str(path)
    kind, current_role = _roles_of(spath, mapping)
    specs = {role: v for role, v in mapping.items() if isinstance(v, FieldSpec)}
    if not Path(path).exists():
        raise MeasurementFormatError(spath, None, 'cannot be opened as a rosbag2 bag: it '
                                     'does not exist')
    try:
        record = read_fields(path, specs)
    except RecordingError as err:
        raise refused_bag(spath, err) from err
    notes = list(record.notes)
    t, cols = _columns(spath, record, current_role, mapping, notes)
    for role in ('duty', 'pwm_frequency'):
        if role in cols:
            _finite(spath, role, str(mapping[role]), cols[role])
    build = _operation if kind == 'operation' else _step
    return build(spath, t, cols, current_role, mapping, notes)
