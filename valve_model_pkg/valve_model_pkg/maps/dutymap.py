"""The static duty map and its versioned file format.

A :class:`DutyMap` holds, for a grid of PWM frequencies and supply pressures, the curve
x_avg / x_max against duty at periodic steady state (Section 5, Figs. 8 and 9 of the paper),
together with everything needed to know what it is valid for: the full valve parameter set
and its SHA-256 hash, the drive electronics, the supply voltage, the output pressure and the
steady-state criterion it was generated with.

File format (JSON, UTF-8), ``format = "valve_suite/duty_map"``, ``format_version = 1``::

    {
      "format": "valve_suite/duty_map", "format_version": 1,
      "created_utc": "...", "generator": {...}, "notes": [...],
      "parameters_sha256": "<sha256 of the canonical JSON of 'parameters'>",
      "parameters": {"valve": {...}, "orifice": {...}, "effects": {...}},
      "electronics": {...}, "supply_voltage_v": 24.0, "output_pressure_pa": 0.0,
      "steady_state": {...}, "stop_tolerance": 1e-06, "refinement": {...},
      "units": {...},
      "grid": {"duty": [0.0, 0.01, ...], "supply_pressure_pa": [...],
               "pwm_frequency_hz": [...]},
      "curves": [
        {"pwm_frequency_hz": 50.0, "supply_pressure_pa": 400000.0,
         "position_fraction": [...], "periods": [...], "unconverged_duties": [...],
         "subharmonic_cycles": [[duty, periods per cycle], ...],
         "features": {"dead_band_duty": ..., "opening_duty": ..., "saturation_duty": ...,
                      "effective_width": ..., "max_decrease": ...},
         "dead_band_edge": ... or null, "saturation_edge": ... or null,
         "extra_points": [[duty, fraction], ...],  (off-grid steady points)
         "jumps": [[d_a, x_a, d_b, x_b], ...]},     (informational, recomputed on reading)
        ...  (frequency-major, then pressure)
      ]
    }

Duties and positions are fractions [1] (the CLI and figures show percent); pressures are
gauge [Pa]. Reading checks everything and refuses a bad file with a
:class:`~valve_model_pkg.errors.MapFormatError` naming the file and the problem.
"""
from __future__ import annotations

import datetime as _dt
import hashlib
import json
import math
import os
import re
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..model.constants import ATMOSPHERIC_PRESSURE_PA
from .curves import DEFAULT_STOP_TOLERANCE, CurveFeatures, curve_features
from ..errors import MapFormatError, MapParameterMismatchError

__all__ = [
    'FORMAT_NAME', 'FORMAT_VERSION', 'DEFAULT_MAP_FILENAME', 'DutyMap', 'parameters_hash',
    'canonical_parameters', 'default_map_path', 'load_map',
]

FORMAT_NAME = 'valve_suite/duty_map'
FORMAT_VERSION = 1
DEFAULT_MAP_FILENAME = 'valve_map.json'
#: Slack on the [0, 1] range of a stored position fraction (rounding in the file).
_RANGE_SLACK = 1e-6
_UNITS = {
    'duty': '1 (fraction of the PWM period)',
    'position_fraction': '1 (x_avg / x_max, periodic steady state)',
    'supply_pressure_pa': 'Pa, gauge',
    'output_pressure_pa': 'Pa, gauge',
    'pwm_frequency_hz': 'Hz',
    'supply_voltage_v': 'V',
}


def canonical_parameters(params: Any) -> dict[str, Any]:
    """The nested parameter dict of a ValveParameters or of a mapping, validated.

    Parameters
    ----------
    params : ValveParameters or mapping
        A parameter set, or its ``to_dict()`` form (nested or flat).

    Raises
    ------
    ValueError
        (ParameterError) if the mapping is not a valid parameter set.
    """
    from valve_model_pkg.model.parameters import ValveParameters
    if isinstance(params, ValveParameters):
        return params.to_dict()
    return ValveParameters.from_dict(params).to_dict()


