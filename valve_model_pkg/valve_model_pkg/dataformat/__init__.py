"""The measured-data format: bench and operational records of a valve as CSV.

The format is defined in *the measured-data format* document
(``shared/measured-data-format.md`` of the steering repository). This package is its one
reader and writer (ROS-free: numpy and the standard library): every tool that reads or
writes such files (``valve_simulate``, ``valve_identify``, ``valve_flow_check``, the test
data generator's checks) goes through :mod:`.csv_format`, so the rules are the same
everywhere.

- :func:`read_record` reads any kind and returns a typed record: :class:`TraceRecord`
  (``step``, ``pwm``), :class:`OperationRecord` (``operation``) or :class:`FlowMapRecord`
  (``flow_map``); :func:`read_trace`, :func:`read_operation` and :func:`read_flow_map`
  read one kind and refuse the others.
- :func:`write_table` writes any kind from metadata and named columns;
  :func:`write_record` writes a record read before.
- :class:`DataFormatError` names the file, the line, the key and the value.
"""
from __future__ import annotations

from .csv_format import (
    EXPERIMENTS, FORMAT_NAME, MAX_ABS_CURRENT_A, MAX_COLUMNS, MAX_FILE_BYTES, MAX_LINE_CHARS,
    MAX_ROWS, DataFormatError, FlowMapRecord, OperationRecord, TraceRecord,
    check_time_axis, read_flow_map, read_operation, read_record, read_trace, write_record,
    write_table,
)

__all__ = [
    'EXPERIMENTS', 'FORMAT_NAME', 'MAX_ABS_CURRENT_A', 'MAX_COLUMNS', 'MAX_FILE_BYTES',
    'MAX_LINE_CHARS', 'MAX_ROWS', 'DataFormatError', 'FlowMapRecord', 'OperationRecord',
    'TraceRecord', 'check_time_axis', 'read_flow_map', 'read_operation', 'read_record',
    'read_trace', 'write_record', 'write_table',
]
