"""The fleet table: one row a valve, written as ``fleet.csv`` and ``fleet.parquet``.

Columns, in order (units in the names; SI parameters with the names of ValveParameters):

``valve_id``, ``status`` (``ok`` / ``failed``), ``reason`` (why it failed),
``effect``, ``confidence``, ``unexplained_structure`` (the diagnosis), the errors of the
final (augmented) model ``fit_rmse_a``, ``fit_nrmse_pct``, ``fit_iae_a_s``,
``validation_rmse_a``, ``validation_nrmse_pct``, ``validation_iae_a_s`` and of the
baseline model ``baseline_fit_rmse_a``, ``baseline_validation_rmse_a``; then for every
parameter ``P`` of the report: ``P`` (the final model's value), ``P_ci95_low``,
``P_ci95_high`` (the report's local 95 % interval, empty where the data do not pin it
down), and for the parameters the outlier rule looks at, ``P_z`` (robust z-score); then
``outlier`` (``yes`` / ``no`` / ``cannot tell``), ``outlier_reason``, ``duration_s``,
``fit_files``, ``validation_files`` (``;``-separated) and ``output`` (the valve's folder
relative to DIR).
"""
from __future__ import annotations

import csv
import math
import os
from pathlib import Path
from typing import Any, Sequence

from .manifest import ValveJob
from .outliers import MIN_VALVES, THRESHOLD, flag_outliers

__all__ = ['HEAD_COLUMNS', 'fleet_rows', 'valve_row', 'failed_row', 'write_table',
           'outlier_parameters']

HEAD_COLUMNS = ('valve_id', 'status', 'reason', 'effect', 'confidence',
                'unexplained_structure', 'fit_rmse_a', 'fit_nrmse_pct', 'fit_iae_a_s',
                'validation_rmse_a', 'validation_nrmse_pct', 'validation_iae_a_s',
                'baseline_fit_rmse_a', 'baseline_validation_rmse_a')
TAIL_COLUMNS = ('outlier', 'outlier_reason', 'duration_s', 'fit_files', 'validation_files',
                'output')
_STRING_COLUMNS = {'valve_id', 'status', 'reason', 'effect', 'confidence', 'outlier',
                   'outlier_reason', 'fit_files', 'validation_files', 'output'}
_BOOL_COLUMNS = {'unexplained_structure'}
#: the baseline search's parameters: the outlier rule's default when no report names them
_DEFAULT_OUTLIER_PARAMETERS = ('coil_resistance_ohm', 'stroke_m', 'core_area_m2',
                               'spring_pretension_m', 'damping_n_s_per_m',
                               'equivalent_gap_m')


def _num(x: Any) -> float:
    return float(x) if isinstance(x, (int, float)) and not isinstance(x, bool) else math.nan


def _errors(block: dict[str, Any] | None, key: str) -> float:
    return _num(block.get(key)) if isinstance(block, dict) else math.nan


def valve_row(job: ValveJob, report: dict[str, Any], duration_s: float) -> dict[str, Any]:
    """The table row of a finished valve, from its report.json content."""
    aug, base = report['augmented'], report['baseline']
    diag = report.get('diagnosis') or {}
    row: dict[str, Any] = {
        'valve_id': job.valve_id, 'status': 'ok', 'reason': '',
        'effect': diag.get('effect', ''), 'confidence': diag.get('confidence', ''),
        'unexplained_structure': diag.get('unexplained_structure'),
        'fit_rmse_a': _errors(aug.get('fit'), 'rmse'),
        'fit_nrmse_pct': _errors(aug.get('fit'), 'nrmse_pct'),
        'fit_iae_a_s': _errors(aug.get('fit'), 'iae'),
        'validation_rmse_a': _errors(aug.get('validation'), 'rmse'),
        'validation_nrmse_pct': _errors(aug.get('validation'), 'nrmse_pct'),
        'validation_iae_a_s': _errors(aug.get('validation'), 'iae'),
        'baseline_fit_rmse_a': _errors(base.get('fit'), 'rmse'),
        'baseline_validation_rmse_a': _errors(base.get('validation'), 'rmse'),
    }
    ci = ((aug.get('sensitivity') or {}).get('ci95_pct') or {})
    for name, value in (aug.get('parameters') or {}).items():
        v = _num(value)
        half = _num(ci.get(name))
        row[name] = v
        row[f'{name}_ci95_low'] = v * (1.0 - half / 100.0) if math.isfinite(half) else math.nan
        row[f'{name}_ci95_high'] = v * (1.0 + half / 100.0) if math.isfinite(half) else math.nan
    row['_searched'] = list((report.get('search_bounds') or {}).keys())
    _tail(row, job, duration_s)
    return row


def failed_row(job: ValveJob, reason: str, duration_s: float) -> dict[str, Any]:
    """The table row of a valve whose identification failed (or did not run)."""
    row: dict[str, Any] = {'valve_id': job.valve_id, 'status': 'failed', 'reason': reason}
    _tail(row, job, duration_s)
    row['output'] = ''
    return row