def parameters_hash(params: Any) -> str:
    """SHA-256 (hex) of the canonical JSON of a parameter set (sorted keys, float repr)."""
    text = json.dumps(canonical_parameters(params), sort_keys=True, separators=(',', ':'),
                      allow_nan=False)
    return hashlib.sha256(text.encode('utf-8')).hexdigest()


def _flat(d: Mapping[str, Any], prefix: str = '') -> dict[str, Any]:
    out: dict[str, Any] = {}
    for k, v in d.items():
        if isinstance(v, Mapping):
            out.update(_flat(v, f'{prefix}{k}.'))
        else:
            out[f'{prefix}{k}'] = v
    return out


def default_map_path() -> Path:
    """Path of the shipped ``config/valve_map.json`` (source tree or ament share directory).

    Raises
    ------
    FileNotFoundError
        If no location holds the file.
    """
    here = Path(__file__).resolve()
    candidates = [here.parents[2] / 'config' / DEFAULT_MAP_FILENAME]
    prefix = os.environ.get('AMENT_PREFIX_PATH', '')
    for root in filter(None, prefix.split(os.pathsep)):
        candidates.append(Path(root) / 'share' / 'valve_model_pkg' / 'config'
                          / DEFAULT_MAP_FILENAME)
    for path in candidates:
        if path.is_file():
            return path
    raise FileNotFoundError(
        f'{DEFAULT_MAP_FILENAME} not found; looked in ' + ', '.join(str(c) for c in candidates))


