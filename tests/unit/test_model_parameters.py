"""ValveParameters: YAML loading, validation, conversions, effects table."""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import yaml

from valve_model_pkg.model import (
    EFFECTS, PARAMETER_FIELDS, ParameterError, ValveParameters, default_parameters_path,
    load_parameters,
)


def test_packaged_yaml_is_the_paper_set() -> None:
    p = load_parameters(default_parameters_path())
    assert p == ValveParameters()
    # Table 1 and Table 2 (identified), SI
    assert p.spool_mass_kg == pytest.approx(0.027)
    assert p.spring_stiffness_n_per_m == pytest.approx(1.0e4)
    assert p.coil_turns == 1250
    assert p.area_a1_m2 == pytest.approx(26.57e-6)
    assert p.area_a2_m2 == pytest.approx(35.25e-6)
    assert p.area_a3_m2 == p.area_a4_m2 == pytest.approx(55.86e-6)
    assert p.core_length_m == pytest.approx(0.115)
    assert p.coil_resistance_ohm == pytest.approx(13.0)
    assert p.stroke_m == pytest.approx(0.33e-3)
    assert p.core_area_m2 == pytest.approx(0.8e-4)
    assert p.spring_pretension_m == pytest.approx(1.1e-3)
    assert p.total_air_gap_m == pytest.approx(0.4e-3)
    assert p.damping_n_s_per_m == pytest.approx(0.2)
    assert p.relative_permeability == pytest.approx(120.0)
    assert p.active_effects() == ()


def test_dict_and_vector_round_trip() -> None:
    p = ValveParameters().replace(coulomb_friction_n=0.5, restitution_coefficient=0.3)
    assert ValveParameters.from_dict(p.to_dict()) == p
    assert ValveParameters.from_vector(p.to_vector()) == p
    assert p.to_vector().shape == (len(PARAMETER_FIELDS),)
    assert set(p.active_effects()) == {'coulomb_friction', 'end_stop_bounce'}


def test_frozen() -> None:
    p = ValveParameters()
    with pytest.raises(dataclasses.FrozenInstanceError):
        p.spool_mass_kg = 1.0  # type: ignore[misc]


@pytest.mark.parametrize('field, value, match', [
    ('spool_mass_kg', 0.0, r'spool_mass_kg must be positive, got 0\.0'),
    ('spool_mass_kg', -0.027, r'spool_mass_kg must be positive, got -0\.027'),
    ('stroke_m', 0.4e-3, r'stroke_m must be below total_air_gap_m .*got 0\.0004'),
    ('stroke_m', 0.5e-3, r'stroke_m must be below total_air_gap_m'),
    ('coil_resistance_ohm', math.nan, r'coil_resistance_ohm must be finite, got nan'),
    ('damping_n_s_per_m', math.inf, r'damping_n_s_per_m must be finite, got inf'),
    ('restitution_coefficient', 1.0, r'restitution_coefficient must be below 1, got 1\.0'),
    ('coulomb_friction_n', -1.0, r'coulomb_friction_n must be non-negative, got -1\.0'),
    ('heat_capacity_ratio', 1.0, r'heat_capacity_ratio must be above 1'),
    ('coil_turns', 'many', r"coil_turns must be a number, got 'many'"),
])
def test_invalid_values_are_refused(field: str, value: object, match: str) -> None:
    with pytest.raises(ParameterError, match=match):
        ValveParameters().replace(**{field: value})
    assert issubclass(ParameterError, ValueError)


def _write(tmp_path, data) -> object:
    path = tmp_path / 'p.yaml'
    path.write_text(yaml.safe_dump(data))
    return path


def test_missing_key_in_yaml(tmp_path) -> None:
    data = ValveParameters().to_dict()
    del data['valve']['spool_mass_kg']
    with pytest.raises(ParameterError, match=r"p\.yaml: missing parameter 'spool_mass_kg'"):
        load_parameters(_write(tmp_path, data))


def test_unknown_key_in_yaml(tmp_path) -> None:
    data = ValveParameters().to_dict()
    data['valve']['spool_mas_kg'] = 0.027
    with pytest.raises(ParameterError, match=r"unknown parameter 'spool_mas_kg' = 0\.027"):
        load_parameters(_write(tmp_path, data))
    data = ValveParameters().to_dict()
    data['effects']['magic'] = {}
    with pytest.raises(ParameterError, match=r"unknown effect 'magic'"):
        load_parameters(_write(tmp_path, data))


def test_invalid_value_in_yaml_names_field_and_value(tmp_path) -> None:
    data = ValveParameters().to_dict()
    data['valve']['spool_mass_kg'] = -1
    with pytest.raises(ParameterError, match=r'spool_mass_kg must be positive, got -1'):
        load_parameters(_write(tmp_path, data))
    data['valve']['spool_mass_kg'] = '.nan'
    path = tmp_path / 'nan.yaml'
    path.write_text(yaml.safe_dump(data).replace("'.nan'", '.nan'))
    with pytest.raises(ParameterError, match=r'spool_mass_kg must be finite, got nan'):
        load_parameters(path)


def test_effects_section_optional(tmp_path) -> None:
    data = ValveParameters().to_dict()
    del data['effects']
    assert load_parameters(_write(tmp_path, data)) == ValveParameters()
    data['effects'] = {'coulomb_friction': {'coulomb_friction_n': 0.7}}
    assert load_parameters(_write(tmp_path, data)).coulomb_friction_n == 0.7


def test_bad_yaml_and_empty_file(tmp_path) -> None:
    path = tmp_path / 'bad.yaml'
    path.write_text('valve: [1, 2\n')
    with pytest.raises(ParameterError, match='not valid YAML'):
        load_parameters(path)
    path.write_text('')
    with pytest.raises(ParameterError, match='missing parameter'):
        load_parameters(path)


def test_effects_table_is_consistent() -> None:
    assert tuple(EFFECTS) == ('magnetic_saturation', 'eddy_current', 'coulomb_friction',
                              'coil_heating', 'leakage_inductance', 'end_stop_bounce')
    default = ValveParameters()
    for name, spec in EFFECTS.items():
        for field in spec.fields:
            assert field in PARAMETER_FIELDS
            assert getattr(default, field) == spec.neutral[field], (name, field)
            lo, hi = spec.bounds[field]
            assert lo <= spec.neutral[field] <= hi
            # the bounds themselves are valid parameter values (hi for e is below 1)
            default.replace(**{field: lo})
            default.replace(**{field: hi})
    # every effect switches on with its upper bound
    for name, spec in EFFECTS.items():
        changed = default.replace(**{spec.fields[0]: spec.bounds[spec.fields[0]][1]})
        assert name in changed.active_effects()


def test_vector_shape_checked() -> None:
    with pytest.raises(ParameterError, match='shape'):
        ValveParameters.from_vector(np.zeros(3))
