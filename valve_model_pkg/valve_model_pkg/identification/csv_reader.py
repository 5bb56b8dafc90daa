"""CSV records of the measured-data format read for identification, and traces written.

The format (``shared/measured-data-format.md`` of the steering repository: metadata lines
``# key: value``, one header row, one row per sample, SI units, gauge pressures) is read by
:mod:`valve_model_pkg.dataformat`; this module turns its records into
:class:`~.measurement.Measurement` objects: a ``step`` record drives the bare coil with
its voltage column; a ``pwm`` record drives it with its ``coil_voltage`` column or, when
that does not resolve the chopper, runs the drive electronics from the main PWM column;
an ``operation`` record runs the electronics from the duty and frequency in force.
Malformed input is refused with a :class:`~valve_model_pkg.errors.MeasurementFormatError`
naming the file, the line and the reason.
"""
from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from valve_model_pkg import dataformat

from ..errors import MeasurementFormatError
from .measurement import (MIN_SAMPLES, DriveInput, Measurement, check_excitation,
                          mean_voltage_column, median_pressure)
from .pwm_grid import discard_for, drive_from_in_force, drive_from_main_pwm

__all__ = ['read_csv', 'read_operation_csv', 'write_csv']

_LOG = logging.getLogger(__name__)

#: Largest current of a bare coil after a long on-phase, as a fraction of V / R_max: a
#: lower plateau means a current chopper holds it (R_max = 22.5 ohm, the search bound).
_BARE_COIL_R_MAX_OHM = 22.5
#: Shortest on-phase of a pwm record's coil voltage searched for a held plateau [s]: a bare
#: coil (tau = L / R, about 11 ms) still rises by 5 % of its level within the last fifth of
#: 4 ms; a chopper holds it flat.
_PWM_MIN_ON_S = 4e-3


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
    if n_rows < MIN_SAMPLES:
        raise MeasurementFormatError(
            spath, None, f'has {n_rows} data rows; at least {MIN_SAMPLES} are needed')
    if record.n_missing_values > 0.5 * n_rows:
        raise MeasurementFormatError(
            spath, None, f'{record.n_missing_values} of {n_rows} current values are missing')
    voltage = record.voltage_v
    notes = list(record.notes)
    drive = None
    sampling = ('interval_mean' if record.metadata.get('current_averaging') == 'interval_mean'
                else 'instant')
    if record.experiment == 'pwm':
        voltage, drive = _pwm_input(spath, record, notes)
    elif record.experiment in ('step', 'unknown'):
        _refuse_pwm_in_step(spath, record.t_s, voltage, record.current_a)
    check_excitation(spath, voltage, record.line_numbers)
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


def _pwm_input(spath: str, record: dataformat.TraceRecord, notes: list[str]
               ) -> tuple[np.ndarray, DriveInput | None]:
    """What drives the model for a ``pwm`` record: (coil voltage, None) for the bare coil,
    or (main PWM voltage, its commands) for the drive electronics; notes appended.

    A pwm record's ``voltage`` is the main PWM input to the drive electronics. With a
    ``coil_voltage`` column that resolves the chopper, the bare coil is driven by it;
    otherwise the model runs the drive electronics from the main PWM.
    """
    voltage = record.voltage_v
    coil = record.coil_voltage_v
    use_coil = coil is not None and bool(np.all(np.isfinite(coil)))
    if use_coil and _chopper_unresolved(coil, voltage):
        use_coil = False
        notes.append('coil_voltage toggles faster than its samples resolve (the 20 kHz '
                     'current chopper): not used as a bare-coil input; the model runs '
                     'the drive electronics from the main PWM column instead')
    elif use_coil and _held_plateau(record.t_s, coil, record.current_a,
                                    _PWM_MIN_ON_S) is not None:
        use_coil = False
        level, volts = _held_plateau(record.t_s, coil, record.current_a, _PWM_MIN_ON_S)
        notes.append(f'coil_voltage stays at {volts:.3g} V while the current holds '
                     f'{level:.3g} A: its samples miss the chopper (sampled in step with '
                     'it), so it is not used as a bare-coil input; the model runs the drive '
                     'electronics from the main PWM column instead')
    elif coil is not None and not use_coil:
        notes.append('coil_voltage has missing values: not used; the model runs the '
                     'drive electronics from the main PWM column')
    if use_coil:
        notes.append('pwm record: the bare coil model is driven by the measured '
                     'coil_voltage column (chopper and release pulse included)')
        return coil, None
    check_excitation(spath, voltage, record.line_numbers)
    meta_v = record.metadata.get('supply_voltage_v')
    supply_v = float(meta_v) if meta_v else float(np.max(voltage))
    if not meta_v:
        notes.append(f'no supply_voltage_v: the drive supply is taken as the main '
                     f'PWM high level, {supply_v:.3g} V')
    freq = record.metadata.get('pwm_frequency_hz')
    drive = drive_from_main_pwm(record.t_s, voltage, supply_v, float(freq) if freq else None)
    notes.append(f'pwm record: the model runs the drive electronics (boost, current '
                 f'chopper, release pulse) from the main PWM column at {supply_v:.3g} '
                 'V supply')
    return voltage, drive