@dataclass(frozen=True, eq=False)
class DutyMap:
    """Static duty map: x_avg / x_max at periodic steady state on a grid.

    Attributes
    ----------
    duty : numpy.ndarray, shape (n_d,)
        Ascending duties [1], from 0 to 1.
    supply_pressures_pa : numpy.ndarray, shape (n_p,)
        Ascending supply pressures, gauge [Pa].
    pwm_frequencies_hz : numpy.ndarray, shape (n_f,)
        Ascending main PWM frequencies [Hz].
    position_fraction : numpy.ndarray, shape (n_f, n_p, n_d)
        x_avg / x_max [1] at periodic steady state.
    parameters : dict
        The valve parameter set (nested ``ValveParameters.to_dict()`` form).
    electronics : dict
        The drive electronics (``ElectronicsConfig.to_dict()``).
    supply_voltage_v : float
        Drive supply voltage [V].
    output_pressure_pa : float
        Output port pressure during generation, gauge [Pa].
    steady_state : dict
        The periodic-steady-state criterion used (see :mod:`.steady_state`).
    periods : numpy.ndarray of int, shape (n_f, n_p, n_d), optional
        PWM periods simulated per grid point until steady state.
    converged : numpy.ndarray of bool, shape (n_f, n_p, n_d), optional
        False where the steady-state criterion was not met within the period limit.
    cycles : numpy.ndarray of int, shape (n_f, n_p, n_d), optional
        PWM periods per steady cycle (1 normally; m > 1 for a sub-harmonic limit cycle,
        whose value is the average over the whole cycle; 0 where not converged).
    dead_band_edges, saturation_edges : numpy.ndarray, shape (n_f, n_p), optional
        Edges refined between grid duties (nan where not refined).
    stop_tolerance : float
        Fraction of x_max within which a point counts as on an end stop.
    extra_points : list of (numpy.ndarray, numpy.ndarray), optional
        Per curve (frequency-major, then pressure) the steady points simulated off the
        grid (edge bisection and adaptive refinement of steep or curved segments): duties
        [1] and x_avg / x_max [1]. :meth:`curve_points` merges them with the grid.
    refinement : dict
        Settings of the adaptive refinement: ``min_spacing`` (finest duty step),
        ``jump_threshold`` (rise of x_avg / x_max across a finest-step segment that counts
        as a jump), ``interp_tolerance``, ``max_rise``.
    created_utc : str
    generator : dict
        Program, version, run time and other provenance.
    notes : list of str
    """

    duty: np.ndarray
    supply_pressures_pa: np.ndarray
    pwm_frequencies_hz: np.ndarray
    position_fraction: np.ndarray
    parameters: dict[str, Any]
    electronics: dict[str, Any]
    supply_voltage_v: float = 24.0
    output_pressure_pa: float = 0.0
    steady_state: dict[str, Any] = field(default_factory=dict)
    periods: np.ndarray | None = None
    converged: np.ndarray | None = None
    cycles: np.ndarray | None = None
    dead_band_edges: np.ndarray | None = None
    saturation_edges: np.ndarray | None = None
    stop_tolerance: float = DEFAULT_STOP_TOLERANCE
    extra_points: list[tuple[np.ndarray, np.ndarray]] | None = None
    refinement: dict[str, Any] = field(default_factory=dict)
    created_utc: str = ''
    generator: dict[str, Any] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)

    def __post_init__(self) -> None:
        d = np.asarray(self.duty, dtype=float)
        p = np.asarray(self.supply_pressures_pa, dtype=float)
        f = np.asarray(self.pwm_frequencies_hz, dtype=float)
        x = np.asarray(self.position_fraction, dtype=float)
        _check_grid(d, p, f)
        if x.shape != (f.size, p.size, d.size):
            raise ValueError(f'position_fraction must have shape {(f.size, p.size, d.size)} '
                             f'(frequencies, pressures, duties), got {x.shape}')
        if not np.all(np.isfinite(x)):
            raise ValueError('position_fraction holds non-finite values')
        if x.min() < -_RANGE_SLACK or x.max() > 1.0 + _RANGE_SLACK:
            raise ValueError(f'position_fraction must lie in [0, 1], got '
                             f'[{x.min():.6g}, {x.max():.6g}]')
        for name, arr in (('duty', d), ('supply_pressures_pa', p), ('pwm_frequencies_hz', f),
                          ('position_fraction', np.clip(x, 0.0, 1.0))):
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)
        for name, dtype, shape in (('periods', int, x.shape), ('converged', bool, x.shape),
                                   ('cycles', int, x.shape),
                                   ('dead_band_edges', float, x.shape[:2]),
                                   ('saturation_edges', float, x.shape[:2])):
            value = getattr(self, name)
            if value is None:
                continue
            arr = np.asarray(value, dtype=dtype)
            if arr.shape != shape:
                raise ValueError(f'{name} must have shape {shape}, got {arr.shape}')
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)
        if self.extra_points is not None:
            if len(self.extra_points) != f.size * p.size:
                raise ValueError(f'extra_points must hold {f.size * p.size} curves, got '
                                 f'{len(self.extra_points)}')
            clean = []
            for n, (ed, ex) in enumerate(self.extra_points):
                ed = np.asarray(ed, dtype=float).ravel()
                ex = np.asarray(ex, dtype=float).ravel()
                if ed.shape != ex.shape or not (np.all(np.isfinite(ed))
                                                and np.all(np.isfinite(ex))):
                    raise ValueError(f'extra_points[{n}]: duties and values must be finite '
                                     'and of equal length')
                if ed.size and (ed.min() < 0.0 or ed.max() > 1.0 or ex.min() < -_RANGE_SLACK
                                or ex.max() > 1.0 + _RANGE_SLACK):
                    raise ValueError(f'extra_points[{n}]: duty or value outside [0, 1]')
                order = np.argsort(ed, kind='stable')
                clean.append((ed[order], np.clip(ex[order], 0.0, 1.0)))
            object.__setattr__(self, 'extra_points', clean)

    # --- queries --------------------------------------------------------------------------
    @property
    def parameters_sha256(self) -> str:
        """SHA-256 of the parameter set the map was generated for."""
        return parameters_hash(self.parameters)

    def frequency_index(self, pwm_frequency_hz: float, rel_tol: float = 1e-9) -> int:
        """Index of a grid frequency.

        Raises
        ------
        KeyError
            If the frequency is not on the grid (the message lists the grid).
        """
        for i, f in enumerate(self.pwm_frequencies_hz):
            if math.isclose(f, pwm_frequency_hz, rel_tol=rel_tol):
                return i
        raise KeyError(f'PWM frequency {pwm_frequency_hz:g} Hz is not in the map (it has '
                       + ', '.join(f'{f:g}' for f in self.pwm_frequencies_hz) + ' Hz)')

    def pressure_index(self, supply_pressure_pa: float, abs_tol: float = 1e-6) -> int:
        """Index of a grid supply pressure (gauge Pa); KeyError if not on the grid."""
        for i, p in enumerate(self.supply_pressures_pa):
            if abs(p - supply_pressure_pa) <= abs_tol:
                return i
        raise KeyError(f'supply pressure {supply_pressure_pa:g} Pa is not in the map (it has '
                       + ', '.join(f'{p:g}' for p in self.supply_pressures_pa) + ' Pa)')

    def curve(self, pwm_frequency_hz: float, supply_pressure_pa: float) -> np.ndarray:
        """x_avg / x_max against :attr:`duty` for a grid frequency and pressure."""
        return self.position_fraction[self.frequency_index(pwm_frequency_hz),
                                      self.pressure_index(supply_pressure_pa)]

    def features(self, i_freq: int, i_press: int) -> CurveFeatures:
        """Dead band, saturation and width of one curve (grid indices)."""
        return curve_features(self.duty, self.position_fraction[i_freq, i_press],
                              self.stop_tolerance)

    def curve_points(self, i_freq: int, i_press: int) -> tuple[np.ndarray, np.ndarray]:
        """All steady points of one curve: the grid merged with the extra points.

        Returns
        -------
        (numpy.ndarray, numpy.ndarray)
            Ascending duties [1] and x_avg / x_max [1]; an extra point at a grid duty is
            dropped in favour of the grid value.
        """
        d, x = self.duty, self.position_fraction[i_freq, i_press]
        if not self.extra_points:
            return d.copy(), x.copy()
        ed, ex = self.extra_points[i_freq * self.supply_pressures_pa.size + i_press]
        keep = np.array([np.min(np.abs(d - v)) > 1e-12 for v in ed], dtype=bool)
        dd = np.concatenate([d, ed[keep]])
        xx = np.concatenate([x, ex[keep]])
        order = np.argsort(dd, kind='stable')
        return dd[order], xx[order]

    def jumps(self, i_freq: int, i_press: int) -> list[tuple[float, float, float, float]]:
        """Discontinuities of a curve: ``(d_a, x_a, d_b, x_b)`` per jump.

        A jump is a segment between neighbouring points at most 1.5 ``min_spacing`` wide
        whose opening changes by more than ``jump_threshold``: the refinement went as fine
        as it goes and the curve still leaps. Openings strictly between ``x_a`` and ``x_b``
        are not reached at steady state by any duty. Empty without refinement settings.
        """
        spacing = self.refinement.get('min_spacing')
        threshold = self.refinement.get('jump_threshold')
        if not spacing or not threshold:
            return []
        d, x = self.curve_points(i_freq, i_press)
        out = []
        for k in range(d.size - 1):
            if d[k + 1] - d[k] <= 1.5 * spacing + 1e-12 and abs(x[k + 1] - x[k]) > threshold:
                out.append((float(d[k]), float(x[k]), float(d[k + 1]), float(x[k + 1])))
        return out

    def all_features(self) -> dict[tuple[float, float], CurveFeatures]:
        """``{(frequency Hz, pressure Pa): CurveFeatures}`` for every curve."""
        return {(float(f), float(p)): self.features(i, j)
                for i, f in enumerate(self.pwm_frequencies_hz)
                for j, p in enumerate(self.supply_pressures_pa)}

    def check_parameters(self, params: Any, path: str = '<map>',
                         params_source: str = 'the parameter set in force') -> None:
        """Refuse the map if it was made for other valve parameters.

        Parameters
        ----------
        params : ValveParameters or mapping
            The parameter set in force.
        path : str
            The map file, for the message.
        params_source : str
            Where ``params`` came from, for the message.

        Raises
        ------
        MapParameterMismatchError
            Naming both hashes and up to five differing fields with both values.
        """
        mine = canonical_parameters(self.parameters)
        theirs = canonical_parameters(params)
        if parameters_hash(mine) == parameters_hash(theirs):
            return
        a, b = _flat(mine), _flat(theirs)
        diffs = [f'{k} = {a.get(k)!r} in the map, {b.get(k)!r} in {params_source}'
                 for k in sorted(set(a) | set(b)) if a.get(k) != b.get(k)]
        more = f' (and {len(diffs) - 5} more)' if len(diffs) > 5 else ''
        raise MapParameterMismatchError(
            path, f'map made for other valve parameters (sha256 {parameters_hash(mine)[:12]} '
                  f'vs {parameters_hash(theirs)[:12]}): ' + '; '.join(diffs[:5]) + more)

    # --- file I/O -------------------------------------------------------------------------
    def to_json_dict(self) -> dict[str, Any]:
        """The file's JSON structure (see the module docstring)."""
        curves = []
        for i, f in enumerate(self.pwm_frequencies_hz):
            for j, p in enumerate(self.supply_pressures_pa):
                c: dict[str, Any] = {
                    'pwm_frequency_hz': float(f), 'supply_pressure_pa': float(p),
                    'position_fraction': [_round(v) for v in self.position_fraction[i, j]],
                    'features': self.features(i, j).as_dict(),
                }
                if self.periods is not None:
                    c['periods'] = [int(n) for n in self.periods[i, j]]
                if self.converged is not None:
                    c['unconverged_duties'] = [
                        float(d) for d, ok in zip(self.duty, self.converged[i, j]) if not ok]
                if self.cycles is not None:
                    c['subharmonic_cycles'] = [
                        [float(d), int(m)] for d, m in zip(self.duty, self.cycles[i, j])
                        if m > 1]
                for key, arr in (('dead_band_edge', self.dead_band_edges),
                                 ('saturation_edge', self.saturation_edges)):
                    v = None if arr is None else float(arr[i, j])
                    c[key] = None if v is None or math.isnan(v) else v
                if self.extra_points is not None:
                    ed, ex = self.extra_points[i * self.supply_pressures_pa.size + j]
                    c['extra_points'] = [[_round(a), _round(b)] for a, b in zip(ed, ex)]
                    c['jumps'] = [[_round(v) for v in jmp] for jmp in self.jumps(i, j)]
                curves.append(c)
        return {
            'format': FORMAT_NAME,
            'format_version': FORMAT_VERSION,
            'created_utc': self.created_utc or _now(),
            'generator': self.generator,
            'notes': list(self.notes),
            'parameters_sha256': self.parameters_sha256,
            'parameters': canonical_parameters(self.parameters),
            'electronics': self.electronics,
            'supply_voltage_v': float(self.supply_voltage_v),
            'output_pressure_pa': float(self.output_pressure_pa),
            'steady_state': self.steady_state,
            'stop_tolerance': float(self.stop_tolerance),
            'refinement': self.refinement,
            'units': _UNITS,
            'grid': {
                'duty': [_round(v) for v in self.duty],
                'supply_pressure_pa': [float(v) for v in self.supply_pressures_pa],
                'pwm_frequency_hz': [float(v) for v in self.pwm_frequencies_hz],
            },
            'curves': curves,
        }

    def save(self, path: str | os.PathLike[str]) -> Path:
        """Write the map file (JSON); returns the path."""
        path = Path(path)
        text = _compact_json(self.to_json_dict())
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(path.name + '.tmp')
        tmp.write_text(text + '\n', encoding='utf-8')
        os.replace(tmp, path)
        return path

    @classmethod
    def from_json_dict(cls, data: Any, path: str = '<map>') -> DutyMap:
        """Build from the file's JSON structure, checking every part.

        Raises
        ------
        MapFormatError
            Naming ``path`` and the problem.
        """
        def fail(reason: str) -> MapFormatError:
            return MapFormatError(path, reason)

        params = _checked_header(data, fail)
        duty, press, freq = _checked_grid(data['grid'], fail)
        c = _read_curves(data['curves'], duty, press, freq, fail)
        refinement = data.get('refinement') or {}
        if not isinstance(refinement, dict):
            raise fail('refinement must be an object')
        try:
            supply_v = float(data.get('supply_voltage_v', 24.0))
            output_pa = float(data.get('output_pressure_pa', 0.0))
            stop_tol = float(data.get('stop_tolerance', DEFAULT_STOP_TOLERANCE))
        except (TypeError, ValueError) as err:
            raise fail(f'bad scalar field: {err}') from err
        return cls(duty=duty, supply_pressures_pa=press, pwm_frequencies_hz=freq,
                   position_fraction=c.x, parameters=params,
                   electronics=dict(data['electronics'] or {}), supply_voltage_v=supply_v,
                   output_pressure_pa=output_pa,
                   steady_state=dict(data.get('steady_state') or {}),
                   periods=c.periods if c.have_periods else None, converged=c.converged,
                   cycles=c.cycles,
                   dead_band_edges=c.db_edges, saturation_edges=c.sat_edges,
                   stop_tolerance=stop_tol, extra_points=c.extra, refinement=dict(refinement),
                   created_utc=str(data.get('created_utc', '')),
                   generator=dict(data.get('generator') or {}),
                   notes=list(data.get('notes') or []))

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> DutyMap:
        """Read and check a map file.

        Raises
        ------
        MapFormatError
            If the file is missing, unreadable, not JSON or not a valid duty map; the
            message names the file and the reason.
        """
        spath = str(path)
        try:
            text = Path(path).read_text(encoding='utf-8')
        except FileNotFoundError as err:
            raise MapFormatError(spath, 'no such map file') from err
        except (OSError, UnicodeDecodeError) as err:
            raise MapFormatError(spath, f'cannot read the map file: {err}') from err
        try:
            data = json.loads(text)
        except json.JSONDecodeError as err:
            raise MapFormatError(spath, f'not valid JSON (line {err.lineno}, column '
                                        f'{err.colno}): {err.msg}') from err
        return cls.from_json_dict(data, spath)


