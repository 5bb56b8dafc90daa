"""Measured valve data: CSV files and rosbag2 bags into one in-memory form.

Two sources feed the identification:

* bench CSV files of the measured-data format (``shared/measured-data-format.md`` of the
  steering repository), read by :mod:`valve_model_pkg.dataformat`: metadata lines
  ``# key: value``, one header row, one row per sample, SI units, gauge pressures;
* rosbag2 bags recorded from the suite (``valve_msgs/msg/ValveState`` on ``/valve/state``).

Both end up as a :class:`Measurement`. Malformed input is refused with a
:class:`~valve_model_pkg.errors.MeasurementFormatError` naming the file, the
line (or message) and the reason. Nothing is dropped silently: a sample whose current is
empty or ``nan`` is kept as ``nan`` (and excluded from the error integrals), gaps in the
time axis are counted, and every such finding is listed in :attr:`Measurement.notes`.

Files with different sample rates are combined by keeping each on its own time base: the
model is simulated at its own step and sampled at each file's sample times, and the error
integrals are integrals over time, so a 1 kHz file and a 50 kHz file weigh by duration,
not by sample count.
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterable, Sequence

import numpy as np

from valve_model_pkg import dataformat
from valve_model_pkg.interface import TOPIC_STATE

from ..errors import MeasurementFormatError

__all__ = [
    'DriveInput',
    'Measurement',
    'VALVE_STATE_MSG',
    'VALVE_STATE_TYPE',
    'read_csv',
    'read_bag',
    'read_measurements',
    'write_csv',
]

_LOG = logging.getLogger(__name__)

#: The message type the suite records its valve state with.
VALVE_STATE_TYPE = 'valve_msgs/msg/ValveState'

#: Text of ``valve_msgs/msg/ValveState.msg``, used to register the type when a bag does
#: not embed its definition (a unit test keeps it equal to the interface file).
VALVE_STATE_MSG = """\
std_msgs/Header header
uint64 sequence
float64 coil_voltage
float64 coil_current
float64 coil_current_mean
float64 coil_voltage_mean
float64 spool_position
float64 spool_velocity
float64 spool_position_avg
float64 mass_flow
float64 duty
float64 pwm_frequency
float64 supply_pressure
float64 output_pressure
uint8 SOURCE_SIMULATOR=0
uint8 SOURCE_CAN=1
uint8 source
bool position_measured
"""

_MIN_SAMPLES = 10
#: ValveState field with the mean coil current since the previous message [A] (issue 12).
MEAN_CURRENT_FIELD = 'coil_current_mean'
#: A coil voltage at or below this everywhere counts as no excitation [V].
_MIN_EXCITATION_V = 1e-3
#: An interval-mean current at most this is exactly 0 (the coil never energised) [A].
_REST_MEAN_A = 1e-9


@dataclass(frozen=True)
class DriveInput:
    """Main PWM commands through the drive electronics, as the model's ``pwm_commands``.

    Built by the readers so that the model latches each command at the period start the
    record shows (see :func:`drive_from_in_force` and :func:`drive_from_main_pwm`).

    Attributes
    ----------
    t_s, duty, pwm_frequency_hz, supply_voltage_v : numpy.ndarray, shape (n,)
        Arguments of ``InputTrace.pwm_commands``: command times [s], duty [1], main PWM
        frequency [Hz], drive supply voltage [V].
    period_starts_s : numpy.ndarray, shape (m,)
        The main PWM period starts the reader reconstructed [s].
    high_until_s : numpy.ndarray, shape (m,)
        End of the high phase of each period [s] (for the phases of the residual).
    """

    t_s: np.ndarray
    duty: np.ndarray
    pwm_frequency_hz: np.ndarray
    supply_voltage_v: np.ndarray
    period_starts_s: np.ndarray
    high_until_s: np.ndarray
    period_duty: np.ndarray | None = None
    period_freq_hz: np.ndarray | None = None
    #: Shifts of the period grid [s] the record allows (its changes bound the phase).
    phase_range_s: tuple[float, float] = (0.0, 0.0)
    #: Immediate switch-offs (duty 0 acts at once) [s] and the frequency then [Hz].
    off_times_s: np.ndarray | None = None
    off_freq_hz: np.ndarray | None = None

    def shifted(self, delta_s: float) -> 'DriveInput':
        """The same commands on a period grid moved by ``delta_s`` [s]."""
        starts = self.period_starts_s + delta_s
        keep = starts >= 0.0
        out = _commands_from_periods(list(starts[keep]), list(self.period_duty[keep]),
                                     list(self.period_freq_hz[keep]),
                                     float(self.supply_voltage_v[0]))
        if self.off_times_s is not None and self.off_times_s.size:
            out = _with_offs(out, self.off_times_s, self.off_freq_hz)
        lo, hi = self.phase_range_s
        from dataclasses import replace
        return replace(out, phase_range_s=(lo - delta_s, hi - delta_s))

    def main_pwm_level(self, t_s: np.ndarray) -> np.ndarray:
        """Supply voltage where the main PWM is high at ``t_s``, else 0 [V], shape (n,)."""
        k = np.searchsorted(self.period_starts_s, t_s, side='right') - 1
        ok = k >= 0
        kk = np.clip(k, 0, None)
        started = self.high_until_s[kk] > self.period_starts_s[kk]
        high = ok & (t_s < self.high_until_s[kk]) & started
        v = np.interp(t_s, self.t_s, self.supply_voltage_v)
        return np.where(high, v, 0.0)


@dataclass(frozen=True)
class Measurement:
    """One measured trace, whatever file it came from.

    Attributes
    ----------
    source : str
        File (or bag directory) the trace was read from.
    t_s : numpy.ndarray, shape (n,)
        Sample times [s], strictly increasing, starting at or after 0.
    voltage_v : numpy.ndarray, shape (n,)
        Voltage at the coil terminals [V]. Between samples it is held (zero-order hold).
    current_a : numpy.ndarray, shape (n,)
        Measured coil current [A]; ``nan`` marks a missing value.
    supply_pressure_pa : float or None
        Supply pressure, gauge [Pa]; ``None`` when the file does not say.
    output_pressure_pa : float
        Output port pressure, gauge [Pa] (0 when the file does not say).
    experiment : str
        ``step`` or ``pwm`` (``unknown`` when the file does not say).
    position_m : numpy.ndarray or None, shape (n,)
        Measured spool position [m] when available.
    metadata : dict
        All metadata as read (unknown keys kept).
    notes : tuple of str
        Everything the reader noticed and kept: missing values, gaps, rate mismatches.
    n_missing_values : int
        Number of samples whose current is missing (``nan``).
    n_gaps : int
        Number of steps of the time axis longer than 1.5 nominal periods.
    """

    source: str
    t_s: np.ndarray
    voltage_v: np.ndarray
    current_a: np.ndarray
    supply_pressure_pa: float | None
    output_pressure_pa: float = 0.0
    experiment: str = 'unknown'
    position_m: np.ndarray | None = None
    metadata: dict[str, str] = field(default_factory=dict)
    notes: tuple[str, ...] = ()
    n_missing_values: int = 0
    n_gaps: int = 0
    drive: DriveInput | None = None
    sampling: str = 'instant'
    exclude_before_s: float = 0.0
    held_out_from_s: float | None = None

    @property
    def through_electronics(self) -> bool:
        """True when the model runs the drive electronics from the main PWM commands."""
        return self.drive is not None

    @property
    def name(self) -> str:
        """Short name of the source (file name without directories)."""
        return Path(self.source).name

    @property
    def n_samples(self) -> int:
        """Number of samples (rows), missing values included."""
        return int(self.t_s.size)

    @property
    def duration_s(self) -> float:
        """Time span of the trace [s]."""
        return float(self.t_s[-1] - self.t_s[0]) if self.t_s.size else 0.0

    @property
    def sample_rate_hz(self) -> float:
        """Actual sample rate [Hz] from the median sampling period."""
        if self.t_s.size < 2:
            return float('nan')
        return 1.0 / float(np.median(np.diff(self.t_s)))

    @property
    def valid(self) -> np.ndarray:
        """Samples that enter the errors, shape (n,): a measured current, and not in the
        discarded start (``exclude_before_s``: a record that starts in motion, or the fit
        part of a record whose hold-out this is)."""
        return np.isfinite(self.current_a) & (self.t_s >= self.exclude_before_s)

    def with_current(self, current_a: np.ndarray, source: str | None = None) -> 'Measurement':
        """Return a copy whose current is replaced (used for residuals and for tests).

        Parameters
        ----------
        current_a : numpy.ndarray, shape (n,)
            New current trace [A].
        source : str, optional
            New source name; by default the old one.
        """
        cur = np.asarray(current_a, dtype=float)
        if cur.shape != self.t_s.shape:
            raise ValueError(f'current has shape {cur.shape}, expected {self.t_s.shape}')
        from dataclasses import replace
        return replace(self, source=self.source if source is None else source,
                       current_a=cur, metadata=dict(self.metadata),
                       n_missing_values=int(np.count_nonzero(~np.isfinite(cur))))

    def summary(self) -> str:
        """One line a person can read in a progress log."""
        p = ('unknown' if self.supply_pressure_pa is None
             else f'{self.supply_pressure_pa / 1e5:.2f} bar')
        v = self.voltage_v
        return (f'{self.name}: {self.n_samples} samples, {self.duration_s * 1e3:.1f} ms at '
                f'{self.sample_rate_hz / 1e3:.3g} kHz, voltage {v.min():.3g}..{v.max():.3g} V, '
                f'supply {p}, {self.n_missing_values} missing values, {self.n_gaps} gaps')


# --------------------------------------------------------------------------------------
# CSV (the measured-data format, read and written by valve_model_pkg.dataformat)
# --------------------------------------------------------------------------------------

def _check_time_axis(path: str, t: np.ndarray, linenos: Sequence[int] | None) -> None:
    """The format's time-axis rule, raised as the identification's error type."""
    try:
        dataformat.check_time_axis(path, t, linenos)
    except dataformat.DataFormatError as err:
        raise MeasurementFormatError(err.path, err.line, err.reason) from err


def read_csv(path: str | Path) -> Measurement:
    """Read a bench measurement (``step`` or ``pwm``) of the measured-data format.

    Parameters
    ----------
    path : str or pathlib.Path
        The CSV file.

    Returns
    -------
    Measurement
        The trace; ``supply_pressure_pa`` is ``None`` if the metadata lacks it. For a
        ``pwm`` record, ``voltage_v`` is its ``coil_voltage`` column (the identification
        drives the coil model with the voltage at the coil terminals).

    Raises
    ------
    MeasurementFormatError
        The file cannot be read or is malformed (the message names the file, the line, the
        key and the value), is a ``flow_map`` record, has fewer than 10 rows, lacks more
        than half of its current values, or is a ``step`` record with PWM content.

    Notes
    -----
    The format's rules are applied by :func:`valve_model_pkg.dataformat.read_trace`: a
    current field that is empty or ``nan`` is a missing sample, kept as ``nan``, counted
    in ``n_missing_values`` and listed in ``notes``; every other field must be a finite
    number. An ``operation`` record is read by :func:`read_operation_csv`. A ``pwm``
    record drives the bare coil through its ``coil_voltage`` column when that resolves the
    chopper, else the model runs the drive electronics from the main PWM column. A
    ``step`` record whose content is PWM or a current chopper is refused with the reason.
    """
    spath = str(path)
    try:
        record = dataformat.read_record(path)
        if record.kind == 'flow_map':
            dataformat.read_trace(path)  # raises the format's own 'is a flow_map' refusal
    except dataformat.DataFormatError as err:
        raise MeasurementFormatError(err.path, err.line, err.reason) from err
    if record.kind == 'operation':
        return read_operation_csv(path)
    n_rows = record.t_s.size
    if n_rows < _MIN_SAMPLES:
        raise MeasurementFormatError(
            spath, None, f'has {n_rows} data rows; at least {_MIN_SAMPLES} are needed')
    if record.n_missing_values > 0.5 * n_rows:
        raise MeasurementFormatError(
            spath, None, f'{record.n_missing_values} of {n_rows} current values are missing')
    voltage = record.voltage_v
    notes = list(record.notes)
    drive = None
    sampling = ('interval_mean' if record.metadata.get('current_averaging') == 'interval_mean'
                else 'instant')
    if record.experiment == 'pwm':
        # A pwm record's 'voltage' is the main PWM input to the drive electronics. With a
        # coil_voltage column that resolves the chopper, the bare coil is driven by it;
        # otherwise the model runs the drive electronics from the main PWM.
        coil = record.coil_voltage_v
        use_coil = coil is not None and bool(np.all(np.isfinite(coil)))
        if use_coil and _chopper_unresolved(coil, voltage):
            use_coil = False
            notes.append('coil_voltage toggles faster than its samples resolve (the 20 kHz '
                         'current chopper): not used as a bare-coil input; the model runs '
                         'the drive electronics from the main PWM column instead')
        elif coil is not None and not use_coil:
            notes.append('coil_voltage has missing values: not used; the model runs the '
                         'drive electronics from the main PWM column')
        if use_coil:
            voltage = coil
            notes.append('pwm record: the bare coil model is driven by the measured '
                         'coil_voltage column (chopper and release pulse included)')
        else:
            _check_excitation(spath, voltage, record.line_numbers)
            meta_v = record.metadata.get('supply_voltage_v')
            supply_v = float(meta_v) if meta_v else float(np.max(voltage))
            if not meta_v:
                notes.append(f'no supply_voltage_v: the drive supply is taken as the main '
                             f'PWM high level, {supply_v:.3g} V')
            freq = record.metadata.get('pwm_frequency_hz')
            drive = drive_from_main_pwm(record.t_s, voltage, supply_v,
                                        float(freq) if freq else None)
            notes.append(f'pwm record: the model runs the drive electronics (boost, current '
                         f'chopper, release pulse) from the main PWM column at {supply_v:.3g} '
                         'V supply')
    elif record.experiment in ('step', 'unknown'):
        _refuse_pwm_in_step(spath, record.t_s, voltage, record.current_a)
    _check_excitation(spath, voltage, record.line_numbers)
    if record.n_missing_values:
        notes = [n + ' and excluded from the errors' if 'without a current value' in n else n
                 for n in notes]
    for note in notes:
        _LOG.info('%s: %s', spath, note)
    return Measurement(
        source=spath, t_s=record.t_s.copy(), voltage_v=voltage.copy(),
        current_a=record.current_a.copy(), supply_pressure_pa=record.supply_pressure_pa,
        output_pressure_pa=record.output_pressure_pa, experiment=record.experiment,
        position_m=None if record.position_m is None else record.position_m.copy(),
        metadata=dict(record.metadata), notes=tuple(notes),
        n_missing_values=record.n_missing_values, n_gaps=record.n_gaps, drive=drive,
        sampling=sampling)


def _check_excitation(source: str, voltage: np.ndarray, line_numbers: np.ndarray | None
                      ) -> None:
    """Refuse a record whose coil voltage is zero throughout: it excites nothing to fit.

    Checked before any simulation, so such a record is refused at once instead of being
    fitted for minutes.
    """
    if np.any(np.abs(voltage) > _MIN_EXCITATION_V):
        return
    where = (f' (lines {int(line_numbers[0])}..{int(line_numbers[-1])})'
             if line_numbers is not None and len(line_numbers) else '')
    raise MeasurementFormatError(
        source, None, f'has no excitation: the coil voltage is 0 V in all {voltage.size} '
        f'samples{where}; nothing to identify')


def write_csv(path: str | Path, t_s: np.ndarray, voltage_v: np.ndarray, current_a: np.ndarray,
              metadata: dict[str, object], *, position_m: np.ndarray | None = None,
              precision: int = 7) -> Path:
    """Write a trace in the measured-data format (:func:`valve_model_pkg.dataformat.
    write_table`).

    Parameters
    ----------
    path : str or pathlib.Path
        Destination file (parent directories are created).
    t_s, voltage_v, current_a : numpy.ndarray, shape (n,)
        Time [s], coil voltage [V] and current [A]; ``nan`` current is written empty
        (a missing sample).
    metadata : dict
        Written as ``# key: value`` lines in the given order.
    position_m : numpy.ndarray, optional
        Spool position [m], written as column ``position``.
    precision : int
        Significant digits of every value.

    Returns
    -------
    pathlib.Path
        The written file.
    """
    columns: dict[str, np.ndarray] = {'t': t_s, 'voltage': voltage_v, 'current': current_a}
    if position_m is not None:
        columns['position'] = position_m
    return dataformat.write_table(path, metadata, columns, precision=precision)


# --------------------------------------------------------------------------------------
# rosbag2
# --------------------------------------------------------------------------------------

def _one_line(err: object) -> str:
    """An exception's text on one line (library messages may span several)."""
    return ' '.join(str(err).split()) or type(err).__name__


