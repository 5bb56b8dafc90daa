"""rosbag2 bags read for identification: the suite's valve state, or a user's own topics.

Bags are opened by :mod:`valve_model_pkg.recording` (any storage, split, compressed, with
or without ``metadata.yaml``); this module turns what it reads into a
:class:`~.measurement.Measurement`:

* the suite's ``valve_msgs/msg/ValveState`` on ``/valve/state`` (:func:`read_bag`,
  :func:`measurement_from_state`): a bag of the suite running PWM is an ``operation``
  record compared as interval means (``coil_current_mean``); one of steps on the bare
  coil a ``step`` or ``pwm`` record driven by ``coil_voltage``;
* a user's own topics, named by a mapping ``ROLE=TOPIC[.FIELD]`` (:mod:`.topic_map`).

Malformed input is refused with a :class:`~valve_model_pkg.errors.MeasurementFormatError`
naming the bag, the topic or message and the reason.
"""
from __future__ import annotations

import logging
from collections.abc import Mapping
from dataclasses import dataclass, fields, replace
from pathlib import Path

import numpy as np

from valve_model_pkg.interface import STATE_SOURCE_SIMULATOR, TOPIC_STATE

from ..errors import MeasurementFormatError, RecordingError
from ..recording import TopicData, load_bag_contents
from .measurement import (MIN_SAMPLES, Measurement, check_excitation, check_time_axis,
                          mean_voltage_column, median_pressure, refused_bag)
from .pwm_grid import operation_measurement
from .topic_map import FieldSpecOrValue, read_mapped_bag

__all__ = ['DEFAULT_BAG_SUPPLY_V', 'MEAN_CURRENT_FIELD', 'StateColumns', 'VALVE_STATE_TYPE',
           'measurement_from_state', 'read_bag']

_LOG = logging.getLogger(__name__)

#: The message type the suite records its valve state with.
VALVE_STATE_TYPE = 'valve_msgs/msg/ValveState'
#: ValveState field with the mean coil current since the previous message [A].
MEAN_CURRENT_FIELD = 'coil_current_mean'
#: ValveState field with the mean coil voltage since the previous message [V] (NaN when
#: the source does not measure it).
MEAN_VOLTAGE_FIELD = 'coil_voltage_mean'
#: Drive supply voltage assumed for a suite bag, which does not carry it [V].
DEFAULT_BAG_SUPPLY_V = 24.0
#: A state stream slower than this is coarse for identification (the stroke lasts under
#: 1 ms) [Hz].
_COARSE_RATE_HZ = 10e3


