"""The fleet manifest: which valves, which records, which options (CSV or YAML).

CSV (one valve a row, several files in one cell separated by ``;``)::

    valve_id,fit,validate,quick
    V001,v001/fit_24v_step.csv,v001/validate_15v_step.csv,
    V002,v002/fit_a.csv;v002/fit_b.csv,v002/validate_15v_step.csv,true

YAML (a list of valves, or a mapping with ``valves`` and optional ``defaults``)::

    defaults: {quick: true}
    valves:
      - valve_id: V001
        fit: v001/fit_24v_step.csv          # a path or a list of paths
        validate: [v001/validate_15v_step.csv]
        params: known/v001.yaml             # optional per-valve options
        route: mean-voltage
        electronics: known/v001_driver.yaml

Record paths (and ``params``, ``electronics``) are relative to the manifest's folder. A
refused manifest raises :class:`ManifestError`, whose message is one line naming the file,
the line (CSV and YAML) and key, and the value. The options are ``valve_identify``'s
(:data:`OPTION_KEYS`).
"""
from __future__ import annotations

import csv
import hashlib
import json
import re
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import yaml

from ..errors import ManifestError

__all__ = ['ManifestError', 'ValveJob', 'OPTION_KEYS', 'read_manifest']

#: valve ids become folder names under DIR/valves/: letters, digits, ``._-``, no leading dot
_VALVE_ID = re.compile(r'^[A-Za-z0-9_-][A-Za-z0-9._-]{0,127}$')

#: per-valve option -> (type, meaning); the same names as valve_identify's options
OPTION_KEYS: dict[str, tuple[type, str]] = {
    'params': (str, 'known parameters YAML (Table 1, orifice); default: the packaged set'),
    'quick': (bool, 'smaller search effort (valve_identify --quick)'),
    'diagnose': (bool, 'false stops after the baseline fit (valve_identify --no-diagnosis)'),
    'plots': (bool, 'write the PNG plots into the valve folder'),
    'topic': (str, 'valve state topic in bag records'),
    'valve': (str, 'frame_id of the valve in multi-valve bags'),
    'map': (str, 'ROLE=TOPIC[.FIELD] entries of bag records, separated by ";" '
                 '(valve_identify --map)'),
    'route': (str, 'auto, mean-voltage or electronics (valve_identify --route)'),
    'electronics': (str, 'drive electronics description YAML (valve_identify --electronics)'),
    'fit_electronics': (bool, 'the electronics file\'s constants are start values '
                              '(valve_identify --fit-electronics)'),
    'choose_electronics': (bool, 'the data choose the electronics\' form: true always, '
                                 'false never; absent: when the paper\'s driver\'s form '
                                 'misfits (valve_identify --choose-electronics)'),
}
#: options naming a file, resolved relative to the manifest like the records
_FILE_KEYS = ('params', 'electronics')
_RECORD_KEYS = ('fit', 'validate')
_ALL_KEYS = ('valve_id',) + _RECORD_KEYS + tuple(OPTION_KEYS)
_TRUE = {'true', 'yes', '1', 'on'}
_FALSE = {'false', 'no', '0', 'off'}


@dataclass(frozen=True)
class ValveJob:
    """One valve's identification, as the manifest asks for it.

    Attributes
    ----------
    valve_id : str
        Unique name; the valve's output goes to ``DIR/valves/<valve_id>/``.
    fit, validate : tuple of str
        Absolute paths of the fit and validation records (CSV files or bag directories).
    options : dict
        Per-valve options (keys of :data:`OPTION_KEYS`), ``params`` as an absolute path.
    line : int or None
        Where the valve is in the manifest (for messages).
    """

    valve_id: str
    fit: tuple[str, ...]
    validate: tuple[str, ...]
    options: dict[str, Any] = field(default_factory=dict)
    line: int | None = field(default=None, compare=False)

    def to_json(self) -> dict[str, Any]:
        """JSON form (what a worker receives, and what ``fleet_job.json`` keeps)."""
        d = asdict(self)
        d.pop('line')
        d['fit'], d['validate'] = list(self.fit), list(self.validate)
        return d

    def fingerprint(self) -> str:
        """Hash of records and options: a finished valve is reused only if it matches."""
        text = json.dumps(self.to_json(), sort_keys=True)
        return hashlib.sha256(text.encode('utf-8')).hexdigest()[:16]


def _bool(value: Any, path: Path, line: int | None, key: str) -> bool:
    if isinstance(value, bool):
        return value
    text = str(value).strip().lower()
    if text in _TRUE:
        return True
    if text in _FALSE:
        return False
    raise ManifestError(path, line, key, f'{value!r} is not a boolean (true/false)')