def _valve_typestore(connection: object) -> object:
    """A typestore that knows ValveState: from the bag if it embeds it, else from our text."""
    from rosbags.interfaces import MessageDefinitionFormat
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.ROS2_JAZZY)
    msgdef = getattr(connection, 'msgdef', None)
    if msgdef is not None and msgdef.format == MessageDefinitionFormat.MSG and msgdef.data:
        types = get_types_from_msg(msgdef.data, VALVE_STATE_TYPE)
    else:
        types = get_types_from_msg(VALVE_STATE_MSG, VALVE_STATE_TYPE)
    store.register(types)
    return store


def read_bag(path: str | Path, *, topic: str = '/' + TOPIC_STATE,
             valve: str | None = None) -> Measurement:
    """Read the valve state stream of a rosbag2 bag recorded from the suite.

    Parameters
    ----------
    path : str or pathlib.Path
        Bag directory (with ``metadata.yaml``), any storage rosbags reads (MCAP, sqlite3).
    topic : str
        Topic of the ``valve_msgs/msg/ValveState`` messages.
    valve : str, optional
        ``header.frame_id`` of the valve to take when the topic carries several valves.

    Returns
    -------
    Measurement
        Time from ``header.stamp`` relative to the first message (the bag's receive time
        when the stamps are all zero); ``coil_voltage``, ``coil_current``; the supply
        pressure is the median of ``supply_pressure`` over the messages; the spool position
        only if the messages say it is measured (``position_measured``).

    Raises
    ------
    MeasurementFormatError
        The bag cannot be read, lacks the topic, mixes valves without ``valve`` given,
        has non-increasing stamps or non-finite voltages.

    Notes
    -----
    The suite publishes its state at about 1 kHz. That is coarse for identification (the
    spool stroke lasts under a millisecond): the fit uses what there is, the model is
    simulated at its own step and sampled at the message times, and the voltage is held
    between messages, so PWM edges between two messages are lost. Sequence gaps are
    reported as missing samples.
    """
    from rosbags.rosbag2 import Reader
    from rosbags.typesys import TypesysError

    spath = str(path)
    try:
        reader = Reader(Path(path))
        reader.open()
    except Exception as err:  # rosbags raises several unrelated types here
        raise MeasurementFormatError(spath, None, f'cannot be opened as a rosbag2 bag: '
                                     f'{_one_line(err)}') from err
    try:
        conns = [c for c in reader.connections if c.topic == topic]
        if not conns:
            have = sorted({f'{c.topic} ({c.msgtype})' for c in reader.connections})
            raise MeasurementFormatError(spath, None, f'has no topic {topic!r}; it has {have}')
        wrong = [c.msgtype for c in conns if c.msgtype != VALVE_STATE_TYPE]
        if wrong:
            raise MeasurementFormatError(
                spath, None, f'topic {topic!r} carries {wrong[0]}, not {VALVE_STATE_TYPE}')
        try:
            store = _valve_typestore(conns[0])
        except TypesysError as err:
            raise MeasurementFormatError(
                spath, None, f'message definition of {VALVE_STATE_TYPE} unusable: {err}'
            ) from err
        records: list[tuple] = []
        messages = reader.messages(connections=conns)
        index = 0
        while True:
            try:
                conn, logtime, raw = next(messages)
            except StopIteration:
                break
            except Exception as err:  # a damaged chunk: rosbags/mcap raise many types
                raise MeasurementFormatError(
                    spath, None, f'is damaged after message {index} on {topic} '
                    f'({type(err).__name__}: {_one_line(err)}); try valve_recorder '
                    '--recover') from err
            try:
                msg = store.deserialize_cdr(raw, conn.msgtype)
            except Exception as err:  # a truncated or foreign payload
                raise MeasurementFormatError(
                    spath, None, f'message {index} on {topic} cannot be decoded: '
                    f'{_one_line(err)}') from err
            index += 1
            stamp = msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec
            records.append((msg.header.frame_id, stamp, logtime * 1e-9, int(msg.sequence),
                            msg.coil_voltage, msg.coil_current, msg.spool_position,
                            bool(msg.position_measured), msg.supply_pressure,
                            msg.output_pressure, msg.pwm_frequency, msg.duty,
                            getattr(msg, MEAN_CURRENT_FIELD, math.nan),
                            1.0 if hasattr(msg, MEAN_CURRENT_FIELD) else 0.0))
    finally:
        reader.close()
    return _bag_records_to_measurement(spath, topic, valve, records)