@dataclass(frozen=True)
class StateColumns:
    """The ``ValveState`` fields identification uses, one array per field, shape (n,).

    Attributes
    ----------
    frame_id : numpy.ndarray of str
        ``header.frame_id``: the valve.
    stamp_s, log_time_s : numpy.ndarray
        ``header.stamp`` and the bag's receive time [s since the epoch].
    sequence : numpy.ndarray
        The publisher's message counter (float64).
    coil_voltage_v, coil_current_a, spool_position_m : numpy.ndarray
        Instantaneous coil voltage [V], coil current [A], spool position [m].
    position_measured : numpy.ndarray of bool
        Whether ``spool_position`` is measured (else modelled).
    supply_pressure_pa, output_pressure_pa : numpy.ndarray
        Gauge pressures [Pa].
    pwm_frequency_hz, duty : numpy.ndarray
        Main PWM command in force: frequency [Hz] and duty [1].
    coil_current_mean_a : numpy.ndarray or None
        Mean coil current since the previous message [A]; ``None`` when the recorded
        definition of ``ValveState`` has no such field.
    coil_voltage_mean_v : numpy.ndarray or None
        Mean coil voltage since the previous message [V] (NaN where the source gives
        none); ``None`` when the recorded definition has no such field.
    source : numpy.ndarray or None
        ``source``: the backend that made each state (``None`` without the field).
    """

    frame_id: np.ndarray
    stamp_s: np.ndarray
    log_time_s: np.ndarray
    sequence: np.ndarray
    coil_voltage_v: np.ndarray
    coil_current_a: np.ndarray
    spool_position_m: np.ndarray
    position_measured: np.ndarray
    supply_pressure_pa: np.ndarray
    output_pressure_pa: np.ndarray
    pwm_frequency_hz: np.ndarray
    duty: np.ndarray
    coil_current_mean_a: np.ndarray | None = None
    coil_voltage_mean_v: np.ndarray | None = None
    source: np.ndarray | None = None

    def __len__(self) -> int:
        return int(self.stamp_s.size)

    @classmethod
    def from_topic(cls, data: TopicData) -> 'StateColumns':
        """The columns of a ``ValveState`` topic as :func:`~valve_model_pkg.recording.
        load_bag` reads it."""
        f = data.fields

        def num(name: str) -> np.ndarray:
            return np.asarray(f[name], dtype=float)

        return cls(
            frame_id=np.asarray(f['header.frame_id'], dtype=str),
            stamp_s=num('header.stamp.sec') + 1e-9 * num('header.stamp.nanosec'),
            log_time_s=data.log_time_ns * 1e-9, sequence=num('sequence'),
            coil_voltage_v=num('coil_voltage'), coil_current_a=num('coil_current'),
            spool_position_m=num('spool_position'),
            position_measured=np.asarray(f['position_measured'], dtype=bool),
            supply_pressure_pa=num('supply_pressure'),
            output_pressure_pa=num('output_pressure'), pwm_frequency_hz=num('pwm_frequency'),
            duty=num('duty'),
            coil_current_mean_a=num(MEAN_CURRENT_FIELD) if MEAN_CURRENT_FIELD in f else None,
            coil_voltage_mean_v=num(MEAN_VOLTAGE_FIELD) if MEAN_VOLTAGE_FIELD in f else None,
            source=num('source') if 'source' in f else None)

    def select(self, keep: np.ndarray) -> 'StateColumns':
        """The messages where ``keep`` (bool, shape (n,)) is true."""
        return StateColumns(**{fl.name: None if getattr(self, fl.name) is None
                               else getattr(self, fl.name)[keep] for fl in fields(self)})


def read_bag(path: str | Path, *, topic: str = '/' + TOPIC_STATE, valve: str | None = None,
             mapping: Mapping[str, FieldSpecOrValue] | None = None) -> Measurement:
    """Read a rosbag2 bag for identification.

    Parameters
    ----------
    path : str or pathlib.Path
        Bag directory (any bag :func:`valve_model_pkg.recording.load_bag` reads: MCAP or
        sqlite3, split, zstd-compressed, with or without ``metadata.yaml``) or one storage
        file of it.
    topic : str
        Topic of the suite's ``valve_msgs/msg/ValveState`` messages.
    valve : str, optional
        ``header.frame_id`` of the valve to take when the topic carries several valves.
    mapping : mapping of str to FieldSpec or float, optional
        A user's own topics by role (:func:`~.topic_map.parse_topic_map`); when given,
        ``topic`` and ``valve`` are not used (:func:`~.topic_map.read_mapped_bag`).

    Returns
    -------
    Measurement
        From ValveState: time from ``header.stamp`` relative to the first message (the
        bag's receive time when the stamps are all zero); ``coil_voltage``,
        ``coil_current``; the supply pressure is the median of ``supply_pressure`` over
        the messages; the spool position only if the messages say it is measured
        (``position_measured``).

    Raises
    ------
    MeasurementFormatError
        The bag cannot be read, lacks the topic, mixes valves without ``valve`` given,
        has non-increasing stamps or non-finite voltages.

    Notes
    -----
    The suite publishes its state at about 1 kHz. That is coarse for identification (the
    spool stroke lasts under a millisecond): the fit uses what there is, the model is
    simulated at its own step and sampled at the message times. Messages that carry
    ``coil_voltage_mean`` drive the coil with it (exact over each interval, an edge placed
    within its interval); otherwise the sampled voltage is held between messages, so an
    edge moves to the next message and PWM edges between two messages are lost. Sequence
    gaps are reported as missing samples.
    """
    spath = str(path)
    if mapping:
        return read_mapped_bag(path, mapping)
    if not Path(path).exists():
        raise MeasurementFormatError(spath, None, 'cannot be opened as a rosbag2 bag: it '
                                     'does not exist')
    try:
        contents = load_bag_contents(path, [topic])
    except RecordingError as err:
        raise refused_bag(spath, err) from err
    data = contents.topics.get(topic if topic.startswith('/') else '/' + topic)
    if data is None:
        have = sorted(f'{t} ({m})' for t, m in contents.available.items())
        raise MeasurementFormatError(spath, None, f'has no topic {topic!r}; it has {have}')
    if data.msgtype != VALVE_STATE_TYPE:
        raise MeasurementFormatError(
            spath, None, f'topic {topic!r} carries {data.msgtype}, not {VALVE_STATE_TYPE}')
    m = measurement_from_state(spath, topic, valve, StateColumns.from_topic(data))
    if contents.notes:
        m = replace(m, notes=tuple(contents.notes) + m.notes)
    return m


