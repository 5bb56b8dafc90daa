"""Instrument export files written from the truth model's traces, as the instruments write
them (layouts from the vendors' manuals and files seen in the wild), for the import tests.

A :class:`ScopeTrace` is what a scope saw: the truth model's coil voltage and current on
the scope's clock (file time 0 at the trigger, the voltage step; negative = pre-trigger),
with probe noise on the current. Each writer quantises the channels as its instrument's
ADC would (8-bit: 25 levels per division; 12-bit: 4096 levels over 10 divisions) and
prints them as the instrument prints them. Nothing here imports ``valve_model_pkg``.

=====================  ========================================================================
writer                 file
=====================  ========================================================================
write_tds_pair         Tektronix TDS2000-style: F0000CH1.CSV + F0000CH2.CSV, 2500 points,
                       metadata in columns 1-2, time and value in columns 4-5, CRLF
write_mso              Tektronix MSO54 CSV: header block, ``TIME,CH1,CH2``
write_rigol            Rigol DS1054Z CSV, 8-bit, current through a 100 mV/A clamp (Volt)
write_keysight         Keysight InfiniiVision ``x-axis,1,2`` / ``second,Volt,Ampere``
write_pico_csv         PicoScope CSV in ms / V / mA (or tab-separated text with a BOM)
write_pico_mat         PicoScope MATLAB file, v4 or v5 (scipy) or v7.3 (h5py, HDF5)
write_tdms             NI TDMS with waveform properties (npTDMS writer, several segments)
write_plain_csv        ``time [ms],voltage [V],current [mA]``
=====================  ========================================================================
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .truth import TruthValve, simulate_truth

__all__ = ['ScopeTrace', 'scope_trace', 'quantise', 'write_tds_pair', 'write_mso',
           'write_rigol', 'write_keysight', 'write_pico_csv', 'write_pico_mat', 'write_tdms',
           'write_plain_csv', 'WRITERS']


@dataclass(frozen=True)
class ScopeTrace:
    """The truth model's signals on a scope's clock.

    Attributes
    ----------
    t_s : numpy.ndarray, shape (n,)
        File time [s]: the step at 0, pre-trigger negative.
    voltage_v, current_a : numpy.ndarray, shape (n,)
        Coil voltage [V] (ideal steps) and current [A] (probe noise added).
    clean_current_a : numpy.ndarray, shape (n,)
        The truth model's current without noise [A].
    dt_s : float
    pre_s : float
        Pre-trigger time [s].
    """

    t_s: np.ndarray
    voltage_v: np.ndarray
    current_a: np.ndarray
    clean_current_a: np.ndarray
    dt_s: float
    pre_s: float

    def every(self, k: int) -> 'ScopeTrace':
        """Every k-th sample (a slower time base of the same capture)."""
        return ScopeTrace(self.t_s[::k], self.voltage_v[::k], self.current_a[::k],
                          self.clean_current_a[::k], self.dt_s * k, self.pre_s)


def scope_trace(valve: TruthValve | None = None, *, voltage_v: float = 24.0,
                dt_s: float = 2e-6, pre_s: float = 2e-3, on_s: float = 15e-3,
                total_s: float = 40e-3, supply_pa: float = 4e5, noise_a: float = 2e-3,
                seed: int = 1) -> ScopeTrace:
    """Simulate a voltage step on the truth model, sampled by a scope at ``dt_s``."""
    valve = valve or TruthValve()
    n = int(round(total_s / dt_s))
    t = np.arange(n) * dt_s
    segments = [(0.0, 0.0), (pre_s, voltage_v), (pre_s + on_s, 0.0)]
    tr = simulate_truth(valve, segments, t[-1], t, supply_pa)
    rng = np.random.default_rng(seed)
    noisy = tr.current_a + rng.normal(0.0, noise_a, n)
    # The scope's clock: sample k at k dt - pre (integer arithmetic, no drift).
    t_file = (np.arange(n) - int(round(pre_s / dt_s))) * dt_s
    return ScopeTrace(t_file, tr.voltage_cmd_v.copy(), noisy, tr.current_a, dt_s, pre_s)


def quantise(x: np.ndarray, lsb: float, lo: float, hi: float) -> np.ndarray:
    """An ADC: codes of ``lsb`` clipped to the screen [lo, hi]."""
    return np.clip(np.round(x / lsb) * lsb, lo, hi)


def _crlf(lines: list[str]) -> str:
    return '\r\n'.join(lines) + '\r\n'


# --- Tektronix --------------------------------------------------------------------------------
def write_tds_pair(directory: Path, tr: ScopeTrace, *, volts_per_div: float = 5.0,
                   amps_per_div: float = 0.5, model: str = 'TDS2024B'
                   ) -> tuple[Path, Path, dict[str, float]]:
    """Two TDS-style files of one 2500-point capture: CH1 voltage, CH2 current (A probe).

    Returns the two paths and the LSBs ({'voltage': V, 'current': A}).
    """
    if tr.t_s.size != 2500:
        raise ValueError(f'a TDS record has 2500 points, the trace {tr.t_s.size}')
    directory.mkdir(parents=True, exist_ok=True)
    lsbs = {'voltage': volts_per_div / 25.0, 'current': amps_per_div / 25.0}
    trig = int(np.argmin(np.abs(tr.t_s)))
    out = []
    for ch, (values, unit, scale, probe) in {
            'CH1': (tr.voltage_v, 'V', volts_per_div, 10.0),
            'CH2': (tr.current_a, 'A', amps_per_div, 1.0)}.items():
        lsb = scale / 25.0
        q = quantise(values, lsb, -4.0 * scale - 2 * lsb, 6.0 * scale)
        meta = [('Record Length', '2.500000e+03'), ('Sample Interval', f'{tr.dt_s:.6e}'),
                ('Trigger Point', f'{trig:.12e}'), ('', ''), ('', ''), ('', ''),
                ('Source', ch), ('Vertical Units', unit), ('Vertical Scale', f'{scale:.6e}'),
                ('Vertical Offset', f'{-2.0 * scale:.6e}'), ('Horizontal Units', 's'),
                ('Horizontal Scale', f'{250 * tr.dt_s:.6e}'), ('Pt Fmt', 'Y'),
                ('Yzero', '0.000000e+00'), ('Probe Atten', f'{probe:.6e}'),
                ('Model Number', model), ('Serial Number', 'C012345'),
                ('Firmware Version', 'FV:v22.11')]
        lines = []
        for k in range(tr.t_s.size):
            key, value = meta[k] if k < len(meta) else ('', '')
            lines.append(f'{key},{value},,{tr.t_s[k]:.12f},{q[k]:.5g},')
        path = directory / f'F0000{ch}.CSV'
        path.write_text(_crlf(lines), encoding='ascii', newline='')
        out.append(path)
    return out[0], out[1], lsbs


def write_mso(path: Path, tr: ScopeTrace, *, volts_per_div: float = 5.0,
              amps_per_div: float = 0.5) -> dict[str, float]:
    """A Tektronix MSO54 CSV (12-bit), CH1 voltage, CH2 current probe in A."""
    lsbs = {'voltage': 10.0 * volts_per_div / 4096, 'current': 10.0 * amps_per_div / 4096}
    v = quantise(tr.voltage_v, lsbs['voltage'], -5 * volts_per_div, 5 * volts_per_div)
    i = quantise(tr.current_a, lsbs['current'], -5 * amps_per_div, 5 * amps_per_div)
    n = tr.t_s.size
    head = ['Model,MSO54', 'Firmware Version,1.30.0.7', ',',
            'Waveform Type,ANALOG,ANALOG', 'Point Format,Y,Y', 'Horizontal Units,s,s',
            f'Horizontal Scale,{n * tr.dt_s / 10:g},{n * tr.dt_s / 10:g}',
            f'Horizontal Delay,{-tr.t_s[0] - n * tr.dt_s / 2:g},{-tr.t_s[0] - n * tr.dt_s / 2:g}',
            f'Sample Interval,{tr.dt_s:g},{tr.dt_s:g}', f'Record Length,{n},{n}',
            'Gating,0.0% to 100.0%,0.0% to 100.0%', 'Probe Attenuation,10,1',
            'Vertical Units,V,A', 'Vertical Offset,0,0',
            f'Vertical Scale,{volts_per_div:g},{amps_per_div:g}',
            'Vertical Position,-3,-3', ',', 'Label,,', 'TIME,CH1,CH2']
    rows = [f'{tr.t_s[k]:.6e},{v[k]:.6g},{i[k]:.6g}' for k in range(n)]
    path.write_text(_crlf(head + rows), encoding='ascii', newline='')
    return lsbs


# --- Rigol, Keysight --------------------------------------------------------------------------
def write_rigol(path: Path, tr: ScopeTrace, *, current_lsb_a: float = 0.016,
                clamp_v_per_a: float = 0.1, volts_per_div: float = 5.0) -> dict[str, float]:
    """A Rigol DS1054Z CSV, 8-bit: CH1 the voltage, CH2 a current clamp's output (Volt).

    The clamp gives ``clamp_v_per_a`` volts per ampere; the vertical scale is chosen so the
    current's LSB is ``current_lsb_a``. Values print with three significant digits.
    """
    ch2_lsb_v = current_lsb_a * clamp_v_per_a
    # 0 V two divisions above the bottom of the 8-division screen.
    v = quantise(tr.voltage_v, volts_per_div / 25.0, -2 * volts_per_div, 6 * volts_per_div)
    i = quantise(tr.current_a * clamp_v_per_a, ch2_lsb_v, -100 * ch2_lsb_v, 156 * ch2_lsb_v)
    head = ['X,CH1,CH2,Start,Increment,',
            f'Sequence,Volt,Volt,{tr.t_s[0]:.6e},{tr.dt_s:.6e}']
    rows = [f'{k},{v[k]:.2e},{i[k]:.2e},' for k in range(tr.t_s.size)]
    path.write_text(_crlf(head + rows), encoding='ascii', newline='')
    return {'voltage': volts_per_div / 25.0, 'current': current_lsb_a}


def _eng(x: float) -> str:
    """Engineering notation as InfiniiVision prints times: -995.000E-06, +1.000000E-03."""
    if x == 0.0:
        return '+0.0E+00'
    e = int(math.floor(math.log10(abs(x)) / 3.0) * 3)
    return f'{x / 10.0 ** e:+.6f}E{e:+03d}'.replace('+-', '-')


def write_keysight(path: Path, tr: ScopeTrace, *, volts_per_div: float = 5.0,
                   amps_per_div: float = 0.5) -> dict[str, float]:
    """A Keysight InfiniiVision CSV (8-bit): channel 1 in Volt, channel 2 in Ampere."""
    lsbs = {'voltage': volts_per_div / 32.0, 'current': amps_per_div / 32.0}
    v = quantise(tr.voltage_v, lsbs['voltage'], -2 * volts_per_div, 6 * volts_per_div)
    i = quantise(tr.current_a, lsbs['current'], -2 * amps_per_div, 6 * amps_per_div)
    rows = [f'{_eng(tr.t_s[k])},{v[k]:+.6E},{i[k]:+.6E}' for k in range(tr.t_s.size)]
    path.write_text('\n'.join(['x-axis,1,2', 'second,Volt,Ampere'] + rows) + '\n',
                    encoding='ascii')
    return lsbs


# --- PicoScope --------------------------------------------------------------------------------
def write_pico_csv(path: Path, tr: ScopeTrace, *, tab: bool = False,
                   over_range_at: int | None = None) -> dict[str, float]:
    """PicoScope CSV (or tab text with a BOM): time in ms, A in V (+-50 V), B in mA (+-2 A),
    12-bit.

    ``over_range_at``: a current sample written as the infinity sign (over range).
    """
    lsbs = {'voltage': 100.0 / 4096, 'current': 4.0 / 4096}
    v = quantise(tr.voltage_v, lsbs['voltage'], -50.0, 50.0)
    i = quantise(tr.current_a, lsbs['current'], -2.0, 2.0) * 1e3
    sep = '\t' if tab else ','
    rows = []
    for k in range(tr.t_s.size):
        cur = '\u221e' if k == over_range_at else f'{i[k]:.8f}'
        rows.append(f'{tr.t_s[k] * 1e3:.8f}{sep}{v[k]:.8f}{sep}{cur}')
    text = '\r\n'.join([sep.join(['Time', 'Channel A', 'Channel B']),
                        sep.join(['(ms)', '(V)', '(mA)']), ''] + rows) + '\r\n'
    path.write_text(('\ufeff' if tab else '') + text, encoding='utf-8', newline='')
    return lsbs


def write_pico_mat(path: Path, tr: ScopeTrace, *, version: str = '5') -> dict[str, float]:
    """PicoScope MATLAB export: Tstart, Tinterval, Length, A (V), B (A probe), float32.

    ``version``: ``'4'`` and ``'5'`` written by scipy, ``'7.3'`` by h5py as MATLAB does
    (512-byte header block, then HDF5; column vectors stored as (1, n) datasets).
    """
    lsbs = {'voltage': 100.0 / 65536, 'current': 4.0 / 65536}
    a = quantise(tr.voltage_v, lsbs['voltage'], -50.0, 50.0).astype(np.float32)
    b = quantise(tr.current_a, lsbs['current'], -2.0, 2.0).astype(np.float32)
    variables = {'Tstart': float(tr.t_s[0]), 'Tinterval': float(tr.dt_s),
                 'Length': float(tr.t_s.size), 'ExtraSamples': 0.0,
                 'RequestedLength': float(tr.t_s.size), 'A': a.reshape(-1, 1),
                 'B': b.reshape(-1, 1)}
    if version in ('4', '5'):
        import scipy.io
        scipy.io.savemat(path, {k: np.atleast_2d(v) if np.isscalar(v) else v
                                for k, v in variables.items()}, format=version)
        return lsbs
    if version != '7.3':
        raise ValueError(f'MAT version {version!r}')
    import h5py
    with h5py.File(path, 'w', userblock_size=512) as f:
        for name, value in variables.items():
            arr = np.atleast_2d(np.asarray(value))
            data = f.create_dataset(name, data=arr.T)
            data.attrs['MATLAB_class'] = np.bytes_('single' if arr.dtype == np.float32
                                                   else 'double')
    header = ('MATLAB 7.3 MAT-file, Platform: PCWIN64, Created on: Mon Jan  6 10:00:00 2025 '
              'HDF5 schema 1.00 .').ljust(116).encode('ascii')
    with open(path, 'r+b') as fh:
        fh.write(header + b'\x00' * 8 + b'\x00\x02' + b'IM')
    return lsbs


# --- NI TDMS, plain CSV -----------------------------------------------------------------------
def write_tdms(path: Path, tr: ScopeTrace, *, segment: int = 100_000,
               group: str = 'Measurement', spare_group: str | None = None
               ) -> dict[str, float]:
    """A TDMS file as a DAQ writes it: one group, voltage and current channels with
    ``wf_start_offset``, ``wf_increment``, ``unit_string`` (16-bit, +-30 V / +-5 A).

    ``spare_group``: a second group with a channel of the same name (``Coil current``).
    """
    from nptdms import ChannelObject, GroupObject, RootObject, TdmsWriter
    lsbs = {'voltage': 60.0 / 65536, 'current': 10.0 / 65536}
    v = quantise(tr.voltage_v, lsbs['voltage'], -30.0, 30.0)
    i = quantise(tr.current_a, lsbs['current'], -5.0, 5.0)
    props = {'wf_start_offset': float(tr.t_s[0]), 'wf_increment': float(tr.dt_s),
             'wf_samples': int(tr.t_s.size),
             'wf_start_time': np.datetime64('2025-01-06T10:00:00')}
    with TdmsWriter(str(path)) as writer:
        for a in range(0, tr.t_s.size, segment):
            b = min(a + segment, tr.t_s.size)
            objects = [] if a else [RootObject({'name': 'bench'}),
                                    GroupObject(group, {})]
            writer.write_segment(objects + [
                ChannelObject(group, 'Coil voltage', v[a:b],
                              {**props, 'unit_string': 'V'} if not a else {}),
                ChannelObject(group, 'Coil current', i[a:b],
                              {**props, 'unit_string': 'A'} if not a else {})])
        if spare_group is not None:
            writer.write_segment([ChannelObject(spare_group, 'Coil current',
                                                np.zeros(tr.t_s.size),
                                                {**props, 'unit_string': 'A'})])
    return lsbs


def write_plain_csv(path: Path, tr: ScopeTrace) -> dict[str, float]:
    """A logger's CSV: ``time [ms],voltage [V],current [mA]``, full precision."""
    rows = [f'{tr.t_s[k] * 1e3:.9g},{tr.voltage_v[k]:.9g},{tr.current_a[k] * 1e3:.9g}'
            for k in range(tr.t_s.size)]
    path.write_text('\n'.join(['time [ms],voltage [V],current [mA]'] + rows) + '\n',
                    encoding='utf-8')
    return {'voltage': 0.0, 'current': 0.0}


#: Format key -> (writer, sample step on a 2 us base trace, voltage channel, current
#: channel, extra valve_import options).
WRITERS = {
    'tektronix-mso': (write_mso, 1, 'CH1', 'ch2', []),
    'rigol': (write_rigol, 5, 'CH1', 'CH2', ['--current-scale', '10']),
    'keysight': (write_keysight, 2, '1', '2', []),
    'picoscope-csv': (write_pico_csv, 4, 'Channel A', 'B', []),
    'picoscope-mat': (write_pico_mat, 1, 'A', 'B', []),
    'tdms': (write_tdms, 5, 'Measurement/Coil voltage', 'coil current', []),
    'plain-csv': (write_plain_csv, 10, 'voltage', 'current [mA]', []),
}