def _bag_records_to_measurement(spath: str, topic: str, valve: str | None,
                                records: list[tuple]) -> Measurement:
    """Turn decoded ValveState fields into a Measurement (checks and notes included)."""
    frames = sorted({r[0] for r in records})
    if valve is not None:
        records = [r for r in records if r[0] == valve]
        if not records:
            raise MeasurementFormatError(
                spath, None, f'no message on {topic} has frame_id {valve!r}; found {frames}')
    elif len(frames) > 1:
        raise MeasurementFormatError(
            spath, None, f'{topic} carries several valves {frames}; choose one (valve=...)')
    if len(records) < _MIN_SAMPLES:
        raise MeasurementFormatError(
            spath, None, f'has {len(records)} messages on {topic}; at least {_MIN_SAMPLES} '
            'are needed')
    arr = np.array([r[1:] for r in records], dtype=float)
    stamps, logtimes, seq = arr[:, 0], arr[:, 1], arr[:, 2]
    notes: list[str] = []
    if np.all(stamps == 0.0):
        notes.append('all header stamps are zero; the bag receive times are used')
        stamps = logtimes
    t = stamps - stamps[0]
    n_back = int(np.count_nonzero(np.diff(t) <= 0.0))
    if n_back and np.all(np.diff(seq) > 0) and t[-1] > t[0]:
        # The CAN driver on simulation time stamps each state on receipt with a /clock
        # that can lag a step behind the emulator's telemetry; the telemetry itself comes
        # at one message per step, which the sequence numbers count. The step is the
        # median over pairs half the record apart: from the two end stamps alone, a last
        # one that lags a step makes it 0.02 % short at 5000 messages (a least-squares
        # line is biased too, the lags are one-sided), and the samples then drift a whole
        # step against the model's PWM grid by the end.
        half = seq.size // 2
        step = float(np.median((t[half:] - t[:seq.size - half])
                               / (seq[half:] - seq[:seq.size - half])))
        t = (seq - seq[0]) * step
        notes.append(f'{n_back} header stamps do not increase while the sequence numbers '
                     f'do; the time axis is rebuilt from the sequence numbers at the '
                     f'step {step * 1e3:.6g} ms (median over half-record spans)')
    _check_time_axis(spath, t, None)
    freq_all, duty_all = arr[:, 9], arr[:, 10]
    if np.any(freq_all > 0.0) and np.any(duty_all > 0.0):
        if not _bench_steps(duty_all, arr[:, 3]):
            return _bag_operation(spath, topic, frames[0] if valve is None else valve, t,
                                  arr, notes)
        notes.append('duty steps between 0 and 1 with an unchopped coil voltage (a bench '
                     'with the drive electronics bypassed): fitted as a bare coil driven by '
                     'coil_voltage')
    voltage, current = arr[:, 3], arr[:, 4]
    bad_v = np.flatnonzero(~np.isfinite(voltage))
    if bad_v.size:
        raise MeasurementFormatError(
            spath, None, f'message {int(bad_v[0])} has a non-finite coil_voltage')
    _check_excitation(spath, voltage, None)
    n_missing = int(np.count_nonzero(~np.isfinite(current)))
    if n_missing:
        notes.append(f'{n_missing} messages with a non-finite coil_current; kept, excluded')
    dseq = np.diff(seq)
    lost = int(np.sum(np.clip(dseq - 1, 0, None)))
    n_gaps = int(np.count_nonzero(dseq > 1))
    if lost:
        notes.append(f'{n_gaps} sequence gaps, {lost} messages lost; kept, the model is '
                     'simulated through them')
    supply_all = arr[:, 7]
    supply = float(np.median(supply_all))
    if np.ptp(supply_all) > 0.01 * max(abs(supply), 1e3):
        notes.append(f'supply_pressure varies {supply_all.min():.0f}..{supply_all.max():.0f} '
                     f'Pa; the median {supply:.0f} Pa is used')
    rate = 1.0 / float(np.median(np.diff(t)))
    if rate < 10e3:
        notes.append(f'state stream at {rate:.0f} Hz is coarse for identification (the '
                     'stroke lasts under 1 ms); fitted on what there is')
    measured = arr[:, 6].astype(bool)
    position = arr[:, 5].copy() if np.all(measured) else None
    metadata = {
        'experiment': 'pwm' if np.any(np.abs(np.diff(voltage)) > 0) and
        np.nanmax(arr[:, 9]) > 0 else 'step',
        'valve': frames[0] if valve is None else valve,
        'supply_pressure_pa': f'{supply:g}',
        'output_pressure_pa': f'{float(np.median(arr[:, 8])):g}',
        'sample_rate_hz': f'{rate:g}',
        'topic': topic,
    }
    for note in notes:
        _LOG.info('%s: %s', spath, note)
    return Measurement(
        source=spath, t_s=t, voltage_v=voltage.copy(), current_a=current.copy(),
        supply_pressure_pa=supply, output_pressure_pa=float(np.median(arr[:, 8])),
        experiment=metadata['experiment'], position_m=position, metadata=metadata,
        notes=tuple(notes), n_missing_values=n_missing, n_gaps=n_gaps)


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