def _one_valve(spath: str, topic: str, valve: str | None, cols: StateColumns
               ) -> tuple[StateColumns, str]:
    """The messages of one valve, and its name."""
    frames = sorted(set(cols.frame_id.tolist()))
    if valve is not None:
        cols = cols.select(cols.frame_id == valve)
        if not len(cols):
            raise MeasurementFormatError(
                spath, None, f'no message on {topic} has frame_id {valve!r}; found {frames}')
    elif len(frames) > 1:
        raise MeasurementFormatError(
            spath, None, f'{topic} carries several valves {frames}; choose one (valve=...)')
    if len(cols) < MIN_SAMPLES:
        raise MeasurementFormatError(
            spath, None, f'has {len(cols)} messages on {topic}; at least {MIN_SAMPLES} '
            'are needed')
    return cols, frames[0] if valve is None else valve


def _state_time_axis(spath: str, cols: StateColumns, notes: list[str]) -> np.ndarray:
    """Time since the first message [s] from the header stamps (receive times when the
    stamps are all zero), rebuilt from the sequence numbers when stamps repeat."""
    stamps, seq = cols.stamp_s, cols.sequence
    if np.all(stamps == 0.0):
        notes.append('all header stamps are zero; the bag receive times are used')
        stamps = cols.log_time_s
    t = stamps - stamps[0]
    n_back = int(np.count_nonzero(np.diff(t) <= 0.0))
    if n_back and np.all(np.diff(seq) > 0) and t[-1] > t[0]:
        # A driver on simulation time stamps each state on receipt with a /clock that can
        # lag a step behind the telemetry, which comes at one message per step (counted
        # by the sequence numbers). The step is the median over pairs half the record
        # apart: one-sided lags of single stamps, the end ones included, do not bias it
        # (a line through the end stamps or a least-squares line would drift against the
        # model's PWM grid).
        half = seq.size // 2
        step = float(np.median((t[half:] - t[:seq.size - half])
                               / (seq[half:] - seq[:seq.size - half])))
        t = (seq - seq[0]) * step
        notes.append(f'{n_back} header stamps do not increase while the sequence numbers '
                     f'do; the time axis is rebuilt from the sequence numbers at the '
                     f'step {step * 1e3:.6g} ms (median over half-record spans)')
    check_time_axis(spath, t, None)
    return t


#: A sequence gap is filled with its lost messages when the stamps across it advance by
#: this range of the record's step per message (else the publisher restarted or its clock
#: jumped, and the gap is left as it is).
_LOST_STEP_RANGE = (0.5, 1.5)
#: Most lost messages put back per message read (a hostile bag's counter jumps cost no
#: memory).
_MAX_LOST_PER_MESSAGE = 10


