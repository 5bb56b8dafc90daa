"""ROS-free static duty map of the valve (paper Section 5): generation, file, inversion.

- :mod:`.steady_state`: periodic-steady-state detection from period averages;
- :mod:`.generation`: :func:`generate_map` on a grid of duties, pressures, frequencies;
- :mod:`.dutymap`: :class:`DutyMap` and its versioned JSON file (parameter set + hash);
- :mod:`.curves`: dead band, saturation and effective width of a curve;
- :mod:`.inversion`: eq. (12) solved for the opening and the map inverted (flow -> duty);
- :mod:`.flow_check`: measured ``flow_map`` files against the map (Fig. 10);
- :mod:`.plots`: Figs. 8, 9 and 10 as PNG.

The generation needs the model (numba); reading a map and inverting it do not run it.
"""
from .curves import DEFAULT_STOP_TOLERANCE, CurveFeatures, curve_features, monotone_envelope
from .dutymap import (DEFAULT_MAP_FILENAME, FORMAT_NAME, FORMAT_VERSION, DutyMap,
                      default_map_path, load_map, parameters_hash)
from ..errors import (FlowMapFormatError, MapError, MapFormatError, MapGenerationError,
                      MapParameterMismatchError)
from .inversion import (ATMOSPHERIC_PRESSURE_PA, FlowStatus, FlowToDutyInverter,
                        FlowToDutyResult, OrificeConstants, flow_per_opening,
                        invalid_flow_reason)
from .steady_state import SteadyState, SteadyStateCriterion, detect_steady_state

__all__ = [
    'ATMOSPHERIC_PRESSURE_PA', 'CurveFeatures', 'DEFAULT_MAP_FILENAME',
    'DEFAULT_STOP_TOLERANCE', 'DutyMap', 'FORMAT_NAME', 'FORMAT_VERSION', 'FlowMapFormatError',
    'FlowStatus', 'FlowToDutyInverter', 'FlowToDutyResult', 'MapError', 'MapFormatError',
    'MapGenerationError', 'MapParameterMismatchError', 'OrificeConstants', 'SteadyState',
    'SteadyStateCriterion', 'curve_features', 'default_map_path', 'detect_steady_state',
    'flow_per_opening', 'invalid_flow_reason', 'load_map', 'monotone_envelope',
    'parameters_hash',
]