def _bag_operation(spath: str, topic: str, frame: str, t: np.ndarray, arr: np.ndarray,
                   notes: list[str]) -> Measurement:
    """A bag of the suite running PWM: an operational record (drive electronics on)."""
    if not np.all(arr[:, 12] > 0.0) or not np.any(np.isfinite(arr[:, 11])):
        raise MeasurementFormatError(
            spath, None, f'{topic} carries PWM (pwm_frequency up to '
            f'{float(np.max(arr[:, 9])):g} Hz) but its messages have no (or only NaN) '
            f'{MEAN_CURRENT_FIELD!r} field (the mean coil current since the previous '
            'message): a 1 kHz sample of a chopped current cannot be compared with the '
            'model; record the bag with a suite whose ValveState carries it')
    current = arr[:, 11].copy()
    freq, duty = arr[:, 9].copy(), arr[:, 10].copy()
    bad = np.flatnonzero(~np.isfinite(freq) | ~np.isfinite(duty) | (freq <= 0.0)
                         | (duty < 0.0) | (duty > 1.0))
    if bad.size:
        raise MeasurementFormatError(spath, None, f'message {int(bad[0])} has duty '
                                     f'{duty[bad[0]]!r} / pwm_frequency {freq[bad[0]]!r}')
    seq = arr[:, 2]
    dseq = np.diff(seq)
    lost = int(np.sum(np.clip(dseq - 1, 0, None)))
    n_gaps = int(np.count_nonzero(dseq > 1))
    if lost:
        notes.append(f'{n_gaps} sequence gaps, {lost} messages lost; kept, the model is '
                     'simulated through them')
    supply = _median_pressure(arr[:, 7], 'supply_pressure', None, notes)
    output = _median_pressure(arr[:, 8], 'output_pressure', 0.0, notes)
    notes.append(f'the bag does not carry the drive supply voltage: {DEFAULT_BAG_SUPPLY_V:g} V '
                 '(the suite\'s) is assumed')
    drive, dnotes = drive_from_in_force(t, duty, freq, DEFAULT_BAG_SUPPLY_V, current)
    notes += dnotes
    moving = np.flatnonzero(duty > 0.0)
    at_rest = bool(moving.size and t[moving[0]] - t[0] >= 1.0 / freq[0])
    cut, cnotes = _discard_for(drive, float(t[0]), at_rest)
    notes += cnotes
    n_missing = int(np.count_nonzero(~np.isfinite(current)))
    rate = 1.0 / float(np.median(np.diff(t)))
    notes.append(f'operation record from {topic}: the model runs the drive electronics from '
                 f'duty and pwm_frequency and is compared with {MEAN_CURRENT_FIELD} '
                 '(interval means)')
    metadata = {'experiment': 'operation', 'valve': frame, 'topic': topic,
                'supply_pressure_pa': f'{supply:g}', 'sample_rate_hz': f'{rate:g}',
                'supply_voltage_v': f'{DEFAULT_BAG_SUPPLY_V:g}',
                'current_averaging': 'interval_mean'}
    for note in notes:
        _LOG.info('%s: %s', spath, note)
    return Measurement(
        source=spath, t_s=t, voltage_v=drive.main_pwm_level(t), current_a=current,
        supply_pressure_pa=supply, output_pressure_pa=output, experiment='operation',
        metadata=metadata, notes=tuple(notes), n_missing_values=n_missing, n_gaps=n_gaps,
        drive=drive, sampling='interval_mean', exclude_before_s=cut)