def _with_lost_messages(cols: StateColumns, t: np.ndarray, notes: list[str], *,
                        bench: bool = False) -> tuple[StateColumns, np.ndarray]:
    """The messages with each lost one (a gap in the sequence numbers) put back at its
    time as a missing sample: no current (NaN), no spool position, the rest (commands,
    voltages, pressures) held from the message before; on a ``bench`` (an unchopped
    step) the lost mean voltage is the sampled voltage held, the level in force.

    A message's means (``coil_current_mean``, ``coil_voltage_mean``) cover the interval
    since the previous message its publisher sent; read without the lost ones, the record's
    interval would span the whole gap, and through the chopper the mean over the gap is
    not the mean over the last period (tens of mA).
    """
    seq = cols.sequence
    d = np.diff(seq)
    if t.size < 3 or not np.all(np.isfinite(seq)) or not np.any(d > 1) \
            or not np.any(d == 1):
        return cols, t
    step = float(np.median(np.diff(t)[d == 1]))
    with np.errstate(invalid='ignore', divide='ignore'):
        per = np.diff(t) / np.where(d > 0, d, 1.0)
    lo, hi = _LOST_STEP_RANGE
    fill = (d > 1) & (per > lo * step) & (per < hi * step)
    lost = np.where(fill, d - 1, 0).astype(np.int64)
    total = int(lost.sum())
    if total == 0:
        return cols, t
    if total > _MAX_LOST_PER_MESSAGE * t.size:
        notes.append(f'the sequence numbers skip {total} messages, more than '
                     f'{_MAX_LOST_PER_MESSAGE} per message read: not put back')
        return cols, t
    counts = np.ones(t.size, dtype=np.int64)
    counts[:-1] += lost
    src = np.repeat(np.arange(t.size), counts)
    offset = np.arange(src.size) - np.repeat(np.cumsum(counts) - counts, counts)
    per_after = np.append(np.where(fill, per, 0.0), 0.0)
    put = offset > 0
    out = {}
    for fl in fields(cols):
        col = getattr(cols, fl.name)
        out[fl.name] = None if col is None else col[src]
    out['sequence'] = seq[src] + offset
    for name in ('coil_current_a', 'coil_current_mean_a', 'spool_position_m'):
        if out[name] is not None:
            out[name] = out[name].astype(float)
            out[name][put] = np.nan
    if bench and out['coil_voltage_mean_v'] is not None:
        out['coil_voltage_mean_v'] = out['coil_voltage_mean_v'].astype(float)
        out['coil_voltage_mean_v'][put] = out['coil_voltage_v'][put]
    t_new = t[src] + offset * per_after[src]
    notes.append(f'{total} lost messages put back at their times as missing samples (no '
                 'current compared there, the drive held from the message before): each '
                 'mean covers the interval since the message before it was sent')
    return StateColumns(**out), t_new


def _sequence_gaps(seq: np.ndarray, notes: list[str]) -> int:
    """Number of gaps in the sequence numbers (a note says how many messages were lost)."""
    dseq = np.diff(seq)
    lost = int(np.sum(np.clip(dseq - 1, 0, None)))
    n_gaps = int(np.count_nonzero(dseq > 1))
    if lost:
        notes.append(f'{n_gaps} sequence gaps, {lost} messages lost; the model is '
                     'simulated through them')
    return n_gaps


