"""Typed, validated parameter set of the valve model (Tables 1 and 2 of the paper).

All values are SI. The set is a frozen dataclass so identification can copy and vary it
safely; ``replace`` returns a validated copy. ``to_vector`` / ``from_vector`` give the flat
float vector in :data:`PARAMETER_FIELDS` order used by the compiled kernel and the batch API.
"""
from __future__ import annotations

import dataclasses
import math
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import yaml

__all__ = [
    'ParameterError',
    'ValveParameters',
    'EffectSpec',
    'EFFECTS',
    'PARAMETER_FIELDS',
    'SECTIONS',
    'load_parameters',
    'default_parameters_path',
]


class ParameterError(ValueError):
    """An invalid, missing or unknown model parameter (message names field and value)."""


@dataclasses.dataclass(frozen=True)
class EffectSpec:
    """One optional physical effect: its parameter fields, neutral values and bounds.

    Attributes
    ----------
    fields : tuple of str
        ValveParameters field names belonging to the effect.
    neutral : dict
        Field -> value that switches the effect off (the paper's model).
    bounds : dict
        Field -> (low, high), a physically sensible search range for identification.
    description : str
        One line on what the effect models.
    """

    fields: tuple[str, ...]
    neutral: dict[str, float]
    bounds: dict[str, tuple[float, float]]
    description: str

    def is_active(self, params: ValveParameters) -> bool:
        """Return True if ``params`` switches this effect on."""
        # coil_heating's time constant alone does not switch it on.
        key = self.fields[0]
        return getattr(params, key) != self.neutral[key]


#: The model extensions, each switched off by its neutral values (= the paper's model).
EFFECTS: dict[str, EffectSpec] = {
    'magnetic_saturation': EffectSpec(
        ('saturation_coefficient_per_a',),
        {'saturation_coefficient_per_a': 0.0},
        {'saturation_coefficient_per_a': (0.0, 2.0)},
        'flux linkage L(x) i / (1 + beta |i|), beta = 1/i_sat; force from the co-energy'),
    'eddy_current': EffectSpec(
        ('eddy_conductance_s',),
        {'eddy_conductance_s': 0.0},
        {'eddy_conductance_s': (0.0, 0.02)},
        'eddy-loss resistor R_e = 1/G_e across the coil inductance'),
    'coulomb_friction': EffectSpec(
        ('coulomb_friction_n',),
        {'coulomb_friction_n': 0.0},
        {'coulomb_friction_n': (0.0, 3.0)},
        'dry friction F_c opposing motion, stiction at zero velocity'),
    'coil_heating': EffectSpec(
        ('thermal_resistance_k_per_w', 'thermal_time_constant_s'),
        {'thermal_resistance_k_per_w': 0.0, 'thermal_time_constant_s': 60.0},
        {'thermal_resistance_k_per_w': (0.0, 200.0), 'thermal_time_constant_s': (1.0, 1000.0)},
        'copper self-heating: R = R0 (1 + 0.00393/K dT), dT first order with R_th, tau_th'),
    'leakage_inductance': EffectSpec(
        ('leakage_inductance_h',),
        {'leakage_inductance_h': 0.0},
        {'leakage_inductance_h': (0.0, 0.05)},
        'constant series inductance that stores no force-producing energy'),
    'end_stop_bounce': EffectSpec(
        ('restitution_coefficient',),
        {'restitution_coefficient': 0.0},
        {'restitution_coefficient': (0.0, 0.9)},
        'coefficient of restitution at both end stops (0 = plastic stop, the paper)'),
}

#: YAML section of each non-effect field.
SECTIONS: dict[str, tuple[str, ...]] = {
    'valve': (
        'spool_mass_kg', 'spring_stiffness_n_per_m', 'coil_turns', 'area_a1_m2',
        'area_a2_m2', 'area_a3_m2', 'area_a4_m2', 'core_length_m', 'coil_resistance_ohm',
        'stroke_m', 'core_area_m2', 'spring_pretension_m', 'total_air_gap_m',
        'damping_n_s_per_m', 'relative_permeability',
    ),
    'orifice': (
        'discharge_coefficient', 'orifice_area_gradient_m', 'supply_temperature_k',
        'gas_constant_j_per_kg_k', 'heat_capacity_ratio',
    ),
}


