"""``loop.md``: the loop in service's ``loop.json`` for a person (paths relative to the
loop's directory)."""
from __future__ import annotations

__all__ = ['loop_markdown']


def _figure(block: dict, part: str, key: str, scale: float = 1.0, fmt: str = '.4g') -> str:
    v = (block.get(part) or {}).get(key)
    return 'n/a' if v is None else format(v * scale, fmt)


def _head_lines(loop: dict) -> list[str]:
    diag = loop['diagnosis']
    lines = [
        '# The loop in service', '',
        f'Effect carried by the emulator\'s valve: **{loop["effect_injected"]}**; named by '
        f'the identification: **{diag.get("effect")}** (confidence '
        f'{diag.get("confidence", "n/a")}).', '']
    plant = loop.get('plant') or {}
    if plant:
        lines += [
            f'The valve in service discharges with C_d {plant["discharge_coefficient"]:g} '
            f'(the suite\'s set says {plant["suite_discharge_coefficient"]:g}): its flow area '
            f'at full opening is {plant["full_opening_area_m2"] * 1e6:.4g} mm^2, the suite '
            f'assumes {plant["suite_full_opening_area_m2"] * 1e6:.4g} mm^2. The suite does '
            f'not know it (`plant_valve.yaml`).', '']
    return lines


def _current_lines(loop: dict) -> list[str]:
    diag, base, aug = loop['diagnosis'], loop['baseline'], loop['augmented']
    return [
        '## Coil current (identification from the before run\'s bag)', '',
        '| model | fit IAE [A s] | validation IAE [A s] | validation RMSE [mA] |',
        '|---|---|---|---|',
        f'| baseline (nominal equations) | {_figure(base, "fit", "iae")} | '
        f'{_figure(base, "validation", "iae")} | '
        f'{_figure(base, "validation", "rmse", 1e3, ".2f")} |',
        f'| augmented ({diag.get("effect")}) | {_figure(aug, "fit", "iae")} | '
        f'{_figure(aug, "validation", "iae")} | '
        f'{_figure(aug, "validation", "rmse", 1e3, ".2f")} |',
        '', 'Validation: the last 30 % of the record, never seen by the fit. Details and plots: '
        '[identification/report.md](identification/report.md).', '']


def _tracking_lines(loop: dict) -> list[str]:
    tr = loop['tracking']
    cal = loop.get('flow_calibration') or {}
    cal_note = ' (flow scale calibrated)' if 'product_m' in cal else ''
    return [
        '## Position tracking (RMS of goal - position over the run)', '',
        '| run | flow_to_duty with | RMS [mm] | mean abs [mm] | max abs [mm] |',
        '|---|---|---|---|---|',
        f'| before | nominal parameters and map | {tr["before"]["rms_mm"]:.3f} | '
        f'{tr["before"]["mean_abs_mm"]:.3f} | {tr["before"]["max_abs_mm"]:.2f} |',
        f'| after | identified parameters and map{cal_note} | {tr["after"]["rms_mm"]:.3f} | '
        f'{tr["after"]["mean_abs_mm"]:.3f} | {tr["after"]["max_abs_mm"]:.2f} |',
        '', 'Each goal counts from its hold point (the demo holds the simulation until the '
        'controller acknowledged it); the RMS includes the step transients.', '']


def _calibration_lines(loop: dict) -> list[str]:
    cal = loop.get('flow_calibration') or {}
    if 'product_m' not in cal:
        return [f'Flow scale not calibrated: {cal.get("error")}', ''] if cal else []
    area = ''
    if 'full_opening_error_pct' in cal:
        area = (f' Flow area at full opening (C_d C_A x stroke of that set) '
                f'{cal["full_opening_area_m2"] * 1e6:.4g} mm^2: '
                f'{cal["full_opening_error_pct"]:+.1f} % off the valve in service (the '
                f'suite\'s set: {cal["suite_full_opening_error_pct"]:+.1f} %).')
    return [
        f'Flow scale of the identified set, calibrated on the before run\'s chamber mass '
        f'balance (opening from the identified map at the recorded duties): C_d C_A '
        f'{cal["prior_product_m"] * 1e3:.4g} -> {cal["product_m"] * 1e3:.4g} mm '
        f'(x {cal["ratio"]:.3f}; balance error {cal["balance_error_pct"]["before"]:.1f} '
        f'-> {cal["balance_error_pct"]["after"]:.1f} %). flow_to_duty ran with '
        '`params_identified.yaml` and `map_identified.json`.' + area, '']


def _flow_lines(loop: dict) -> list[str]:
    fl = loop['flow']
    window_s = fl['runs'][fl['record']]['window_s']
    lines = [
        'Plots: [before/report/report.md](before/report/report.md) '
        '(before/report/overview.png), [after/report/report.md](after/report/report.md) '
        '(after/report/overview.png).', '',
        '## Flow prediction (model driven by the recorded duty commands vs the flow the '
        'chamber received)', '',
        f'RMS error over {window_s:g} s windows in % of full flow '
        f'({fl["full_flow_kg_s"] * 1e3:.2f} g/s: spool open, supply into the atmosphere). '
        'Measured by the chamber\'s mass balance (C2, C3: pressure, piston position, the '
        'suite\'s cylinder); valve/state mass_flow is not a measurement (the CAN driver '
        'derives it with the suite\'s orifice constants).', '',
        '| record | nominal parameters | identified parameters | identified, flow scale '
        'calibrated |', '|---|---|---|---|']
    for name, run in fl['runs'].items():
        calibrated = run.get('calibrated', {}).get('rms_pct')
        lines.append(f'| {name.replace("_", " ")} | {run["nominal"]["rms_pct"]:.2f} % | '
                     f'{run["identified"]["rms_pct"]:.2f} % | '
                     f'{"n/a" if calibrated is None else format(calibrated, ".2f") + " %"} |')
    return lines + ['', 'The after run was not used by the identification. The static map '
                    'from the identified parameters: `map_identified.json` (figures in '
                    '`map/`).', '']


def _stage_lines(loop: dict) -> list[str]:
    lines = ['## Time of each stage (wall time)', '', '| stage | s |', '|---|---|']
    lines += [f'| {k} | {v:.1f} |' for k, v in loop['stages_s'].items()]
    timings = loop['identification'].get('timings_s') or {}
    if timings:
        lines += ['', 'Identification split: ' + ', '.join(
            f'{k} {v:.1f} s' for k, v in timings.items() if isinstance(v, (int, float)))]
    return lines


def loop_markdown(loop: dict) -> str:
    """``loop.md`` of a ``loop.json`` (:func:`valve_bringup.operation_loop.run_operation_loop`).

    Parameters
    ----------
    loop : dict
        The parsed ``loop.json``.

    Returns
    -------
    str
        Markdown: the diagnosis and the valve in service, the coil current's errors, the
        tracking error of both runs, the flow calibration, the flow prediction error and
        the stage times.
    """
    return '\n'.join(_head_lines(loop) + _current_lines(loop) + _tracking_lines(loop)
                     + _calibration_lines(loop) + _flow_lines(loop) + _stage_lines(loop)) + '\n'
