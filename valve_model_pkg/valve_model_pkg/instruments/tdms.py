"""NI TDMS files (LabVIEW, DAQmx, FlexLogger), read with npTDMS.

Channels are named ``group/channel``; the waveform properties give the time base
(``wf_start_offset`` [s] + n x ``wf_increment`` [s]) and ``unit_string`` the unit. A file
without waveform properties needs a time channel (``--time group/channel``). npTDMS is
imported only here, when a TDMS file is read.
"""
from __future__ import annotations

from ..errors import InstrumentFormatError
from .base import Head, Loaded
from .capture import (
    MAX_SAMPLES, CaptureHeader, ChannelInfo, TimeAxis, axis_from_printed, time_unit_factor,
    unit_factor,
)

__all__ = ['TdmsReader']

_LEAD_IN = b'TDSm'
_INDEX_LEAD_IN = b'TDSh'


def _nptdms(path: str):  # noqa: ANN202 - the module
    try:
        import nptdms
    except ImportError as err:
        raise InstrumentFormatError(path, None, 'is a TDMS file; reading it needs the npTDMS '
                                    'package (pip install -r requirements/python.txt)'
                                    ) from err
    return nptdms


def _open(path: str):  # noqa: ANN202 - an nptdms.TdmsFile
    nptdms = _nptdms(path)
    try:
        return nptdms.TdmsFile.open(path)
    except (OSError, ValueError, KeyError, EOFError, RuntimeError) as err:
        raise InstrumentFormatError(path, None, f'TDMS file cannot be read (truncated or '
                                    f'corrupt): {err}') from err


class TdmsReader:
    """NI TDMS: ``group/channel`` with ``wf_increment``, ``wf_start_offset``, ``unit_string``.
    """

    key = 'tdms'
    title = 'NI TDMS'

    def sniff(self, head: Head) -> bool:
        return head.raw[:4] in (_LEAD_IN, _INDEX_LEAD_IN)

    def open(self, head: Head) -> CaptureHeader:
        path = head.path
        if head.raw[:4] == _INDEX_LEAD_IN:
            raise InstrumentFormatError(path, None, 'is a TDMS index file (.tdms_index); '
                                        'give the .tdms file it belongs to')
        channels = []
        with _open(path) as f:
            groups = f.groups()
            names = [c.name for g in groups for c in g.channels()]
            for group in groups:
                for ch in group.channels():
                    props = dict(ch.properties)
                    unit = props.get('unit_string')
                    unit = str(unit) if unit not in (None, '') else None
                    si, factor = (None, 1.0)
                    if unit is not None and unit.strip().casefold() not in ('s', 'sec'):
                        si, factor = unit_factor(path, None, unit)
                    alias = (ch.name,) if names.count(ch.name) == 1 else ()
                    stated = {k: str(v) for k, v in props.items()
                              if k in ('wf_increment', 'wf_start_offset', 'wf_samples',
                                       'wf_start_time', 'NI_ChannelName', 'unit_string')}
                    channels.append(ChannelInfo(
                        name=f'{group.name}/{ch.name}', aliases=alias, file_unit=unit,
                        si_unit=si, factor=factor, source=path, key=(group.name, ch.name),
                        stated=stated))
        if not channels:
            raise InstrumentFormatError(path, None, 'TDMS file holds no channels')
        return CaptureHeader(path=path, format=self.key, instrument='NI TDMS',
                             channels=tuple(channels), reader=self)

    def load(self, header: CaptureHeader, channels: list[ChannelInfo],
             time_channel: ChannelInfo | None = None) -> Loaded:
        path = header.path
        with _open(path) as f:
            objs = [f[c.key[0]][c.key[1]] for c in channels]
            axis = _axis(path, f, channels, objs, time_channel)
            values = {}
            for c, obj in zip(channels, objs):
                if len(obj) != axis.n:
                    raise InstrumentFormatError(path, None, f'channel {c.name!r} has '
                                                f'{len(obj)} samples, {channels[0].name!r} '
                                                f'{axis.n}: not one capture')
                values[c.name] = _read(path, c, obj) * c.factor
        return Loaded(time=axis, values=values,
                      over_range={c.name: 0 for c in channels})


def _read(path: str, c: ChannelInfo, obj: object):  # noqa: ANN202 - numpy array
    import numpy as np
    try:
        data = obj.read_data()
    except (OSError, ValueError, KeyError, EOFError, RuntimeError) as err:
        raise InstrumentFormatError(path, None, f'channel {c.name!r} cannot be read '
                                    f'(truncated or corrupt): {err}') from err
    if data.dtype.kind not in 'iuf':
        raise InstrumentFormatError(path, None, f'channel {c.name!r} holds {data.dtype} '
                                    'values; expected numbers')
    return np.asarray(data, dtype=np.float64)


def _axis(path: str, f: object, channels: list[ChannelInfo], objs: list,
          time_channel: ChannelInfo | None) -> TimeAxis:
    n = len(objs[0])
    if n > MAX_SAMPLES:
        raise InstrumentFormatError(path, None, f'channel {channels[0].name!r} has {n} samples, '
                                    f'more than {MAX_SAMPLES}; export a shorter window')
    if time_channel is not None:
        obj = f[time_channel.key[0]][time_channel.key[1]]
        unit = time_channel.file_unit or 's'
        t = _read(path, time_channel, obj) * time_unit_factor(path, None, unit)
        return axis_from_printed(path, t, 1, stated_dt_s=None, what='')
    bases = []
    for c, obj in zip(channels, objs):
        props = obj.properties
        if 'wf_increment' not in props:
            raise InstrumentFormatError(path, None, f'channel {c.name!r} has no wf_increment '
                                        'property (not a waveform); give its time channel '
                                        'with --time GROUP/CHANNEL')
        bases.append((float(props.get('wf_start_offset', 0.0)), float(props['wf_increment'])))
    t0, dt = bases[0]
    for c, (t0b, dtb) in zip(channels[1:], bases[1:]):
        if abs(dtb - dt) > 1e-9 * dt or abs(t0b - t0) > 0.5 * dt:
            raise InstrumentFormatError(path, None, f'channel {c.name!r} has wf_start_offset '
                                        f'{t0b:g} s, wf_increment {dtb:g} s; '
                                        f'{channels[0].name!r} has {t0:g} s, {dt:g} s: not '
                                        'one time base')
    if dt <= 0.0:
        raise InstrumentFormatError(path, None, f'wf_increment {dt!r} must be positive')
    return TimeAxis(n, t0, dt, how=f'wf_start_offset {t0:.9g} s + n x wf_increment '
                    f'{dt:.9g} s')