def _records(value: Any, path: Path, line: int | None, key: str, *, split: bool
             ) -> tuple[str, ...]:
    """Resolve record paths relative to the manifest and check they exist."""
    if value is None:
        items: list[Any] = []
    elif isinstance(value, (list, tuple)):
        items = list(value)
    elif split:
        items = [s for s in str(value).split(';')]
    else:
        items = [value]
    out = []
    for item in items:
        if not isinstance(item, str):
            raise ManifestError(path, line, key, f'{item!r} is not a file path')
        item = item.strip()
        if not item:
            if split:
                continue      # empty cell or a trailing ';'
            raise ManifestError(path, line, key, 'empty file path')
        p = Path(item).expanduser()
        p = p if p.is_absolute() else path.parent / p
        if not p.exists():
            raise ManifestError(path, line, key, f'{item!r}: no such file ({p})')
        out.append(str(p.resolve()))
    return tuple(out)


def _job(entry: dict[str, Any], defaults: dict[str, Any], path: Path, line: int | None,
         lines: dict[str, int], *, split: bool) -> ValveJob:
    def at(key: str) -> int | None:
        return lines.get(key, line)

    unknown = [k for k in entry if k not in _ALL_KEYS]
    if unknown:
        raise ManifestError(path, at(unknown[0]), unknown[0],
                            f'unknown key (known: {", ".join(_ALL_KEYS)})')
    vid = entry.get('valve_id')
    vid = '' if vid is None else str(vid).strip()
    if not _VALVE_ID.match(vid):
        raise ManifestError(path, at('valve_id'), 'valve_id',
                            f'{vid!r} is not a valve id (letters, digits, ".", "_", "-"; '
                            'not starting with ".")')
    fit = _records(entry.get('fit'), path, at('fit'), 'fit', split=split)
    if not fit:
        raise ManifestError(path, at('fit'), 'fit', f'valve {vid}: no fit record')
    validate = _records(entry.get('validate'), path, at('validate'), 'validate', split=split)
    options: dict[str, Any] = {}
    for key, (kind, _) in OPTION_KEYS.items():
        value = entry.get(key, defaults.get(key))
        if value is None or (isinstance(value, str) and not value.strip()):
            continue
        if kind is bool:
            options[key] = _bool(value, path, at(key), key)
        elif key in _FILE_KEYS:
            options[key] = _records(str(value), path, at(key), key, split=False)[0]
        else:
            options[key] = str(value).strip()
    _check_options(options, path, at)
    return ValveJob(vid, fit, validate, options, line)


def _check_options(options: dict[str, Any], path: Path, at: Any) -> None:
    """Refuse what ``valve_identify`` would refuse: an unknown route, a malformed topic map,
    ``fit_electronics`` without a file, ``choose_electronics`` beside one."""
    from ..identification.mean_voltage import ROUTE_CHOICES
    from ..identification.topic_map import parse_topic_map
    route = options.get('route')
    if route is not None and route not in ROUTE_CHOICES:
        raise ManifestError(path, at('route'), 'route',
                            f'{route!r} is not a route (known: {", ".join(ROUTE_CHOICES)})')
    if 'map' in options:
        entries = tuple(e.strip() for e in options['map'].split(';') if e.strip())
        try:
            parse_topic_map(entries)
        except ValueError as err:
            raise ManifestError(path, at('map'), 'map', str(err)) from None
        options['map'] = ';'.join(entries)
    if options.get('fit_electronics') and 'electronics' not in options:
        raise ManifestError(path, at('fit_electronics'), 'fit_electronics',
                            'true needs an electronics file (key electronics)')
    if options.get('choose_electronics') and 'electronics' in options:
        raise ManifestError(path, at('choose_electronics'), 'choose_electronics',
                            'true and an electronics file exclude each other')


def _read_csv(path: Path, defaults: dict[str, Any]) -> list[ValveJob]:
    jobs = []
    with open(path, newline='', encoding='utf-8') as fh:
        rows = [r for r in csv.reader(fh)]
    numbered = [(k + 1, r) for k, r in enumerate(rows)
                if r and any(c.strip() for c in r) and not r[0].lstrip().startswith('#')]
    if not numbered:
        raise ManifestError(path, None, None, 'empty manifest (no header line)')
    head_line, header = numbered[0]
    header = [h.strip() for h in header]
    for h in header:
        if h not in _ALL_KEYS:
            raise ManifestError(path, head_line, h,
                                f'unknown column (known: {", ".join(_ALL_KEYS)})')
    for need in ('valve_id', 'fit'):
        if need not in header:
            raise ManifestError(path, head_line, need, 'missing column')
    if len(set(header)) != len(header):
        dup = next(h for h in header if header.count(h) > 1)
        raise ManifestError(path, head_line, dup, 'column given twice')
    for line, row in numbered[1:]:
        if len(row) > len(header):
            raise ManifestError(path, line, None,
                                f'{len(row)} cells for {len(header)} columns: {row!r}')
        entry = {h: (row[k] if k < len(row) else '') for k, h in enumerate(header)}
        jobs.append(_job(entry, defaults, path, line, {}, split=True))
    return jobs