def measurement_from_state(spath: str, topic: str, valve: str | None,
                           cols: StateColumns) -> Measurement:
    """A Measurement from the ``ValveState`` messages of one bag (checks and notes included).

    Parameters
    ----------
    spath : str
        The bag, named in errors and as the source.
    topic : str
        The topic read, for the notes.
    valve : str or None
        ``frame_id`` to keep; ``None`` when the topic carries one valve.
    cols : StateColumns
        The messages in bag order.

    Raises
    ------
    MeasurementFormatError
        Several valves without ``valve``, too few messages, a bad time axis, non-finite
        voltages, no excitation, PWM without the interval-mean current.
    """
    cols, frame = _one_valve(spath, topic, valve, cols)
    notes: list[str] = []
    t = _state_time_axis(spath, cols, notes)
    n_gaps = _sequence_gaps(cols.sequence, notes)
    if np.any(cols.pwm_frequency_hz > 0.0) and np.any(cols.duty > 0.0):
        if not _bench_steps(cols.duty, cols.coil_voltage_v):
            cols, t = _with_lost_messages(cols, t, notes)
            return _state_operation(spath, topic, frame, t, cols, notes, n_gaps)
        notes.append('duty steps between 0 and 1 with an unchopped coil voltage (a bench '
                     'with the drive electronics bypassed): fitted as a bare coil driven by '
                     'coil_voltage')
    bad_v = np.flatnonzero(~np.isfinite(cols.coil_voltage_v))
    if bad_v.size:
        raise MeasurementFormatError(
            spath, None, f'message {int(bad_v[0])} has a non-finite coil_voltage')
    check_excitation(spath, cols.coil_voltage_v, None)
    n_missing = int(np.count_nonzero(~np.isfinite(cols.coil_current_a)))
    if n_missing:
        notes.append(f'{n_missing} messages with a non-finite coil_current; kept, excluded')
    cols, t = _with_lost_messages(cols, t, notes, bench=True)
    voltage, current = cols.coil_voltage_v, cols.coil_current_a
    drive_v, hold = _bare_coil_drive(voltage, cols.coil_voltage_mean_v, topic, notes)
    n_missing = int(np.count_nonzero(~np.isfinite(current)))
    supply_all = cols.supply_pressure_pa
    supply = float(np.median(supply_all))
    if np.ptp(supply_all) > 0.01 * max(abs(supply), 1e3):
        notes.append(f'supply_pressure varies {supply_all.min():.0f}..{supply_all.max():.0f} '
                     f'Pa; the median {supply:.0f} Pa is used')
    rate = 1.0 / float(np.median(np.diff(t)))
    if rate < _COARSE_RATE_HZ:
        notes.append(f'state stream at {rate:.0f} Hz is coarse for identification (the '
                     'stroke lasts under 1 ms); fitted on what there is')
    position = cols.spool_position_m.copy() if np.all(cols.position_measured) else None
    output = float(np.median(cols.output_pressure_pa))
    metadata = {
        'experiment': 'pwm' if np.any(np.abs(np.diff(voltage)) > 0) and
        np.nanmax(cols.pwm_frequency_hz) > 0 else 'step',
        'valve': frame,
        'supply_pressure_pa': f'{supply:g}',
        'output_pressure_pa': f'{output:g}',
        'sample_rate_hz': f'{rate:g}',
        'topic': topic,
    }
    for note in notes:
        _LOG.info('%s: %s', spath, note)
    return Measurement(
        source=spath, t_s=t, voltage_v=drive_v, current_a=current.copy(),
        supply_pressure_pa=supply, output_pressure_pa=output,
        experiment=metadata['experiment'], position_m=position, metadata=metadata,
        notes=tuple(notes), n_missing_values=n_missing, n_gaps=n_gaps, voltage_hold=hold)


#: A message's coil_voltage_mean agrees with its sampled coil_voltage when it lies between
#: the samples at its interval's ends within this share of the largest |coil_voltage|.
_MEAN_AGREES_SHARE = 0.05


