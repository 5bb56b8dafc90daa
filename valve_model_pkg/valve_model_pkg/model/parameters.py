"""Typed, validated parameter set of the valve model (Tables 1 and 2 of the paper).

All values are SI. The set is a frozen dataclass so identification can copy and vary it
safely; ``replace`` returns a validated copy. ``to_vector`` / ``from_vector`` give the flat
float vector in :data:`PARAMETER_FIELDS` order used by the compiled kernel and the batch API.
"""
from __future__ import annotations

import dataclasses
import logging
import math
import os
import re
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from ..errors import ParameterError

__all__ = [
    'ParameterError',
    'ValveParameters',
    'EffectSpec',
    'EFFECTS',
    'EMULATOR_EFFECTS',
    'PARAMETER_FIELDS',
    'SECTIONS',
    'load_parameters',
    'default_parameters_path',
    'PLAUSIBLE_RANGES',
    'SAFE_RANGE_FACTOR',
    'MAX_PARAMETER_FILE_BYTES',
    'implausible_values',
]

_LOG = logging.getLogger(__name__)


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
    demo : dict
        Field -> value an emulator ``--effect NAME`` without values sets (emulator forms
        only; the identification's effects take a fraction of ``bounds`` instead).
    """

    fields: tuple[str, ...]
    neutral: dict[str, float]
    bounds: dict[str, tuple[float, float]]
    description: str
    demo: dict[str, float] = dataclasses.field(default_factory=dict)

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

#: Effect forms of the emulated valve only, written independently of
#: the identification's candidates in :data:`EFFECTS`: a valve emulated with one of these
#: is not the candidate's own equation, so a loop test that names the right effect is not
#: circular. They are NOT candidates of the identification (``diagnosis`` iterates
#: :data:`EFFECTS` only) and default to off (bit-identical outputs). Equations: the kernel
#: modules (``magnetics._tanh_flux_partials``, ``electrical._ladder_derivatives``) and
#: docs/effects.md. The demo values make each visible in the 1 kHz interval-mean current
#: of a 24 V bench step (at most 11 % / 8 % of the 1.85 A final current, within 20 ms).
EMULATOR_EFFECTS: dict[str, EffectSpec] = {
    'saturation_tanh': EffectSpec(
        ('saturation_tanh_flux_linkage_wb',),
        {'saturation_tanh_flux_linkage_wb': 0.0},
        {'saturation_tanh_flux_linkage_wb': (0.05, 1.0)},
        'emulator form of magnetic saturation (not the candidate): flux linkage '
        'lambda_s tanh(L(x) i / lambda_s), a fixed saturation flux whose knee current '
        'lambda_s / L(x) moves with the air gap; force from the co-energy',
        {'saturation_tanh_flux_linkage_wb': 0.25}),
    'eddy_ladder': EffectSpec(
        ('eddy_ladder_inductance_ratio', 'eddy_ladder_resistance_ohm'),
        {'eddy_ladder_inductance_ratio': 0.0, 'eddy_ladder_resistance_ohm': 20.0},
        {'eddy_ladder_inductance_ratio': (0.0, 3.0),
         'eddy_ladder_resistance_ohm': (1.0, 200.0)},
        'emulator form of eddy currents (not the candidate): the inductance split into '
        'a fast part L/(1+r) in series with a slow part r L/(1+r) shunted by R_b (a '
        'one-rung Foster ladder, two time constants; no resistive path at high frequency)',
        {'eddy_ladder_inductance_ratio': 1.0, 'eddy_ladder_resistance_ohm': 20.0}),
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
    saturation_tanh_flux_linkage_wb : float
        Emulator form ``saturation_tanh`` (not a candidate): saturation flux linkage
        lambda_s, Wb; lambda = lambda_s tanh(L(x) i / lambda_s) (0 = off).
    eddy_ladder_inductance_ratio : float
        Emulator form ``eddy_ladder`` (not a candidate): r = L_slow / L_fast of the
        inductance split (0 = off).
    eddy_ladder_resistance_ohm : float
        Emulator form ``eddy_ladder``: R_b, the eddy path shunting the slow part, ohm.
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
    # emulator effect forms (EMULATOR_EFFECTS); appended so the candidate fields keep
    # their vector positions
    saturation_tanh_flux_linkage_wb: float = 0.0
    eddy_ladder_inductance_ratio: float = 0.0
    eddy_ladder_resistance_ohm: float = 20.0

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if isinstance(value, bool) or not isinstance(value, (int, float, np.floating,
                                                                 np.integer)):
                raise ParameterError(
                    f'{f.name} must be a number, got {value!r}', key=f.name)
            value = float(value)
            if not math.isfinite(value):
                raise ParameterError(f'{f.name} must be finite, got {value!r}', key=f.name)
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
                    f'unknown parameter section {key!r} (expected valve, orifice, effects)',
                    key=key)
        for section, names in SECTIONS.items():
            block = data.get(section)
            if not isinstance(block, Mapping):
                raise ParameterError(f'missing parameter section {section!r}')
            for key in block:
                if key not in names:
                    raise ParameterError(
                        f'unknown parameter {key!r} = {block[key]!r} in section {section!r}',
                        key=key)
            for name in names:
                if name not in block:
                    raise ParameterError(f'missing parameter {name!r} in section {section!r}')
                values[name] = block[name]
        effects = data.get('effects') or {}
        if not isinstance(effects, Mapping):
            raise ParameterError(f'effects must be a mapping, got {effects!r}')
        for effect, block in effects.items():
            spec = EFFECTS.get(effect) or EMULATOR_EFFECTS.get(effect)
            if spec is None:
                raise ParameterError(
                    f'unknown effect {effect!r} (expected one of {", ".join(EFFECTS)}; '
                    f'emulator forms: {", ".join(EMULATOR_EFFECTS)})', key=effect)
            block = block or {}
            if not isinstance(block, Mapping):
                raise ParameterError(f'effect {effect!r} must be a mapping, got {block!r}')
            for key, value in block.items():
                if key not in spec.fields:
                    raise ParameterError(
                        f'unknown parameter {key!r} = {value!r} in effect {effect!r}', key=key)
                values[key] = value
        return cls(**values)

    @classmethod
    def _from_flat(cls, data: Mapping[str, Any]) -> ValveParameters:
        names = {f.name for f in dataclasses.fields(cls)}
        for key in data:
            if key not in names:
                raise ParameterError(f'unknown parameter {key!r} = {data[key]!r}', key=key)
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
        # emulator forms only when set, so identified parameter files look as before
        for e, spec in EMULATOR_EFFECTS.items():
            if any(getattr(self, n) != spec.neutral[n] for n in spec.fields):
                out['effects'][e] = {n: getattr(self, n) for n in spec.fields}
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
        """Names of the effects (candidates, then emulator forms) these parameters switch on."""
        return tuple(name for registry in (EFFECTS, EMULATOR_EFFECTS)
                     for name, spec in registry.items() if spec.is_active(self))


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
    'leakage_inductance_h', 'restitution_coefficient', 'saturation_tanh_flux_linkage_wb',
    'eddy_ladder_inductance_ratio', 'eddy_ladder_resistance_ohm',
)


#: Physically plausible range (low, high) of every parameter, SI units, for a fast
#: switching solenoid valve of the paper's kind (with generous margins either side). A
#: parameter file with a value outside is refused by :func:`load_parameters` unless
#: ``allow_implausible`` (``--allow-implausible``) accepts it with a warning.
PLAUSIBLE_RANGES: dict[str, tuple[float, float]] = {
    'spool_mass_kg': (1e-4, 1.0),                 # 0.1 g .. 1 kg
    'spring_stiffness_n_per_m': (1.0, 1e7),       # N/m
    'coil_turns': (1.0, 1e5),
    'area_a1_m2': (1e-9, 1e-2),                   # 0.001 mm^2 .. 100 cm^2
    'area_a2_m2': (1e-9, 1e-2),
    'area_a3_m2': (1e-9, 1e-2),
    'area_a4_m2': (1e-9, 1e-2),
    'core_length_m': (1e-3, 1.0),
    'coil_resistance_ohm': (1e-2, 1e4),
    'stroke_m': (1e-6, 5e-2),
    'core_area_m2': (1e-7, 1e-2),
    'spring_pretension_m': (0.0, 0.1),
    'total_air_gap_m': (1e-6, 5e-2),
    'damping_n_s_per_m': (0.0, 1e4),
    'relative_permeability': (1.0, 1e6),
    'discharge_coefficient': (0.01, 1.0),
    'orifice_area_gradient_m': (1e-5, 1.0),       # m^2 of orifice per m of stroke
    'supply_temperature_k': (150.0, 600.0),
    'gas_constant_j_per_kg_k': (50.0, 5000.0),    # air 287, helium 2077, hydrogen 4124
    'heat_capacity_ratio': (1.0, 1.7),
    'saturation_coefficient_per_a': (0.0, 100.0),
    'eddy_conductance_s': (0.0, 10.0),
    'coulomb_friction_n': (0.0, 1e3),
    'thermal_resistance_k_per_w': (0.0, 1e4),
    'thermal_time_constant_s': (1e-2, 1e5),
    'leakage_inductance_h': (0.0, 10.0),
    'restitution_coefficient': (0.0, 1.0),
    'saturation_tanh_flux_linkage_wb': (0.0, 100.0),
    'eddy_ladder_inductance_ratio': (0.0, 100.0),
    'eddy_ladder_resistance_ohm': (0.0, 1e6),
}

#: Beyond the plausible range widened by this factor on either side a value is refused
#: always (``allow_implausible`` or not): such values (a 1e-300 kg spool, 1e300 N/m) only
#: make the integrator divide by zero or overflow, so they never reach the kernel.
SAFE_RANGE_FACTOR = 1e3


def _safe_range(name: str) -> tuple[float, float]:
    lo, hi = PLAUSIBLE_RANGES[name]
    # the 1e-12 keeps the printed edges (1e-07) themselves inside despite rounding
    return lo / SAFE_RANGE_FACTOR * (1.0 - 1e-12), hi * SAFE_RANGE_FACTOR * (1.0 + 1e-12)


def implausible_values(params: ValveParameters) -> list[tuple[str, float, tuple[float, float]]]:
    """The parameters outside their :data:`PLAUSIBLE_RANGES`.

    Returns
    -------
    list of (str, float, (float, float))
        ``(name, value, (low, high))`` for each, in :data:`PARAMETER_FIELDS` order.
    """
    out = []
    for name in PARAMETER_FIELDS:
        lo, hi = PLAUSIBLE_RANGES[name]
        value = getattr(params, name)
        if not lo <= value <= hi:
            out.append((name, value, (lo, hi)))
    return out


def _validate(p: ValveParameters) -> None:
    for name in _POSITIVE:
        value = getattr(p, name)
        if value <= 0.0:
            raise ParameterError(f'{name} must be positive, got {value!r}', key=name)
    for name in _NON_NEGATIVE:
        value = getattr(p, name)
        if value < 0.0:
            raise ParameterError(f'{name} must be non-negative, got {value!r}', key=name)
    if p.stroke_m >= p.total_air_gap_m:
        # eq. (2): the holding gap x_t - x_max must stay open, else L(x_max) is unbounded.
        raise ParameterError(
            f'stroke_m must be below total_air_gap_m ({p.total_air_gap_m!r}), '
            f'got {p.stroke_m!r}', key='stroke_m')
    if p.discharge_coefficient > 1.0:
        raise ParameterError(
            f'discharge_coefficient must be at most 1, got {p.discharge_coefficient!r}',
            key='discharge_coefficient')
    if p.heat_capacity_ratio <= 1.0:
        raise ParameterError(
            f'heat_capacity_ratio must be above 1, got {p.heat_capacity_ratio!r}',
            key='heat_capacity_ratio')
    for name in PARAMETER_FIELDS:
        lo, hi = _safe_range(name)
        value = getattr(p, name)
        if not lo <= value <= hi:
            raise ParameterError(
                f'{name} = {value!r} is outside the numerically safe range [{lo:g}, {hi:g}] '
                f'(plausible: [{PLAUSIBLE_RANGES[name][0]:g}, {PLAUSIBLE_RANGES[name][1]:g}])',
                key=name)
    if p.restitution_coefficient >= 1.0:
        raise ParameterError(
            f'restitution_coefficient must be below 1, got {p.restitution_coefficient!r}',
            key='restitution_coefficient')


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


#: A parameter file is a few kB; anything beyond this is refused before it is read.
MAX_PARAMETER_FILE_BYTES = 1 << 20

# YAML 1.2 core-schema floats: PyYAML's resolver is YAML 1.1's, which wants a dot in the
# mantissa and reads 27e-3 or 1e300 as strings.
_YAML12_FLOAT = re.compile(r'''^(?:
    [-+]?(?:[0-9][0-9_]*)(?:\.[0-9_]*)?(?:[eE][-+]?[0-9]+)?
  | [-+]?\.[0-9_]+(?:[eE][-+]?[0-9]+)?
  | [-+]?\.(?:inf|Inf|INF)
  | \.(?:nan|NaN|NAN))$''', re.X)


class _ParameterLoader(yaml.SafeLoader):
    """SafeLoader with YAML 1.2 floats; duplicate keys are found on the node tree."""


_ParameterLoader.add_implicit_resolver('tag:yaml.org,2002:float', _YAML12_FLOAT,
                                       list('-+0123456789.'))


def _one_line(text: str) -> str:
    return ' '.join(str(text).split())


def _key_lines(node: yaml.Node | None, path: str) -> dict[str, int]:
    """Line of every mapping key (1-based) by key name; refuses duplicate keys.

    Field names are unique across sections, so a flat name -> line map is enough.
    """
    lines: dict[str, int] = {}
    stack = [node] if node is not None else []
    while stack:
        current = stack.pop()
        if isinstance(current, yaml.MappingNode):
            seen: dict[object, int] = {}
            for key_node, value_node in current.value:
                line = key_node.start_mark.line + 1
                key = key_node.value if isinstance(key_node, yaml.ScalarNode) else None
                if key is not None and key in seen:
                    raise ParameterError(
                        f'{path}:{line}: duplicate key {key!r} (first on line {seen[key]}); '
                        'a key may be given once', key=key)
                if key is not None:
                    seen[key] = line
                    lines.setdefault(key, line)
                stack.append(value_node)
        elif isinstance(current, yaml.SequenceNode):
            stack.extend(current.value)
    return lines


def _read_parameter_text(path: Path) -> str:
    """The file as text; binary, oversized and non-UTF-8 files are refused."""
    try:
        size = path.stat().st_size
    except FileNotFoundError:
        raise
    except OSError as err:
        raise ParameterError(f'{path}: cannot be read: {err.strerror}') from err
    if size > MAX_PARAMETER_FILE_BYTES:
        raise ParameterError(f'{path}: is {size} bytes; a parameter file may have at most '
                             f'{MAX_PARAMETER_FILE_BYTES} bytes')
    raw = path.read_bytes()
    nul = raw.find(b'\x00')
    if nul >= 0:
        line = raw[:nul].count(b'\n') + 1
        raise ParameterError(f'{path}:{line}: is a binary file, not YAML text (NUL byte at '
                             f'offset {nul})')
    try:
        return raw.decode('utf-8-sig')
    except UnicodeDecodeError as err:
        line = raw[:err.start].count(b'\n') + 1
        raise ParameterError(f'{path}:{line}: is not UTF-8 text (byte 0x{raw[err.start]:02x} '
                             f'at offset {err.start})') from err


def _yaml_document(path: Path, what: str) -> tuple[object, dict]:
    """The YAML document of ``path`` (None when empty) and the line of each top-level key.

    Parameters
    ----------
    path : Path
    what : str
        What the file should be, for the message of a too deeply nested one
        (``'a parameter file'``).

    Raises
    ------
    ParameterError
        One line naming the file (and the line when known): binary, not UTF-8, too large,
        not valid YAML, a duplicate key, nested too deeply.
    """
    text = _read_parameter_text(path)
    loader = _ParameterLoader(text)
    try:
        node = loader.get_single_node()
        lines = _key_lines(node, str(path))
        data = loader.construct_document(node) if node is not None else None
    except yaml.MarkedYAMLError as err:
        mark = err.problem_mark or err.context_mark
        where = f'{path}:{mark.line + 1}' if mark is not None else str(path)
        problem = ' '.join(x for x in (err.context, err.problem) if x)
        raise ParameterError(f'{where}: not valid YAML: {_one_line(problem)}') from err
    except yaml.YAMLError as err:
        raise ParameterError(f'{path}: not valid YAML: {_one_line(err)}') from err
    except RecursionError as err:
        raise ParameterError(f'{path}: not {what}: nested too deeply') from err
    finally:
        loader.dispose()
    return data, lines


def load_parameters(path: str | os.PathLike[str] | None = None, *,
                    allow_implausible: bool = False) -> ValveParameters:
    """Load and validate a parameter YAML file (default: :func:`default_parameters_path`).

    Numbers are read as YAML 1.2 does (``27e-3``, ``1e300`` are floats). Every parameter
    must lie in its :data:`PLAUSIBLE_RANGES` entry; values beyond the range widened by
    :data:`SAFE_RANGE_FACTOR` are refused in any case.

    Parameters
    ----------
    path : path-like, optional
        The YAML file.
    allow_implausible : bool
        Accept values outside :data:`PLAUSIBLE_RANGES` (but within the safe range) with a
        logged warning naming each, instead of refusing the file.

    Raises
    ------
    ParameterError
        One line naming the file (and the line when known), the key and the value: the
        file is binary, not UTF-8, larger than :data:`MAX_PARAMETER_FILE_BYTES`, not valid
        YAML, has a duplicate key, a missing/unknown key, an invalid or implausible value.
    FileNotFoundError
        If the file does not exist.
    """
    path = Path(path) if path is not None else default_parameters_path()
    data, lines = _yaml_document(path, 'a parameter file')
    try:
        params = ValveParameters.from_dict(data if data is not None else {})
        bad = implausible_values(params)
        for name, value, (lo, hi) in bad:
            if not allow_implausible:
                raise ParameterError(
                    f'{name} = {value!r} is physically implausible (plausible range '
                    f'[{lo:g}, {hi:g}]); use --allow-implausible (allow_implausible) to '
                    'accept it', key=name)
            line = lines.get(name)
            _LOG.warning('%s%s: %s = %r is outside the plausible range [%g, %g]; accepted '
                         '(allow_implausible)', path, f':{line}' if line else '', name,
                         value, lo, hi)
        return params
    except ParameterError as err:
        line = lines.get(err.key) if err.key is not None else None
        where = f'{path}:{line}' if line else str(path)
        raise ParameterError(f'{where}: {_one_line(err)}', key=err.key) from err