class _LineLoader(yaml.SafeLoader):
    """Safe loader that remembers the line of every mapping and of each of its keys."""


class _LinedDict(dict):
    line: int | None = None
    key_lines: dict[str, int]


def _construct_mapping(loader: _LineLoader, node: yaml.MappingNode) -> _LinedDict:
    loader.flatten_mapping(node)
    out = _LinedDict()
    out.line = node.start_mark.line + 1
    out.key_lines = {}
    for key_node, value_node in node.value:
        key = loader.construct_object(key_node, deep=True)
        out[key] = loader.construct_object(value_node, deep=True)
        out.key_lines[str(key)] = key_node.start_mark.line + 1
    return out


_LineLoader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG,
                            _construct_mapping)


def _read_yaml(path: Path, defaults: dict[str, Any]) -> list[ValveJob]:
    try:
        doc = yaml.load(path.read_text(encoding='utf-8'), Loader=_LineLoader)  # noqa: S506
    except yaml.YAMLError as err:
        mark = getattr(err, 'problem_mark', None)
        raise ManifestError(path, mark.line + 1 if mark else None, None,
                            f'not valid YAML ({getattr(err, "problem", None) or err})'
                            ) from None
    if isinstance(doc, dict):
        extra = [k for k in doc if k not in ('valves', 'defaults')]
        if extra:
            raise ManifestError(path, doc.key_lines.get(str(extra[0])), str(extra[0]),
                                'unknown top-level key (known: valves, defaults)')
        file_defaults = doc.get('defaults') or {}
        if not isinstance(file_defaults, dict):
            raise ManifestError(path, doc.key_lines.get('defaults'), 'defaults',
                                f'{file_defaults!r} is not a mapping of options')
        bad = [k for k in file_defaults if k not in OPTION_KEYS]
        if bad:
            raise ManifestError(path, file_defaults.key_lines.get(str(bad[0])), str(bad[0]),
                                f'not a per-valve option (known: {", ".join(OPTION_KEYS)})')
        defaults = {**defaults, **file_defaults}
        valves = doc.get('valves')
        where = doc.key_lines.get('valves')
    else:
        valves, where = doc, 1
    if not isinstance(valves, list) or not valves:
        raise ManifestError(path, where, 'valves',
                            f'{valves!r}: expected a non-empty list of valves')
    jobs = []
    for k, entry in enumerate(valves):
        if not isinstance(entry, dict):
            raise ManifestError(path, where, f'valves[{k}]', f'{entry!r} is not a mapping')
        jobs.append(_job(entry, defaults, path, entry.line, entry.key_lines, split=False))
    return jobs


def read_manifest(path: str | Path, defaults: dict[str, Any] | None = None
                  ) -> list[ValveJob]:
    """Read and check a fleet manifest.

    Parameters
    ----------
    path : str or pathlib.Path
        ``.csv`` or ``.yaml``/``.yml`` file.
    defaults : dict, optional
        Options for every valve (keys of :data:`OPTION_KEYS`) unless the manifest's
        ``defaults`` or the valve's own entry says otherwise; ``params`` absolute.

    Returns
    -------
    list of ValveJob
        In manifest order.

    Raises
    ------
    ManifestError
        Unreadable or malformed manifest, unknown key, missing record, bad or repeated
        valve id.
    """
    path = Path(path)
    if not path.is_file():
        raise ManifestError(path, None, None, 'no such file')
    defaults = dict(defaults or {})
    suffix = path.suffix.lower()
    try:
        if suffix == '.csv':
            jobs = _read_csv(path, defaults)
        elif suffix in ('.yaml', '.yml'):
            jobs = _read_yaml(path, defaults)
        else:
            raise ManifestError(path, None, None,
                                f'unknown manifest type {suffix!r} (use .csv or .yaml)')
    except UnicodeDecodeError as err:
        raise ManifestError(path, None, None, f'not UTF-8 text ({err.reason})') from None
    except csv.Error as err:
        raise ManifestError(path, None, None, f'not valid CSV ({err})') from None
    if not jobs:
        raise ManifestError(path, None, None, 'no valves listed')
    seen: dict[str, ValveJob] = {}
    for job in jobs:
        if job.valve_id in seen:
            first = seen[job.valve_id].line
            raise ManifestError(path, job.line, 'valve_id',
                                f'{job.valve_id!r} listed twice (first at line {first})')
        seen[job.valve_id] = job
    return jobs