def load_map(path: str | os.PathLike[str] | None = None) -> DutyMap:
    """Load a map file (default: the shipped :func:`default_map_path`)."""
    if path is None or str(path) == '':
        try:
            path = default_map_path()
        except FileNotFoundError as err:
            raise MapFormatError(DEFAULT_MAP_FILENAME, str(err)) from err
    return DutyMap.load(path)


def _round(v: float) -> float:
    return round(float(v), 7)


def _compact_json(data: dict[str, Any]) -> str:
    """Indented JSON with every list of numbers on one line (a small, diffable file)."""
    text = json.dumps(data, indent=1, allow_nan=False)
    scalar = r'(?:-?[0-9][0-9.eE+-]*|null|true|false)'
    return re.sub(r'\[\s*(' + scalar + r'(?:,\s*' + scalar + r')*)\s*\]',
                  lambda m: '[' + re.sub(r',\s+', ', ', m.group(1)) + ']', text)


def _now() -> str:
    return _dt.datetime.now(_dt.timezone.utc).strftime('%Y-%m-%dT%H:%M:%SZ')


def _array(block: Mapping[str, Any], key: str, fail: Any, where: str) -> np.ndarray:
    raw = block.get(key)
    if not isinstance(raw, list) or not raw:
        raise fail(f'{where}.{key} must be a non-empty list of numbers')
    if not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in raw):
        bad = next(v for v in raw if not isinstance(v, (int, float)) or isinstance(v, bool))
        raise fail(f'{where}.{key} holds a non-number: {bad!r}')
    arr = np.asarray(raw, dtype=float)
    if not np.all(np.isfinite(arr)):
        raise fail(f'{where}.{key} holds non-finite values')
    return arr


