"""loop.md of the loop in service (valve_bringup.loop_report): every figure of loop.json a
person needs, and what it says when the flow scale could not be calibrated."""
from __future__ import annotations

import copy

from valve_bringup.loop_report import loop_markdown

_RUN = {'nominal': {'rms_pct': 5.372}, 'identified': {'rms_pct': 1.525},
        'calibrated': {'rms_pct': 0.813}, 'window_s': 0.1}
LOOP = {
    'effect_injected': 'eddy_current',
    'diagnosis': {'effect': 'eddy_current', 'confidence': 'low'},
    'baseline': {'fit': {'iae': 0.0812, 'rmse': 0.0031},
                 'validation': {'iae': 0.0687, 'rmse': 0.00412}},
    'augmented': {'fit': {'iae': 0.0201}, 'validation': {'iae': 0.0166, 'rmse': 0.00105}},
    'plant': {'discharge_coefficient': 0.62, 'suite_discharge_coefficient': 0.8,
              'full_opening_area_m2': 1.2855e-6, 'suite_full_opening_area_m2': 1.6587e-6},
    'tracking': {'before': {'rms_mm': 10.3699, 'mean_abs_mm': 5.1, 'max_abs_mm': 40.0},
                 'after': {'rms_mm': 8.7865, 'mean_abs_mm': 4.2, 'max_abs_mm': 40.0}},
    'flow_calibration': {'prior_product_m': 5.0264e-3, 'product_m': 4.7279e-3, 'ratio': 0.9406,
                         'balance_error_pct': {'before': 12.04, 'after': 3.01},
                         'full_opening_area_m2': 1.245e-6, 'full_opening_error_pct': -3.15,
                         'suite_full_opening_error_pct': 29.03},
    'flow': {'record': 'after_run', 'full_flow_kg_s': 2.346e-3,
             'runs': {'before_run': _RUN, 'after_run': _RUN}},
    'stages_s': {'run_before': 92.0, 'identification': 728.7, 'total': 922.0},
    'identification': {'timings_s': {'baseline_fit': 200.3, 'note': 'text'}},
}


def test_loop_md_shows_the_diagnosis_the_errors_and_the_calibration() -> None:
    md = loop_markdown(LOOP)
    assert md.startswith('# The loop in service\n')
    assert '**eddy_current**; named by the identification: **eddy_current** (confidence ' \
        'low)' in md
    assert '| baseline (nominal equations) | 0.0812 | 0.0687 | 4.12 |' in md
    assert '| augmented (eddy_current) | 0.0201 | 0.0166 | 1.05 |' in md
    assert '| before | nominal parameters and map | 10.370 | 5.100 | 40.00 |' in md
    assert '| after | identified parameters and map (flow scale calibrated) | 8.787 |' in md
    assert '5.026 -> 4.728 mm (x 0.941; balance error 12.0 -> 3.0 %)' in md
    assert '-3.1 % off the valve in service (the suite\'s set: +29.0 %)' in md
    assert 'RMS error over 0.1 s windows in % of full flow (2.35 g/s' in md
    assert '| after run | 5.37 % | 1.52 % | 0.81 % |' in md
    assert '| identification | 728.7 |' in md
    assert 'Identification split: baseline_fit 200.3 s' in md and 'note' not in md


def test_loop_md_says_why_the_flow_scale_was_not_calibrated() -> None:
    loop = copy.deepcopy(LOOP)
    loop['flow_calibration'] = {'error': 'the valve never opens'}
    for run in loop['flow']['runs'].values():
        run.pop('calibrated', None)
    md = loop_markdown(loop)
    assert 'Flow scale not calibrated: the valve never opens' in md
    assert '(flow scale calibrated)' not in md
    assert '| after run | 5.37 % | 1.52 % | n/a |' in md