def read_operation_csv(path: str | Path) -> Measurement:
    """Read an ``operation`` record (a valve in service) for identification.

    The model runs the drive electronics from the record's duty and frequency in force
    and ``supply_voltage_v`` (required), and is compared with the current as the record
    gives it (interval means with ``current_averaging: interval_mean``). A
    ``coil_voltage_mean`` column is kept as ``coil_voltage_mean_v`` (missing values as
    ``nan``): the identification then fits the valve around the electronics
    (:mod:`.mean_voltage`).

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
    if n < MIN_SAMPLES:
        raise MeasurementFormatError(spath, None, f'has {n} data rows; at least '
                                     f'{MIN_SAMPLES} are needed')
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
    supply = median_pressure(rec.supply_pressure_pa, 'supply_pressure', None, notes)
    output = median_pressure(rec.output_pressure_pa, 'output_pressure', 0.0, notes)
    drive, dnotes = drive_from_in_force(rec.t_s, rec.duty, rec.pwm_frequency_hz,
                                        rec.supply_voltage_v)
    notes += dnotes
    cut, cnotes = discard_for(drive, float(rec.t_s[0]), rec.starts_at_rest)
    notes += cnotes
    sampling = 'interval_mean' if rec.current_averaging == 'interval_mean' else 'instant'
    notes.append(f'operation record: the model runs the drive electronics from the duty '
                 f'commands at {rec.supply_voltage_v:g} V and is compared as '
                 f'{"interval means" if sampling == "interval_mean" else "instantaneous"} '
                 'current')
    v_mean = None
    if rec.coil_voltage_mean_v is not None:
        # missing values were noted by the format reader
        v_mean = mean_voltage_column(rec.coil_voltage_mean_v, 'coil_voltage_mean', [])
        notes.append('the record carries coil_voltage_mean (mean coil voltage over each '
                     'current interval)')
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
        sampling=sampling, exclude_before_s=cut, coil_voltage_mean_v=v_mean)


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
    held = _held_plateau(t, v, i)
    if held is not None:
        level, volts = held
        raise MeasurementFormatError(
            spath, None, f"experiment is 'step' (bare coil) but the current holds "
            f'{level:.3g} A at {volts:.3g} V: a bare coil would need R > {volts / level:.0f} '
            "ohm. A current chopper (the drive electronics) is in the loop: record it as "
            "'pwm' or 'operation'")


def _held_plateau(t: np.ndarray, v: np.ndarray, i: np.ndarray, min_on_s: float = 8e-3
                  ) -> tuple[float, float] | None:
    """``(current [A], voltage [V])`` of a flat current plateau at the end of an on-phase
    of ``v`` at least ``min_on_s`` long [s], well below what a bare coil reaches (0.55 V /
    22.5 ohm; zero current is no plateau): a current chopper the voltage column does not
    show; else None."""
    vmax = float(np.max(np.abs(v)))
    if vmax <= 0.0:
        return None
    on = np.abs(v) > 0.5 * vmax
    # long on-phases: a bare coil's current keeps rising towards V/R; a chopper holds it low
    edges = np.flatnonzero(np.diff(on.astype(int))) + 1
    bounds = np.concatenate(([0], edges, [on.size]))
    for a, b in zip(bounds[:-1], bounds[1:]):
        if not on[a] or t[b - 1] - t[a] < min_on_s:
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
            return level, volts
    return None


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