def read_measurements(paths: Iterable[str | Path], *, topic: str = '/' + TOPIC_STATE,
                      valve: str | None = None) -> list[Measurement]:
    """Read CSV files and bag directories (chosen by what each path is).

    Parameters
    ----------
    paths : iterable of str or pathlib.Path
        CSV files, bag directories, or ``.mcap``/``.db3`` files inside a bag directory.
    topic, valve
        Passed to :func:`read_bag`.

    Returns
    -------
    list of Measurement
        In the order given.
    """
    out = []
    for p in paths:
        path = Path(p)
        if path.is_dir():
            out.append(read_bag(path, topic=topic, valve=valve))
        elif path.suffix in ('.mcap', '.db3') and (path.parent / 'metadata.yaml').exists():
            out.append(read_bag(path.parent, topic=topic, valve=valve))
        else:
            out.append(read_csv(path))
    return out


# --------------------------------------------------------------------------------------
# Records through the drive electronics: main PWM commands -> the model's pwm_commands
# --------------------------------------------------------------------------------------

#: A record that starts in motion: the model starts at rest, so the errors leave out the
#: first ``max(DISCARD_PERIODS main PWM periods, DISCARD_MIN_S)`` of it.
DISCARD_PERIODS = 3
DISCARD_MIN_S = 0.05
#: A command is given this long before the period start it must be latched at [s] (the
#: model latches commands at the next period start).
_LATCH_LEAD_S = 1e-6
#: Drive supply voltage assumed for a bag, which does not carry it [V].
DEFAULT_BAG_SUPPLY_V = 24.0
#: Largest current of a bare coil after a long on-phase, as a fraction of V / R_max: a
#: lower plateau means a current chopper holds it (R_max = 22.5 ohm, the search bound).
_BARE_COIL_R_MAX_OHM = 22.5


def _lead(period_s: float) -> float:
    return min(_LATCH_LEAD_S, 0.25 * period_s)


