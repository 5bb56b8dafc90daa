"""Analysis of suite runs from their bags: steps, tracking, the chamber, the flow, reports.

ROS-free: bags are read through :mod:`valve_model_pkg.recording` (and, as an operational
record of the valve, through the identification's reader); everything else is numpy.

- :mod:`.timebase`: every message on the run's clock (:func:`run_time_base`).
- :mod:`.steps`: settling time, overshoot and steady error per step (:func:`step_results`).
- :mod:`.tracking`: the position-tracking error (:func:`tracking_error`,
  :func:`run_tracking_error`; the goal sequences and their schedule:
  :mod:`valve_model_pkg.pneumatics.goals`).
- :mod:`.chamber`: the chamber of a run at each control tick (:func:`run_chamber`).
- :mod:`.flow_calibration`: the flow scale C_d C_A on the chamber's mass balance
  (:func:`calibrate_flow_scale`).
- :mod:`.flow_prediction`: parameter sets' flow against the chamber's
  (:func:`flow_prediction_error`).
- :mod:`.run_report`: ``report.md``, ``report.json`` and plots of a run
  (:func:`write_run_report`); :mod:`.plots` draws them.
"""
from __future__ import annotations

from .chamber import RunChamber, run_chamber, strictly_increasing
from .flow_calibration import (FLOW_CALIBRATION_WINDOW_S, FlowCalibration,
                               calibrate_flow_scale, full_opening_area_m2, map_opening_m)
from .flow_prediction import (FLOW_PREDICTION_WINDOW_S, FlowPrediction, FlowPredictionError,
                              flow_prediction_error, window_means)
from .run_report import (RunReport, TopicSummary, ValveSummary, topic_summaries,
                         valve_summary, write_run_report)
from .steps import MIN_SETTLED_DWELL_S, SETTLING_BAND_M, StepResult, step_results, steps_at
from .timebase import RunTimeBase, own_times_s, run_time_base
from .tracking import (GOALS_FROM_ACKNOWLEDGEMENT, GoalTimes, RunTracking, TrackingError,
                       acknowledged_goal_times, run_tracking_error, tracking_error)

__all__ = [
    'FLOW_CALIBRATION_WINDOW_S', 'FLOW_PREDICTION_WINDOW_S', 'FlowCalibration',
    'FlowPrediction', 'FlowPredictionError', 'GOALS_FROM_ACKNOWLEDGEMENT', 'GoalTimes',
    'MIN_SETTLED_DWELL_S', 'RunChamber', 'RunReport', 'RunTimeBase', 'RunTracking',
    'SETTLING_BAND_M', 'StepResult', 'TopicSummary', 'TrackingError',
    'ValveSummary', 'acknowledged_goal_times', 'calibrate_flow_scale', 'flow_prediction_error',
    'full_opening_area_m2', 'map_opening_m', 'own_times_s', 'run_chamber',
    'run_time_base', 'run_tracking_error', 'step_results', 'steps_at', 'strictly_increasing',
    'topic_summaries', 'tracking_error', 'valve_summary', 'window_means', 'write_run_report',
]