@dataclasses.dataclass(frozen=True)
class ValveParameters:
    """Parameters of the valve model, SI units (paper symbols and Table values in brackets).

    Attributes
    ----------
    spool_mass_kg : float
        m_s, spool mass [Table 1: 27 g].
    spring_stiffness_n_per_m : float
        k, return spring stiffness [10 000 N/m].
    coil_turns : float
        N, number of coil turns [1250].
    area_a1_m2, area_a2_m2, area_a3_m2, area_a4_m2 : float
        A_1..A_4, spool land areas of eq. (10) [26.57, 35.25, 55.86, 55.86 mm^2].
    core_length_m : float
        l_c, magnetic path length in the core [Table 2: 11.5 cm].
    coil_resistance_ohm : float
        R, coil resistance at the reference temperature [13 ohm].
    stroke_m : float
        x_max, the open end stop [0.33 mm]; must be below ``total_air_gap_m``.
    core_area_m2 : float
        A_e, effective flux cross section [0.8 cm^2].
    spring_pretension_m : float
        delta, spring pre-tension [1.1 mm].
    total_air_gap_m : float
        x_t, total air gap (travelling plus holding gap) [0.4 mm].
    damping_n_s_per_m : float
        b, viscous damping [0.2 N s/m].
    relative_permeability : float
        mu_r, relative permeability of the core [120].
    discharge_coefficient : float
        C_d of eq. (12) (not in the paper; our choice).
    orifice_area_gradient_m : float
        C_A of eq. (12): orifice area per metre of spool travel, m^2/m.
    supply_temperature_k : float
        T of eq. (12).
    gas_constant_j_per_kg_k : float
        R of eq. (12), specific gas constant of air.
    heat_capacity_ratio : float
        gamma of eq. (12).
    saturation_coefficient_per_a : float
        magnetic_saturation effect: beta = 1/i_sat (0 = off).
    eddy_conductance_s : float
        eddy_current effect: G_e = 1/R_e (0 = off).
    coulomb_friction_n : float
        coulomb_friction effect: F_c (0 = off).
    thermal_resistance_k_per_w : float
        coil_heating effect: R_th (0 = off).
    thermal_time_constant_s : float
        coil_heating effect: tau_th.
    leakage_inductance_h : float
        leakage_inductance effect: L_leak (0 = off).
    restitution_coefficient : float
        end_stop_bounce effect: e in [0, 1) (0 = plastic stop, the paper).
    """

    spool_mass_kg: float = 0.027
    spring_stiffness_n_per_m: float = 10000.0
    coil_turns: float = 1250.0
    area_a1_m2: float = 26.57e-6
    area_a2_m2: float = 35.25e-6
    area_a3_m2: float = 55.86e-6
    area_a4_m2: float = 55.86e-6
    core_length_m: float = 0.115
    coil_resistance_ohm: float = 13.0
    stroke_m: float = 0.33e-3
    core_area_m2: float = 0.8e-4
    spring_pretension_m: float = 1.1e-3
    total_air_gap_m: float = 0.4e-3
    damping_n_s_per_m: float = 0.2
    relative_permeability: float = 120.0
    discharge_coefficient: float = 0.8
    orifice_area_gradient_m: float = 6.283e-3
    supply_temperature_k: float = 293.15
    gas_constant_j_per_kg_k: float = 287.0
    heat_capacity_ratio: float = 1.4
    saturation_coefficient_per_a: float = 0.0
    eddy_conductance_s: float = 0.0
    coulomb_friction_n: float = 0.0
    thermal_resistance_k_per_w: float = 0.0
    thermal_time_constant_s: float = 60.0
    leakage_inductance_h: float = 0.0
    restitution_coefficient: float = 0.0

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if isinstance(value, bool) or not isinstance(value, (int, float, np.floating,
                                                                 np.integer)):
                raise ParameterError(
                    f'{f.name} must be a number, got {value!r}')
            value = float(value)
            if not math.isfinite(value):
                raise ParameterError(f'{f.name} must be finite, got {value!r}')
            object.__setattr__(self, f.name, value)
        _validate(self)

    # --- construction / conversion -------------------------------------------------------
    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> ValveParameters:
        """Build from the nested YAML structure (sections ``valve``, ``orifice``, ``effects``).

        Parameters
        ----------
        data : mapping
            ``{'valve': {...}, 'orifice': {...}, 'effects': {name: {...}}}``. ``valve`` and
            ``orifice`` must list every field; ``effects`` and each effect may be omitted
            (neutral values). A flat mapping of field names is also accepted (all non-effect
            fields required).

        Raises
        ------
        ParameterError
            On a missing or unknown key or an invalid value (names field and value).
        """
        if not isinstance(data, Mapping):
            raise ParameterError(f'parameter data must be a mapping, got {type(data).__name__}')
        if not (set(data) & (set(SECTIONS) | {'effects'})):
            return cls._from_flat(data)
        values: dict[str, Any] = {}
        for key in data:
            if key not in SECTIONS and key != 'effects':
                raise ParameterError(
                    f'unknown parameter section {key!r} (expected valve, orifice, effects)')
        for section, names in SECTIONS.items():
            block = data.get(section)
            if not isinstance(block, Mapping):
                raise ParameterError(f'missing parameter section {section!r}')
            for key in block:
                if key not in names:
                    raise ParameterError(
                        f'unknown parameter {key!r} = {block[key]!r} in section {section!r}')
            for name in names:
                if name not in block:
                    raise ParameterError(f'missing parameter {name!r} in section {section!r}')
                values[name] = block[name]
        effects = data.get('effects') or {}
        if not isinstance(effects, Mapping):
            raise ParameterError(f'effects must be a mapping, got {effects!r}')
        for effect, block in effects.items():
            if effect not in EFFECTS:
                raise ParameterError(
                    f'unknown effect {effect!r} (expected one of {", ".join(EFFECTS)})')
            block = block or {}
            if not isinstance(block, Mapping):
                raise ParameterError(f'effect {effect!r} must be a mapping, got {block!r}')
            for key, value in block.items():
                if key not in EFFECTS[effect].fields:
                    raise ParameterError(
                        f'unknown parameter {key!r} = {value!r} in effect {effect!r}')
                values[key] = value
        return cls(**values)

    @classmethod
    def _from_flat(cls, data: Mapping[str, Any]) -> ValveParameters:
        names = {f.name for f in dataclasses.fields(cls)}
        for key in data:
            if key not in names:
                raise ParameterError(f'unknown parameter {key!r} = {data[key]!r}')
        for section, fields in SECTIONS.items():
            for name in fields:
                if name not in data:
                    raise ParameterError(f'missing parameter {name!r} (section {section!r})')
        return cls(**dict(data))

    def to_dict(self) -> dict[str, Any]:
        """Return the nested structure that :meth:`from_dict` and the YAML file use."""
        out: dict[str, Any] = {s: {n: getattr(self, n) for n in names}
                               for s, names in SECTIONS.items()}
        out['effects'] = {e: {n: getattr(self, n) for n in spec.fields}
                          for e, spec in EFFECTS.items()}
        return out

    def replace(self, **changes: float) -> ValveParameters:
        """Return a validated copy with ``changes`` applied (unknown names refused)."""
        names = {f.name for f in dataclasses.fields(self)}
        for key in changes:
            if key not in names:
                raise ParameterError(f'unknown parameter {key!r} = {changes[key]!r}')
        return dataclasses.replace(self, **changes)

    def to_vector(self) -> np.ndarray:
        """Return the float64 vector in :data:`PARAMETER_FIELDS` order (kernel input)."""
        return np.array([getattr(self, n) for n in PARAMETER_FIELDS], dtype=np.float64)

    @classmethod
    def from_vector(cls, vector: np.ndarray) -> ValveParameters:
        """Inverse of :meth:`to_vector` (validated)."""
        vector = np.asarray(vector, dtype=np.float64)
        if vector.shape != (len(PARAMETER_FIELDS),):
            raise ParameterError(
                f'parameter vector must have shape ({len(PARAMETER_FIELDS)},), '
                f'got {vector.shape}')
        return cls(**{n: float(v) for n, v in zip(PARAMETER_FIELDS, vector)})

    def active_effects(self) -> tuple[str, ...]:
        """Names of the effects that these parameters switch on."""
        return tuple(name for name, spec in EFFECTS.items() if spec.is_active(self))


