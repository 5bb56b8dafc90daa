"""Measured valve data: CSV files and rosbag2 bags into one in-memory form.

Two sources feed the identification:

* bench CSV files of the measured-data format (``shared/measured-data-format.md`` of the
  steering repository), read by :mod:`valve_model_pkg.dataformat`: metadata lines
  ``# key: value``, one header row, one row per sample, SI units, gauge pressures;
* rosbag2 bags recorded from the suite (``valve_msgs/msg/ValveState`` on ``/valve/state``).

Both end up as a :class:`Measurement`. Malformed input is refused with a
:class:`~valve_model_pkg.identification.errors.MeasurementFormatError` naming the file, the
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
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterable, Sequence

import numpy as np

from valve_model_pkg import dataformat
from valve_model_pkg.interface import TOPIC_STATE

from .errors import MeasurementFormatError

__all__ = [
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
#: A coil voltage at or below this everywhere counts as no excitation [V].
_MIN_EXCITATION_V = 1e-3


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
        """Boolean mask of samples with a measured current, shape (n,)."""
        return np.isfinite(self.current_a)

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
        return Measurement(
            source=self.source if source is None else source, t_s=self.t_s,
            voltage_v=self.voltage_v, current_a=cur,
            supply_pressure_pa=self.supply_pressure_pa,
            output_pressure_pa=self.output_pressure_pa, experiment=self.experiment,
            position_m=self.position_m, metadata=dict(self.metadata), notes=self.notes,
            n_missing_values=int(np.count_nonzero(~np.isfinite(cur))), n_gaps=self.n_gaps)

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
        key and the value), is a ``flow_map`` or ``operation`` record, has fewer than 10
        rows, lacks more than half of its current values, or is a ``pwm`` record without
        ``coil_voltage``.

    Notes
    -----
    The format's rules are applied by :func:`valve_model_pkg.dataformat.read_trace`: a
    current field that is empty or ``nan`` is a missing sample, kept as ``nan``, counted
    in ``n_missing_values`` and listed in ``notes``; every other field must be a finite
    number. Identification of ``operation`` records (drive electronics in the loop) is not
    implemented yet; they are refused with a message saying so.
    """
    spath = str(path)
    try:
        record = dataformat.read_record(path)
        if record.kind == 'flow_map':
            dataformat.read_trace(path)  # raises the format's own 'is a flow_map' refusal
    except dataformat.DataFormatError as err:
        raise MeasurementFormatError(err.path, err.line, err.reason) from err
    if record.kind == 'operation':
        raise MeasurementFormatError(
            spath, None, 'is an operation record; identification from operation records '
            '(drive electronics in the loop) is not implemented yet: give step or pwm '
            'records with the coil voltage')
    n_rows = record.t_s.size
    if n_rows < _MIN_SAMPLES:
        raise MeasurementFormatError(
            spath, None, f'has {n_rows} data rows; at least {_MIN_SAMPLES} are needed')
    if record.n_missing_values > 0.5 * n_rows:
        raise MeasurementFormatError(
            spath, None, f'{record.n_missing_values} of {n_rows} current values are missing')
    voltage = record.voltage_v
    notes = list(record.notes)
    if record.experiment == 'pwm':
        # A pwm record's 'voltage' is the main PWM input to the drive electronics; the
        # coil model needs the voltage at the coil terminals.
        if record.coil_voltage_v is None:
            raise MeasurementFormatError(
                spath, None, 'is a pwm record without a coil_voltage column; identification '
                'through the drive electronics is not implemented yet: record coil_voltage')
        bad = np.flatnonzero(~np.isfinite(record.coil_voltage_v))
        if bad.size:
            raise MeasurementFormatError(
                spath, int(record.line_numbers[bad[0]]),
                "column 'coil_voltage' has no value (the model is driven by it)")
        voltage = record.coil_voltage_v
        notes.append('pwm record: the coil model is driven by the coil_voltage column')
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
        n_missing_values=record.n_missing_values, n_gaps=record.n_gaps)


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
                            msg.output_pressure, msg.pwm_frequency, msg.duty))
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
    _check_time_axis(spath, t, None)
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