def _check_grid(d: np.ndarray, p: np.ndarray, f: np.ndarray) -> None:
    for name, arr in (('duty', d), ('supply_pressure_pa', p), ('pwm_frequency_hz', f)):
        if arr.ndim != 1 or arr.size < 1 or not np.all(np.isfinite(arr)):
            raise ValueError(f'{name} must be a non-empty 1-D array of finite numbers')
        if np.any(np.diff(arr) <= 0.0):
            raise ValueError(f'{name} must be strictly ascending')
    if d.size < 2 or abs(d[0]) > 1e-12 or abs(d[-1] - 1.0) > 1e-12:
        raise ValueError(f'duty must run from 0 to 1 with at least 2 points, got '
                         f'{d.size} points from {d[0]:g} to {d[-1]:g}')
    if p[0] < -ATMOSPHERIC_PRESSURE_PA:
        raise ValueError(f'supply pressure below vacuum: {p[0]:g} Pa gauge')
    if f[0] <= 0.0:
        raise ValueError(f'PWM frequencies must be positive, got {f[0]:g} Hz')


_Fail = Callable[[str], MapFormatError]


def _checked_header(data: Any, fail: _Fail) -> dict:
    """The format, version and required keys; the parameter set, checked against its hash."""
    if not isinstance(data, dict):
        raise fail(f'not a duty map: top level is {type(data).__name__}, not an object')
    if data.get('format') != FORMAT_NAME:
        raise fail(f'not a duty map: format is {data.get("format")!r}, '
                   f'expected {FORMAT_NAME!r}')
    version = data.get('format_version')
    if version != FORMAT_VERSION:
        raise fail(f'unsupported format_version {version!r} (this reader knows '
                   f'{FORMAT_VERSION})')
    for key in ('parameters_sha256', 'parameters', 'electronics', 'grid', 'curves'):
        if key not in data:
            raise fail(f'missing key {key!r}')
    try:
        params = canonical_parameters(data['parameters'])
    except (ValueError, TypeError) as err:
        raise fail(f'invalid parameter set: {err}') from err
    if parameters_hash(params) != data['parameters_sha256']:
        raise fail('parameters_sha256 does not match the parameter set stored in the '
                   'file (edited or corrupted)')
    return params