#: Field order of :meth:`ValveParameters.to_vector` and of batch parameter matrices.
PARAMETER_FIELDS: tuple[str, ...] = tuple(f.name for f in dataclasses.fields(ValveParameters))

_POSITIVE = (
    'spool_mass_kg', 'spring_stiffness_n_per_m', 'coil_turns', 'area_a1_m2', 'area_a2_m2',
    'area_a3_m2', 'area_a4_m2', 'core_length_m', 'coil_resistance_ohm', 'stroke_m',
    'core_area_m2', 'total_air_gap_m', 'relative_permeability', 'discharge_coefficient',
    'orifice_area_gradient_m', 'supply_temperature_k', 'gas_constant_j_per_kg_k',
    'thermal_time_constant_s',
)
_NON_NEGATIVE = (
    'spring_pretension_m', 'damping_n_s_per_m', 'saturation_coefficient_per_a',
    'eddy_conductance_s', 'coulomb_friction_n', 'thermal_resistance_k_per_w',
    'leakage_inductance_h', 'restitution_coefficient',
)


def _validate(p: ValveParameters) -> None:
    for name in _POSITIVE:
        value = getattr(p, name)
        if value <= 0.0:
            raise ParameterError(f'{name} must be positive, got {value!r}')
    for name in _NON_NEGATIVE:
        value = getattr(p, name)
        if value < 0.0:
            raise ParameterError(f'{name} must be non-negative, got {value!r}')
    if p.stroke_m >= p.total_air_gap_m:
        # eq. (2): the holding gap x_t - x_max must stay open, else L(x_max) is unbounded.
        raise ParameterError(
            f'stroke_m must be below total_air_gap_m ({p.total_air_gap_m!r}), '
            f'got {p.stroke_m!r}')
    if p.discharge_coefficient > 1.0:
        raise ParameterError(
            f'discharge_coefficient must be at most 1, got {p.discharge_coefficient!r}')
    if p.heat_capacity_ratio <= 1.0:
        raise ParameterError(
            f'heat_capacity_ratio must be above 1, got {p.heat_capacity_ratio!r}')
    if p.restitution_coefficient >= 1.0:
        raise ParameterError(
            f'restitution_coefficient must be below 1, got {p.restitution_coefficient!r}')


