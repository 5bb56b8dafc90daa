"""Instrument exports (oscilloscopes, DAQ) into records of the measured-data format.

ROS-free (numpy, scipy; h5py for MATLAB v7.3 files and npTDMS for TDMS files, imported
only when such a file is read). One module per format family:

================  ======================================================================
module            formats
================  ======================================================================
:mod:`.tektronix` Tektronix TDS-style CSV (one file per channel), MSO 4/5/6 series CSV
:mod:`.rigol`     Rigol CSV (``X,CH1,...,Start,Increment,``)
:mod:`.keysight`  Keysight InfiniiVision CSV (``x-axis,1,2`` / ``second,Volt,Volt``)
:mod:`.picoscope` PicoScope CSV/text (``(ms),(V),(mA)`` units row), MATLAB v4/v5/v7.3
:mod:`.tdms`      NI TDMS (``group/channel``, ``wf_increment``, ``unit_string``)
:mod:`.plain`     plain CSV with a header row (``current [mA]``)
================  ======================================================================

:mod:`.detect` tells the format from the content (never the file name) and reads the
chosen channels into a :class:`~.capture.Capture`; :mod:`.record` turns it into a record
(units, probe factors, window, step, decimation, the header); :mod:`.options` holds the
command-line options ``valve_import`` and ``valve_identify`` share and their entries
:func:`import_export` and :func:`records_for`. Refusals are
:class:`~valve_model_pkg.errors.InstrumentFormatError`: one line naming the file, the row
and what was expected.
"""
from __future__ import annotations

from .capture import Capture, CaptureHeader, ChannelInfo, TimeAxis, infer_lsb
from .detect import READERS, open_export, read_capture
from .options import (
    add_import_options, group_captures, import_export, options_from_args, records_for,
)
from .record import ImportedRecord, ImportOptions, build_record, write_record

__all__ = [
    'Capture', 'CaptureHeader', 'ChannelInfo', 'TimeAxis', 'infer_lsb', 'READERS',
    'open_export', 'read_capture', 'add_import_options', 'group_captures', 'import_export',
    'options_from_args', 'records_for', 'ImportedRecord', 'ImportOptions', 'build_record',
    'write_record',
]