def _phase_from_changes(t: np.ndarray, change_idx: np.ndarray, period_s: float,
                        rise: tuple[float, float] | None = None
                        ) -> tuple[float, tuple[float, float]] | None:
    """First main PWM period start in [t0, t0 + T) consistent with the changes seen.

    A change of the command in force seen at sample ``k`` means a period start in
    ``(t[k-1], t[k]]``. The phase that satisfies most such intervals (the middle of the
    widest set that does) is returned with the range of shifts that satisfy as many
    (the identification refines the phase in it from the current); ``None`` without any
    change. ``rise`` = ``[lo, hi)``: a period start the current shows (the first rise of
    the interval-mean current from exactly 0), kept as a hard constraint when some phase
    meets it. The interval ends are candidates too: a controller whose PWM grid is locked
    to its telemetry grid (the emulator: 20 ms = 20 telemetry periods) starts a period
    exactly at a sample time, which the middle of the range misses by half a sample.
    """
    if change_idx.size == 0:
        return None
    a, b = t[change_idx - 1], t[change_idx]
    ends = [b] + ([np.array([rise[0]])] if rise is not None else [])
    cand = np.sort(np.concatenate(
        [t[0] + period_s * (np.arange(4000) + 0.5) / 4000.0]
        + [t[0] + np.mod(e - t[0], period_s) for e in ends]))
    # 1 ns tolerance: a start at exactly b (or at the rise) stays in (a, b] after mod
    d = np.mod(b[None, :] - cand[:, None] + _PHASE_TOL_S, period_s) - _PHASE_TOL_S
    ok = d < (b - a)[None, :]
    score = ok.sum(axis=1)
    if rise is not None:
        dr = np.mod(cand - rise[0] + _PHASE_TOL_S, period_s) - _PHASE_TOL_S
        meets = dr < rise[1] - rise[0]
        if np.any(meets):
            score = np.where(meets, score, -1)
    best = score == score.max()
    # middle of the longest run of best candidates (circular runs are rare; take linear)
    idx = np.flatnonzero(best)
    runs = np.split(idx, np.flatnonzero(np.diff(idx) > 1) + 1)
    run = max(runs, key=len)
    mid = float(cand[run[len(run) // 2]])
    return mid, (float(cand[run[0]]) - mid, float(cand[run[-1]]) - mid)


#: Time tolerance of the phase candidates [s].
_PHASE_TOL_S = 1e-9


def _first_rise(t: np.ndarray, current: np.ndarray | None, duty: np.ndarray,
                end: int) -> tuple[float, float] | None:
    """``[t[j], t[j + 1])``: where the first period start lies if the interval-mean current
    is exactly 0 up to sample j (the coil was never energised before t[j]) and not at j + 1
    (within the first ``end`` samples, with a non-zero duty by then); else None."""
    if current is None:
        return None
    live = np.flatnonzero(~(np.abs(current[:end]) <= _REST_MEAN_A))
    if live.size == 0 or live[0] == 0 or not np.any(duty[:live[0] + 1] > 0.0):
        return None
    j = int(live[0]) - 1
    return float(t[j]), float(t[j + 1])


def _commands_from_periods(starts: list[float], duty: list[float], freq: list[float],
                           supply_v: float) -> DriveInput:
    """pwm_commands arguments that make the model latch each (duty, f) at its start."""
    ts: list[float] = []
    dd: list[float] = []
    ff: list[float] = []
    s0 = starts[0]
    if s0 > 0.0:
        # duty 0 until the first period start, with a pre-period that ends exactly there
        n = max(1, int(math.ceil(s0 / 1e-3)))
        ts.append(0.0)
        dd.append(0.0)
        ff.append(n / s0)
        prev_f = n / s0
    else:
        prev_f = None
    last = (None, None)
    for s, d, f in zip(starts, duty, freq):
        if (d, f) == last:
            continue
        t_cmd = 0.0 if s <= 0.0 else s - _lead(1.0 / prev_f)
        if ts and t_cmd <= ts[-1]:
            t_cmd = ts[-1] + 0.5 * (s - ts[-1])
        ts.append(t_cmd)
        dd.append(d)
        ff.append(f)
        last = (d, f)
        prev_f = f
    st = np.asarray(starts)
    high = st + np.asarray(duty) / np.asarray(freq)
    return DriveInput(t_s=np.asarray(ts), duty=np.asarray(dd), pwm_frequency_hz=np.asarray(ff),
                      supply_voltage_v=np.full(len(ts), float(supply_v)),
                      period_starts_s=st, high_until_s=high, period_duty=np.asarray(duty),
                      period_freq_hz=np.asarray(freq))


def drive_from_in_force(t: np.ndarray, duty: np.ndarray, freq: np.ndarray, supply_v: float,
                        current_mean: np.ndarray | None = None
                        ) -> tuple[DriveInput, list[str]]:
    """Commands of an operational record (duty and frequency *in force* per sample).

    The main PWM period grid is reconstructed: its phase from the samples at which the
    command in force changes (each change happens at a period start between the previous
    sample and that one), then period by period with the frequency in force. With
    ``current_mean`` (interval means [A]) the first rise of the current from exactly 0
    narrows the phase (see :func:`_first_rise`).

    Returns
    -------
    drive : DriveInput
    notes : list of str
    """
    notes: list[str] = []
    # A non-zero command is latched at a period start; a duty of 0 acts at once (close
    # semantics), so only changes to a non-zero duty place the period grid.
    change = np.flatnonzero((np.diff(duty) != 0) | (np.diff(freq) != 0)) + 1
    offs = change[duty[change] == 0.0]
    change = change[duty[change] > 0.0]
    f_first = freq[0]
    first_f_change = np.flatnonzero(np.diff(freq) != 0)
    end_first = first_f_change[0] + 1 if first_f_change.size else t.size
    found = _phase_from_changes(t, change[change <= end_first], 1.0 / f_first,
                                _first_rise(t, current_mean, duty, end_first))
    if found is None:
        phase = float(t[0])
        prange = (0.0, 1.0 / f_first)
        notes.append('the command in force never changes: the main PWM phase cannot be '
                     'read from the record; it is found from the current')
    else:
        phase, prange = found
        notes.append(f'main PWM period grid reconstructed from the command changes: first '
                     f'period start at {phase * 1e3:.3f} ms')
    # the period in progress at the first sample started one period before the phase
    s = phase
    while s - 1.0 / f_first >= -_PHASE_TOL_S:
        s -= 1.0 / f_first
    if s < _PHASE_TOL_S:
        s = 0.0  # a start at t = 0 within rounding (a phase on the sample grid)
    starts, dl, fl = [], [], []
    t_end = float(t[-1])
    while s <= t_end:
        k = min(int(np.searchsorted(t, s - 1e-12, side='left')), t.size - 1)
        starts.append(s)
        dl.append(float(duty[k]))
        fl.append(float(freq[k]))
        s += 1.0 / freq[k]
    from dataclasses import replace
    drive = _commands_from_periods(starts, dl, fl, supply_v)
    if offs.size:
        on_samples = found is not None and float(np.min(np.abs(t - phase))) < 1e-6
        if on_samples:
            # The period grid lies on the sample instants: the controller acts on its own
            # telemetry grid (the emulator in lockstep does), so a switch-off seen in an
            # interval acted at its start (mid-interval put 0.5 ms of supply too much on
            # the coil: 86 mA at a switch-off of a CAN demo bag).
            t_off = t[offs - 1].astype(float)
            where = 'at the start of the interval in which they were seen (the period grid ' \
                'lies on the sample instants)'
        else:
            # unknown instant within the interval: its middle
            t_off = 0.5 * (t[offs - 1] + t[offs])
            where = 'mid-interval'
        drive = _with_offs(drive, t_off, np.interp(t_off, t, freq))
        notes.append(f'{offs.size} switch-offs (duty 0 acts at once) placed {where}')
    return replace(drive, phase_range_s=prange), notes


def _with_offs(drive: DriveInput, t_off: np.ndarray, f_at: np.ndarray) -> DriveInput:
    """``drive`` with immediate duty-0 commands at ``t_off`` merged in."""
    from dataclasses import replace
    # A switch-off must not move the period grid, and the model latches its frequency at
    # the next period start: it carries the frequency of the model's command in force (in
    # the lead-in before the first period start, the lead-in's, not the record's f_at).
    k_cmd = np.clip(np.searchsorted(drive.t_s, t_off, side='right') - 1, 0, None)
    f_cmd = drive.pwm_frequency_hz[k_cmd]
    # The period commands skip repeats of the (duty, f) before; after a switch-off the
    # next non-zero period must be commanded again, or the model stays off for it.
    re_t, re_d, re_f = [], [], []
    if drive.period_duty is not None:
        starts = drive.period_starts_s
        for t0, t1 in zip(t_off, np.append(t_off[1:], np.inf)):
            j = int(np.searchsorted(starts, t0, side='right'))
            if j >= starts.size or starts[j] >= t1 or drive.period_duty[j] <= 0.0:
                continue
            if not np.any((drive.t_s > t0) & (drive.t_s < starts[j])):
                re_t.append(max(starts[j] - _lead(1.0 / drive.period_freq_hz[j]),
                                0.5 * (t0 + starts[j])))
                re_d.append(float(drive.period_duty[j]))
                re_f.append(float(drive.period_freq_hz[j]))
    ts = np.concatenate((drive.t_s, t_off, re_t))
    order = np.argsort(ts, kind='stable')
    out = replace(
        drive, t_s=ts[order],
        duty=np.concatenate((drive.duty, np.zeros(t_off.size), re_d))[order],
        pwm_frequency_hz=np.concatenate((drive.pwm_frequency_hz, f_cmd, re_f))[order],
        supply_voltage_v=np.full(ts.size, float(drive.supply_voltage_v[0])),
        off_times_s=t_off, off_freq_hz=f_at)
    k = np.searchsorted(out.period_starts_s, t_off, side='right') - 1
    high = out.high_until_s.copy()
    ok = k >= 0
    high[k[ok]] = np.minimum(high[k[ok]], t_off[ok])
    return replace(out, high_until_s=high)


def drive_from_main_pwm(t: np.ndarray, v: np.ndarray, supply_v: float,
                        freq_hz: float | None) -> DriveInput:
    """Commands of a bench ``pwm`` record from its main PWM voltage column (its edges)."""
    on = v > 0.5 * float(np.max(v))
    rise = np.flatnonzero(on & ~np.concatenate(([False], on[:-1])))
    fall = np.flatnonzero(~on & np.concatenate(([False], on[:-1])))
    tr = t[rise].astype(float)
    tr[tr == t[0]] = 0.0 if t[0] == 0.0 else tr[tr == t[0]]
    starts, dl, fl = [], [], []
    dt = float(np.median(np.diff(t)))
    for j, r in enumerate(tr):
        f_end = t[fall[fall > rise[j]][0]] if np.any(fall > rise[j]) else t[-1] + dt
        if j + 1 < tr.size:
            period = tr[j + 1] - r
        elif freq_hz:
            period = 1.0 / freq_hz
        else:
            period = (f_end - r) * 2.0 if np.any(fall > rise[j]) else (t[-1] - r + dt) * 1.001
        starts.append(float(r))
        fl.append(1.0 / period)
        dl.append(float(min(1.0, max(0.0, (f_end - r) / period))))
    return _commands_from_periods(starts, dl, fl, supply_v)


def _refuse_pwm_in_step(spath: str, t: np.ndarray, v: np.ndarray, i: np.ndarray) -> None:
    """Refuse a ``step`` (bare-coil) record whose content says PWM or a chopper."""
    vmax = float(np.max(np.abs(v)))
    if vmax <= 0.0:
        return
    on = np.abs(v) > 0.5 * vmax
    pulses = int(np.count_nonzero(on[1:] & ~on[:-1]) + (1 if on[0] else 0))
    if pulses > 4:
        raise MeasurementFormatError(
            spath, None, f"experiment is 'step' (voltage steps on the bare coil) but the "
            f'voltage column switches on {pulses} times: a PWM command. Record it as '
            "'pwm' (main PWM into the drive electronics) or 'operation'; it is not fitted as "
            'a bare coil')
    # long on-phases: a bare coil's current keeps rising towards V/R; a chopper holds it low
    edges = np.flatnonzero(np.diff(on.astype(int))) + 1
    bounds = np.concatenate(([0], edges, [on.size]))
    for a, b in zip(bounds[:-1], bounds[1:]):
        if not on[a] or t[b - 1] - t[a] < 8e-3:
            continue
        tail = np.abs(i[a + int(0.8 * (b - a)):b])
        tail = tail[np.isfinite(tail)]
        if tail.size < 4:
            continue
        level = float(np.median(tail))
        half = tail.size // 2
        flat = abs(float(np.median(tail[half:])) - float(np.median(tail[:half]))) \
            < 0.05 * level
        volts = float(np.median(np.abs(v[a:b])))
        # a held plateau well below what a bare coil reaches (zero current is no chopper)
        if flat and 0.05 < level < 0.55 * volts / _BARE_COIL_R_MAX_OHM:
            raise MeasurementFormatError(
                spath, None, f"experiment is 'step' (bare coil) but the current holds "
                f'{level:.3g} A after {1e3 * (t[b - 1] - t[a]):.1f} ms at {volts:.3g} V: a '
                f'bare coil would need R > {volts / level:.0f} ohm. A current chopper (the '
                "drive electronics) is in the loop: record it as 'pwm' or 'operation'")


def _chopper_unresolved(v_coil: np.ndarray, v_main: np.ndarray) -> bool:
    """True when the coil voltage toggles so often while the main PWM is high that the
    samples cannot resolve the chopper (edges in more than 10 % of those samples)."""
    high = v_main > 0.5 * float(np.max(v_main)) if np.max(v_main) > 0 else np.zeros(
        v_main.size, bool)
    if high.sum() < 20:
        return False
    vmax = max(float(np.max(np.abs(v_coil))), 1e-3)
    lvl = np.round(v_coil / (0.2 * vmax))
    toggles = np.flatnonzero(np.diff(lvl) != 0) + 1
    return bool(np.count_nonzero(high[toggles]) > 0.1 * high.sum())


def _discard_for(drive: DriveInput, t0: float, at_rest: bool) -> tuple[float, list[str]]:
    if at_rest:
        return t0, ['assumed to start at rest (duty 0 for at least one PWM period): the '
                    'model starts at rest, every sample is compared']
    periods = drive.period_starts_s
    first = periods[periods >= t0]
    span = (DISCARD_PERIODS / drive.pwm_frequency_hz[-1]) if first.size < DISCARD_PERIODS + 1 \
        else first[DISCARD_PERIODS] - t0
    cut = t0 + max(span, DISCARD_MIN_S)
    return cut, [f'starts in motion: the model starts at rest, so the first {cut - t0:.3g} s '
                 f'(max of {DISCARD_PERIODS} PWM periods and {DISCARD_MIN_S:g} s) are left '
                 'out of the errors']


def _median_pressure(values: np.ndarray | None, name: str, default: float | None,
                     notes: list[str]) -> float | None:
    if values is None:
        return default
    ok = values[np.isfinite(values)]
    if ok.size == 0:
        return default
    med = float(np.median(ok))
    if np.ptp(ok) > 0.01 * max(abs(med), 1e3):
        notes.append(f'{name} varies {ok.min():.0f}..{ok.max():.0f} Pa; the model takes one '
                     f'pressure per run: the median {med:.0f} Pa is used')
    return med


def read_operation_csv(path: str | Path) -> Measurement:
    """Read an ``operation`` record (a valve in service) for identification.

    The model runs the drive electronics from the record's duty and frequency in force
    and ``supply_voltage_v`` (required), and is compared with the current as the record
    gives it (interval means with ``current_averaging: interval_mean``).

    Raises
    ------
    MeasurementFormatError
        Malformed file, no ``supply_voltage_v``, no supply pressure, no duty above 0.
    """
    spath = str(path)
    try:
        rec = dataformat.read_operation(path)
    except dataformat.DataFormatError as err:
        raise MeasurementFormatError(err.path, err.line, err.reason) from err
    n = rec.t_s.size
    if n < _MIN_SAMPLES:
        raise MeasurementFormatError(spath, None, f'has {n} data rows; at least '
                                     f'{_MIN_SAMPLES} are needed')
    if rec.n_missing_values > 0.5 * n:
        raise MeasurementFormatError(spath, None, f'{rec.n_missing_values} of {n} current '
                                     'values are missing')
    if rec.supply_voltage_v is None:
        raise MeasurementFormatError(spath, None, "metadata lacks 'supply_voltage_v' (the "
                                     'drive supply voltage, V): the electronics cannot be '
                                     'simulated without it')
    if not np.any(rec.duty > 0.0):
        raise MeasurementFormatError(spath, None, f'has no excitation: duty is 0 in all {n} '
                                     'samples; nothing to identify')
    notes = [x for x in rec.notes if not x.startswith('assumed to start')]
    supply = _median_pressure(rec.supply_pressure_pa, 'supply_pressure', None, notes)
    output = _median_pressure(rec.output_pressure_pa, 'output_pressure', 0.0, notes)
    drive, dnotes = drive_from_in_force(rec.t_s, rec.duty, rec.pwm_frequency_hz,
                                        rec.supply_voltage_v)
    notes += dnotes
    cut, cnotes = _discard_for(drive, float(rec.t_s[0]), rec.starts_at_rest)
    notes += cnotes
    sampling = 'interval_mean' if rec.current_averaging == 'interval_mean' else 'instant'
    notes.append(f'operation record: the model runs the drive electronics from the duty '
                 f'commands at {rec.supply_voltage_v:g} V and is compared as '
                 f'{"interval means" if sampling == "interval_mean" else "instantaneous"} '
                 'current')
    meta = dict(rec.metadata)
    if supply is not None:
        meta.setdefault('supply_pressure_pa', f'{supply:g}')
    for note in notes:
        _LOG.info('%s: %s', spath, note)
    return Measurement(
        source=spath, t_s=rec.t_s.copy(), voltage_v=drive.main_pwm_level(rec.t_s),
        current_a=rec.current_a.copy(), supply_pressure_pa=supply, output_pressure_pa=output,
        experiment='operation', metadata=meta, notes=tuple(notes),
        n_missing_values=rec.n_missing_values, n_gaps=rec.n_gaps, drive=drive,
        sampling=sampling, exclude_before_s=cut)


def hold_out(m: Measurement, fraction: float = 0.3, fit_window_s: float | None = None
             ) -> tuple[Measurement, Measurement]:
    """Split one record into a fit part and a hold-out for validation.

    The last ``fraction`` of the record (by time) is held out. The fit part is the record
    up to there (at most ``fit_window_s`` after its discarded start); the validation part
    is the whole record with everything before the hold-out left out of its errors (the
    model is simulated from t = 0 through the fit part, so the hold-out starts from the
    state the fitted model reaches).
    """
    from dataclasses import replace
    t = m.t_s
    split = float(t[0] + (1.0 - fraction) * (t[-1] - t[0]))
    end = split if fit_window_s is None else min(split, m.exclude_before_s + fit_window_s)
    keep = t <= end
    fit = replace(m, t_s=t[keep], voltage_v=m.voltage_v[keep], current_a=m.current_a[keep],
                  position_m=None if m.position_m is None else m.position_m[keep],
                  n_missing_values=int(np.count_nonzero(~np.isfinite(m.current_a[keep]))),
                  notes=m.notes + (f'fit part: {t[0]:.3g}..{end:.3g} s of the record '
                                   f'(the last {100 * fraction:.0f} % from {split:.3g} s is '
                                   'held out for validation)',),
                  held_out_from_s=split)
    val = replace(m, exclude_before_s=max(m.exclude_before_s, split), held_out_from_s=split,
                  notes=m.notes + (f'validation part: the hold-out {split:.3g}..'
                                   f'{t[-1]:.3g} s (the last {100 * fraction:.0f} %), never '
                                   'seen by the fit',))
    return fit, val