def _checked_grid(grid: Any, fail: _Fail) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Duties [1], supply pressures [Pa] and PWM frequencies [Hz] of the grid."""
    if not isinstance(grid, dict):
        raise fail('grid must be an object')
    duty = _array(grid, 'duty', fail, 'grid')
    press = _array(grid, 'supply_pressure_pa', fail, 'grid')
    freq = _array(grid, 'pwm_frequency_hz', fail, 'grid')
    try:
        _check_grid(duty, press, freq)
    except ValueError as err:
        raise fail(f'grid: {err}') from err
    return duty, press, freq


@dataclass
class _ReadCurves:
    """The curves of a file, as arrays over (frequency, pressure[, duty])."""

    x: np.ndarray
    periods: np.ndarray
    have_periods: bool
    converged: np.ndarray
    cycles: np.ndarray
    db_edges: np.ndarray
    sat_edges: np.ndarray
    extra: list[tuple[np.ndarray, np.ndarray]] | None


def _read_curves(curves: Any, duty: np.ndarray, press: np.ndarray, freq: np.ndarray,
                 fail: _Fail) -> _ReadCurves:
    """Every curve, frequency-major then pressure, each checked by :func:`_read_curve`."""
    n_f, n_p, n_d = freq.size, press.size, duty.size
    if not isinstance(curves, list) or len(curves) != n_f * n_p:
        raise fail(f'curves must be a list of {n_f * n_p} curves (frequencies x pressures), '
                   f'got {len(curves) if isinstance(curves, list) else type(curves).__name__}')
    out = _ReadCurves(
        x=np.empty((n_f, n_p, n_d)), periods=np.zeros((n_f, n_p, n_d), dtype=int),
        have_periods=True, converged=np.ones((n_f, n_p, n_d), dtype=bool),
        cycles=np.ones((n_f, n_p, n_d), dtype=int), db_edges=np.full((n_f, n_p), math.nan),
        sat_edges=np.full((n_f, n_p), math.nan),
        extra=[] if curves and all(isinstance(c, dict) and 'extra_points' in c
                                   for c in curves) else None)
    for n, c in enumerate(curves):
        _read_curve(c, n, duty, press, freq, out, fail)
    return out


def _read_curve(c: Any, n: int, duty: np.ndarray, press: np.ndarray, freq: np.ndarray,
                out: _ReadCurves, fail: _Fail) -> None:
    """Curve ``n`` into ``out``: its operating point, values, periods, marks and edges."""
    i, j = divmod(n, press.size)
    n_d = duty.size
    where = f'curves[{n}]'
    if not isinstance(c, dict):
        raise fail(f'{where} must be an object')
    for key, expect in (('pwm_frequency_hz', freq[i]), ('supply_pressure_pa', press[j])):
        got = c.get(key)
        if not isinstance(got, (int, float)) or not math.isclose(
                float(got), expect, rel_tol=1e-9, abs_tol=1e-9):
            raise fail(f'{where}.{key} is {got!r}, expected {expect:g} '
                       '(curves are frequency-major, then pressure)')
    values = _array(c, 'position_fraction', fail, where)
    if values.size != n_d:
        raise fail(f'{where}.position_fraction has {values.size} values, the duty grid '
                   f'{n_d}')
    if values.min() < -_RANGE_SLACK or values.max() > 1.0 + _RANGE_SLACK:
        raise fail(f'{where}.position_fraction outside [0, 1]: '
                   f'[{values.min():.6g}, {values.max():.6g}]')
    out.x[i, j] = values
    if 'periods' in c:
        pv = _array(c, 'periods', fail, where)
        if pv.size != n_d:
            raise fail(f'{where}.periods has {pv.size} values, the duty grid {n_d}')
        out.periods[i, j] = pv.astype(int)
    else:
        out.have_periods = False
    for d in c.get('unconverged_duties') or []:
        k = int(np.argmin(np.abs(duty - float(d))))
        out.converged[i, j, k] = False
        out.cycles[i, j, k] = 0
    for item in c.get('subharmonic_cycles') or []:
        if not (isinstance(item, list) and len(item) == 2
                and all(isinstance(v, (int, float)) for v in item)):
            raise fail(f'{where}.subharmonic_cycles entries must be [duty, periods]')
        k = int(np.argmin(np.abs(duty - float(item[0]))))
        out.cycles[i, j, k] = int(item[1])
    for key, arr in (('dead_band_edge', out.db_edges), ('saturation_edge', out.sat_edges)):
        v = c.get(key)
        if v is not None:
            if not isinstance(v, (int, float)) or not 0.0 <= v <= 1.0:
                raise fail(f'{where}.{key} must be a duty in [0, 1] or null, got {v!r}')
            arr[i, j] = float(v)
    if out.extra is not None:
        out.extra.append(_extra_points(c['extra_points'], where, fail))


def _extra_points(pts: Any, where: str, fail: _Fail) -> tuple[np.ndarray, np.ndarray]:
    """A curve's ``extra_points`` as (duties, fractions), each within [0, 1]."""
    if not isinstance(pts, list) or not all(
            isinstance(pt, list) and len(pt) == 2
            and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in pt)
            for pt in pts):
        raise fail(f'{where}.extra_points must be a list of [duty, fraction]')
    arr2 = np.asarray(pts, dtype=float).reshape(-1, 2)
    if not np.all(np.isfinite(arr2)) or (arr2.size and (
            arr2[:, 0].min() < 0.0 or arr2[:, 0].max() > 1.0
            or arr2[:, 1].min() < -_RANGE_SLACK
            or arr2[:, 1].max() > 1.0 + _RANGE_SLACK)):
        raise fail(f'{where}.extra_points outside [0, 1]')
    return arr2[:, 0], arr2[:, 1]