def _tail(row: dict[str, Any], job: ValveJob, duration_s: float) -> None:
    row['duration_s'] = float(duration_s)
    row['fit_files'] = ';'.join(job.fit)
    row['validation_files'] = ';'.join(job.validate)
    row['output'] = f'valves/{job.valve_id}'


def outlier_parameters(rows: Sequence[dict[str, Any]]) -> list[str]:
    """Parameters the outlier rule looks at: those the identification searched."""
    names: list[str] = []
    for row in rows:
        for name in row.get('_searched', []):
            if name not in names and name in row:
                names.append(name)
    return names or [n for n in _DEFAULT_OUTLIER_PARAMETERS
                     if any(n in r for r in rows)]


def fleet_rows(rows: list[dict[str, Any]], *, threshold: float = THRESHOLD,
               min_valves: int = MIN_VALVES) -> list[dict[str, Any]]:
    """Add the outlier columns (``P_z``, ``outlier``, ``outlier_reason``) to the rows.

    Only valves with status ``ok`` enter the fleet's statistics; a parameter without an
    interval in a valve's report (not pinned down by its data) is counted in the median but
    does not flag that valve.
    """
    names = outlier_parameters(rows)
    ok = [r for r in rows if r['status'] == 'ok']
    values = {n: [_num(r.get(n)) for r in ok] for n in names}
    usable = {n: [math.isfinite(_num(r.get(f'{n}_ci95_low'))) for r in ok] for n in names}
    verdicts = flag_outliers(values, usable=usable, threshold=threshold,
                             min_valves=min_valves) if names and ok else []
    for r, v in zip(ok, verdicts):
        for n in names:
            r[f'{n}_z'] = v.z.get(n, math.nan)
        r['outlier'], r['outlier_reason'] = v.flag, v.reason
    for r in rows:
        r.pop('_searched', None)
        if r['status'] != 'ok':
            r['outlier'], r['outlier_reason'] = '', ''
    return rows


def _columns(rows: Sequence[dict[str, Any]]) -> list[str]:
    middle: list[str] = []
    fixed = set(HEAD_COLUMNS) | set(TAIL_COLUMNS)
    for row in rows:
        for key in row:
            if key not in fixed and key not in middle:
                middle.append(key)
    # Each parameter with its interval and z side by side.
    params = [k for k in middle if not k.endswith(('_ci95_low', '_ci95_high', '_z'))]
    ordered: list[str] = []
    for p in params:
        ordered += [c for c in (p, f'{p}_ci95_low', f'{p}_ci95_high', f'{p}_z')
                    if c in middle]
    ordered += [c for c in middle if c not in ordered]
    return list(HEAD_COLUMNS) + ordered + list(TAIL_COLUMNS)


def _csv_cell(value: Any) -> str:
    if value is None:
        return ''
    if isinstance(value, bool):
        return 'true' if value else 'false'
    if isinstance(value, float):
        return repr(value) if math.isfinite(value) else ''
    return str(value)


def write_table(rows: Sequence[dict[str, Any]], out_dir: str | Path, *,
                parquet: bool = True) -> list[Path]:
    """Write ``fleet.csv`` (and ``fleet.parquet``) into ``out_dir``, each atomically.

    Returns
    -------
    list of pathlib.Path
        The files written.

    Raises
    ------
    ImportError
        ``parquet`` asked for and pyarrow not installed (fleet.csv is written first).
    """
    out = Path(out_dir)
    cols = _columns(rows)
    written = []
    tmp = out / f'.fleet.csv.tmp-{os.getpid()}'
    with open(tmp, 'w', newline='', encoding='utf-8') as fh:
        w = csv.writer(fh)
        w.writerow(cols)
        for r in rows:
            w.writerow([_csv_cell(r.get(c)) for c in cols])
    os.replace(tmp, out / 'fleet.csv')
    written.append(out / 'fleet.csv')
    if parquet:
        import pyarrow as pa
        import pyarrow.parquet as pq

        fields, arrays = [], []
        for c in cols:
            vals = [r.get(c) for r in rows]
            if c in _STRING_COLUMNS:
                typ = pa.string()
                vals = [None if v is None else str(v) for v in vals]
            elif c in _BOOL_COLUMNS:
                typ = pa.bool_()
                vals = [v if isinstance(v, bool) else None for v in vals]
            else:
                typ = pa.float64()
                vals = [v if isinstance(v, float) and math.isfinite(v) else
                        (float(v) if isinstance(v, int) and not isinstance(v, bool) else None)
                        for v in vals]
            fields.append(pa.field(c, typ))
            arrays.append(pa.array(vals, type=typ))
        table = pa.Table.from_arrays(arrays, schema=pa.schema(fields))
        tmp = out / f'.fleet.parquet.tmp-{os.getpid()}'
        pq.write_table(table, tmp)
        os.replace(tmp, out / 'fleet.parquet')
        written.append(out / 'fleet.parquet')
    return written