def _bare_coil_drive(voltage: np.ndarray, v_mean: np.ndarray | None, topic: str,
                     notes: list[str]) -> tuple[np.ndarray, str]:
    """The voltage that drives the bare coil and how it is held (``Measurement.voltage_hold``).

    ``coil_voltage_mean`` when every message carries it and it agrees with the samples
    (each mean between the sampled voltages at its interval's ends: a bench step switches
    at most once in an interval): its integral over each interval is exact and the edge
    within an interval is placed from it (:func:`.model_adapter.interval_segments`). The
    sampled ``coil_voltage`` held from one message to the next moves every edge to a
    message instant, up to one period late, which on a bare coil (L/R of milliseconds,
    1 kHz messages) leaves up to a tenth of an ampere at each edge, far above a bench
    ADC's noise.
    """
    if v_mean is None:
        return voltage.copy(), 'sample'
    field = f'{topic} {MEAN_VOLTAGE_FIELD}'
    if v_mean.size != voltage.size or not np.all(np.isfinite(v_mean)):
        notes.append(f'{field} is missing on some messages: the sampled coil_voltage drives '
                     'the coil, held from one message to the next')
        return voltage.copy(), 'sample'
    before = np.concatenate((voltage[:1], voltage[:-1]))
    tol = _MEAN_AGREES_SHARE * max(float(np.max(np.abs(voltage))), 1e-3)
    off = np.flatnonzero((v_mean < np.minimum(before, voltage) - tol)
                         | (v_mean > np.maximum(before, voltage) + tol))
    if off.size:
        k = int(off[0])
        notes.append(f'{field} disagrees with coil_voltage at {off.size} messages (first: '
                     f'message {k}, mean {v_mean[k]:.4g} V, samples {before[k]:.4g} and '
                     f'{voltage[k]:.4g} V): the sampled coil_voltage drives the coil, held '
                     'from one message to the next')
        return voltage.copy(), 'sample'
    notes.append(f'the coil is driven by {field} held over each interval, an edge within an '
                 'interval placed from its mean; coil_current is compared at the message '
                 'instants')
    return np.asarray(v_mean, dtype=float).copy(), 'interval_mean'


def _bench_steps(duty: np.ndarray, coil_voltage_v: np.ndarray) -> bool:
    """True for a bench record: duty only 0 or 1 and the coil voltage never chopped.

    With the drive electronics on, the chopper holds the current with a 20 kHz voltage
    that a 1 kHz sample catches low most of the time once the valve is open; a bench with
    the electronics bypassed applies the supply for as long as the duty is 1.
    """
    if not np.all((duty == 0.0) | (duty == 1.0)):
        return False
    on = coil_voltage_v[duty == 1.0]
    on = on[np.isfinite(on)]
    return bool(on.size) and bool(np.all(on >= 0.5 * np.max(on))) and float(np.max(on)) > 0.0


def _state_operation(spath: str, topic: str, frame: str, t: np.ndarray, cols: StateColumns,
                     notes: list[str], n_gaps: int) -> Measurement:
    """A bag of the suite running PWM: an operational record (drive electronics on)."""
    mean = cols.coil_current_mean_a
    if mean is None or not np.any(np.isfinite(mean)):
        raise MeasurementFormatError(
            spath, None, f'{topic} carries PWM (pwm_frequency up to '
            f'{float(np.max(cols.pwm_frequency_hz)):g} Hz) but its messages have no (or only '
            f'NaN) {MEAN_CURRENT_FIELD!r} field (the mean coil current since the previous '
            'message): a 1 kHz sample of a chopped current cannot be compared with the '
            'model; record the bag with a suite whose ValveState carries it')
    supply = median_pressure(cols.supply_pressure_pa, 'supply_pressure', None, notes)
    output = median_pressure(cols.output_pressure_pa, 'output_pressure', 0.0, notes)
    notes.append(f'the bag does not carry the drive supply voltage: {DEFAULT_BAG_SUPPLY_V:g} V '
                 '(the suite\'s) is assumed')
    v_mean = mean_voltage_column(cols.coil_voltage_mean_v, f'{topic} {MEAN_VOLTAGE_FIELD}',
                                 notes)
    made_by = {}
    if cols.source is not None and np.all(cols.source == STATE_SOURCE_SIMULATOR):
        made_by = {'state_source': 'simulator'}
    return operation_measurement(
        spath, t, cols.duty.copy(), cols.pwm_frequency_hz.copy(), mean.copy(),
        supply_v=DEFAULT_BAG_SUPPLY_V, supply_pa=supply, output_pa=output, notes=notes,
        n_gaps=n_gaps, interval_means=True,
        described=f'from {topic}: the model runs the drive electronics from duty and '
        f'pwm_frequency and is compared with {MEAN_CURRENT_FIELD} (interval means)',
        metadata={'experiment': 'operation', 'valve': frame, 'topic': topic, **made_by},
        coil_voltage_mean=v_mean)