def default_parameters_path() -> Path:
    """Path of the packaged ``config/valve.yaml`` (source tree or ament share directory).

    Raises
    ------
    FileNotFoundError
        If neither location holds the file.
    """
    here = Path(__file__).resolve()
    candidates = [here.parents[2] / 'config' / 'valve.yaml']
    prefix = os.environ.get('AMENT_PREFIX_PATH', '')
    for root in filter(None, prefix.split(os.pathsep)):
        candidates.append(Path(root) / 'share' / 'valve_model_pkg' / 'config' / 'valve.yaml')
    for path in candidates:
        if path.is_file():
            return path
    raise FileNotFoundError(
        'valve.yaml not found; looked in ' + ', '.join(str(c) for c in candidates))


def load_parameters(path: str | os.PathLike[str] | None = None) -> ValveParameters:
    """Load and validate a parameter YAML file (default: :func:`default_parameters_path`).

    Raises
    ------
    ParameterError
        On YAML syntax errors, missing/unknown keys or invalid values; the message names
        the file.
    FileNotFoundError
        If the file does not exist.
    """
    path = Path(path) if path is not None else default_parameters_path()
    text = path.read_text(encoding='utf-8')
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as err:
        raise ParameterError(f'{path}: not valid YAML: {err}') from err
    try:
        return ValveParameters.from_dict(data if data is not None else {})
    except ParameterError as err:
        raise ParameterError(f'{path}: {err}') from err
