"""Identification of the valve from measured current, and closing the loop.

The front door (docs/identification.md)::

    from valve_model_pkg.identification import IdentifySettings, identify, write_report

    ident = identify(['fit_24v.csv'], ['validate_15v.csv'], IdentifySettings(quick=True))
    print(ident.diagnosis.effect, ident.augmented.validation.rmse)
    write_report(ident, 'out')          # report.json, report.md, params.yaml

:func:`identify` takes records (paths of CSV files or bag directories, or
:class:`Measurement` objects from :func:`read_measurements`) and an
:class:`IdentifySettings` (every option of ``valve_identify``); it returns an
:class:`Identification`. The names are loaded on first use: importing this package
costs nothing.
"""
from __future__ import annotations

import importlib

__all__ = ['IdentifySettings', 'Identification', 'Measurement', 'identify',
           'read_measurements', 'write_report']

_HOMES = {
    'IdentifySettings': 'pipeline',
    'Identification': 'pipeline',
    'identify': 'pipeline',
    'Measurement': 'measurement',
    'read_measurements': 'readers',
    'write_report': 'report',
}


def __getattr__(name: str) -> object:
    home = _HOMES.get(name)
    if home is None:
        raise AttributeError(f'module {__name__!r} has no attribute {name!r}')
    value = getattr(importlib.import_module(f'{__name__}.{home}'), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
