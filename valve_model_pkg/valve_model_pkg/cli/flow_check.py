"""valve_flow_check: compare a measured flow_map file with the static duty map (Fig. 10).

Reads a ``flow_map`` file of the measured-data format (columns ``duty`` and ``mass_flow``
or ``flow_fraction``; metadata ``pwm_frequency_hz``, ``supply_pressure_pa`` and optionally
``output_pressure_pa``), predicts the flow percentage from the map
(x_avg(d) / x_avg(100 %), eq. 12 makes flow proportional to the opening at fixed
pressures) and prints the error per duty and overall. Optionally draws Fig. 10 and writes
the comparison as JSON.

With ``-o/--out DIR`` (a directory) and a ``mass_flow`` file it also identifies the orifice
constant (:mod:`valve_model_pkg.maps.flow_identification`): only C_d*C_A is identifiable
from flow; C_d is kept from the parameter set and C_A scaled. It writes

- ``DIR/flow_identified.json``: C_d, C_A, their product with its 95 % interval, the dead
  band and saturation of the map against the measured curve, the flow error before and
  after in % of the full flow;
- ``DIR/params.yaml``: the start parameter set (``--params``, else the map's own) with the
  identified C_A, loadable by ``valve_map``, ``valve_simulator`` and ``flow_to_duty``;
- ``DIR/map.json``: the map with the identified C_A and its curves unchanged (x_avg(d)
  does not depend on C_d or C_A), so ``flow_to_duty`` restarts at once with
  ``map_file:=DIR/map.json params_file:=DIR/params.yaml``; a map rebuilt with
  ``valve_map --params DIR/params.yaml`` gives the same curves;
- ``DIR/comparison.json``: the comparison with the map (what ``--json`` writes).

``-o FILE.json`` (a path ending in ``.json``) writes the comparison only.

With ``--chamber`` the input is a bag of the suite instead (``valve/state``,
``valve/output_pressure``, ``cylinder/joint_states``): C_d*C_A is identified from the
cylinder chamber's mass balance (:func:`~valve_model_pkg.maps.flow_identification.\
identify_from_chamber`, docs/flow_side.md). The bag does not carry the cylinder's geometry:
``--bore-m`` and ``--dead-volume-m3`` (default: the suite's cylinder, 25 mm bore, 20 cm^3,
said in the output), ``--polytropic-exponent`` (default 1.2, the suite's plant) and
``--bleed-m2`` (C_d A of a bleed to atmosphere; default: identified with the valve). ``--out
DIR`` is required and gets flow_identified.json (``source: chamber``), params.yaml and
map.json as above.

Examples::

    valve_flow_check bench7_flow.csv
    valve_flow_check bench7_flow.csv --map my_map.json --plot fig10.png --json out.json
    valve_flow_check bench7_flow.csv --params valve.yaml --out calibrated/
    valve_flow_check bench7_flow.csv --max-rms-percent 3     # exit 1 if worse
    valve_flow_check run/bag_20261123 --chamber --bore-m 0.032 --out calibrated/

Exit codes: 0 done (and within ``--max-rms-percent``), 2 refused input (the file, the map,
a frequency the map lacks; one line naming file, line and value), 1 a failure inside or
an rms error above ``--max-rms-percent``.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

__all__ = ['main']


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog='valve_flow_check', description=__doc__.split('\n\n')[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument('flow_map', help='measured flow_map CSV file (with --chamber: a bag)')
    p.add_argument('--chamber', action='store_true',
                   help='identify C_d*C_A from a bag\'s chamber mass balance (needs --out)')
    p.add_argument('--bore-m', type=float, default=None,
                   help='--chamber: piston bore [m] (default: the suite cylinder\'s)')
    p.add_argument('--dead-volume-m3', type=float, default=None,
                   help='--chamber: chamber volume at piston position 0 [m^3] (default: the '
                        'suite cylinder\'s)')
    p.add_argument('--polytropic-exponent', type=float, default=None,
                   help='--chamber: n of the chamber air, 1 (isothermal) .. 1.4 (default: '
                        'the suite plant\'s)')
    p.add_argument('--bleed-m2', type=float, default=None,
                   help='--chamber: C_d A of the bleed to atmosphere [m^2] (default: '
                        'identified; 0 for none)')
    p.add_argument('--map', default='', help='duty map file (default: the shipped one)')
    p.add_argument('--params', default='',
                   help='valve parameter YAML the map must match, and the set --out DIR '
                        'starts from (default: the map\'s own parameter set, no check)')
    p.add_argument('--allow-implausible', action='store_true',
                   help='accept --params values outside their plausible ranges with a '
                        'warning')
    p.add_argument('--pwm-frequency', type=float, default=None,
                   help='PWM frequency [Hz] if the file does not state it')
    p.add_argument('--supply-pressure-bar', type=float, default=None,
                   help='supply pressure [bar gauge] if the file does not state it')
    p.add_argument('-o', '--out', default=None,
                   help='output directory: flow_identified.json, params.yaml, '
                        'comparison.json (a path ending in .json: the comparison only)')
    p.add_argument('--json', default=None, help='write the comparison to this JSON file')
    p.add_argument('--plot', default=None, help='write Fig. 10 to this PNG')
    p.add_argument('--max-rms-percent', type=float, default=None,
                   help='exit with code 1 if the rms error exceeds this [%% of full flow]')
    return p


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``valve_flow_check``; returns the exit code."""
    parser = _parser()
    args = parser.parse_args(argv)
    if args.chamber:
        return _chamber_main(args, parser)
    from valve_model_pkg.maps import MapError, load_map
    from valve_model_pkg.maps.flow_check import compare_flow_map, read_flow_map
    from valve_model_pkg.maps.flow_identification import identify_from_flow_map
    from valve_model_pkg.model import ValveParameters
    out_dir = args.out if args.out and not args.out.lower().endswith('.json') else None
    json_file = args.json or (args.out if out_dir is None else None)
    ident = None
    try:
        dmap = load_map(args.map or None)
        start = None
        if args.params:
            from valve_model_pkg.model import load_parameters
            start = load_parameters(args.params, allow_implausible=args.allow_implausible)
            dmap.check_parameters(start, args.map or 'shipped map', args.params)
        measured = read_flow_map(
            args.flow_map, pwm_frequency_hz=args.pwm_frequency,
            supply_pressure_pa=None if args.supply_pressure_bar is None
            else args.supply_pressure_bar * 1e5)
        result = compare_flow_map(dmap, measured)
        if out_dir is not None:
            # FlowIdentificationError (a ValueError): a flow_fraction file, too few open
            # points or an implausible C_A -- the input cannot give the constant
            ident = identify_from_flow_map(
                dmap, measured, start or ValveParameters.from_dict(dmap.parameters))
    except KeyError as err:  # the file's frequency is not in the map: refused input
        print(f'valve_flow_check: error: {args.flow_map}: {err.args[0]}', file=sys.stderr)
        return 2
    except (MapError, ValueError, OSError) as err:
        # FlowMapFormatError and MapFormatError name file, line and value; OSError here
        # can only come from reading the inputs
        print(f'valve_flow_check: error: {err}', file=sys.stderr)
        return 2
    try:
        _write_outputs(args, dmap, measured, result, json_file)
        if ident is not None:
            _write_identification(Path(out_dir), dmap, ident, measured, result, args)
    except OSError as err:
        print(f'valve_flow_check: error: {err}', file=sys.stderr)
        return 1
    if args.max_rms_percent is not None and result.rms_error * 100 > args.max_rms_percent:
        print(f'valve_flow_check: rms error {result.rms_error * 100:.2f} % exceeds '
              f'{args.max_rms_percent:g} %', file=sys.stderr)
        return 1
    return 0


def _chamber_main(args: argparse.Namespace, parser: argparse.ArgumentParser) -> int:
    """``--chamber``: C_d*C_A from a bag's chamber mass balance; returns the exit code."""
    import math
    if not args.out or args.out.lower().endswith('.json'):
        parser.error('--chamber needs -o/--out DIR (a directory)')
    from valve_model_pkg.maps import MapError, load_map
    from valve_model_pkg.maps.flow_identification import (
        FlowIdentificationError, chamber_record_from_bag, identify_from_chamber,
        recalibrated_map, write_parameters)
    from valve_model_pkg.model import ValveParameters
    from valve_model_pkg.pneumatics.cylinder import CylinderParameters
    cyl = CylinderParameters()
    given = {'--bore-m': args.bore_m, '--dead-volume-m3': args.dead_volume_m3,
             '--polytropic-exponent': args.polytropic_exponent, '--bleed-m2': args.bleed_m2}
    for key, value in given.items():
        if value is not None and (not math.isfinite(value) or value < 0.0
                                  or (value == 0.0 and key != '--bleed-m2')):
            parser.error(f'{key} {value!r}: expected a positive finite number')
    if args.polytropic_exponent is not None and not 1.0 <= args.polytropic_exponent <= 1.4:
        parser.error(f'--polytropic-exponent {args.polytropic_exponent!r}: expected 1 .. 1.4')
    bore = cyl.bore_diameter_m if args.bore_m is None else args.bore_m
    dead = cyl.dead_volume_m3 if args.dead_volume_m3 is None else args.dead_volume_m3
    n_poly = cyl.polytropic_exponent if args.polytropic_exponent is None \
        else args.polytropic_exponent
    try:
        dmap = load_map(args.map or None)
        if args.params:
            from valve_model_pkg.model import load_parameters
            start = load_parameters(args.params, allow_implausible=args.allow_implausible)
            dmap.check_parameters(start, args.map or 'shipped map', args.params)
        else:
            start = ValveParameters.from_dict(dmap.parameters)
        record = chamber_record_from_bag(args.flow_map, bore_diameter_m=bore,
                                         dead_volume_m3=dead)
        res = identify_from_chamber(record, start, polytropic_exponent=n_poly,
                                    bleed_discharge_area_m2=args.bleed_m2)
    except (MapError, FlowIdentificationError, ValueError, KeyError, OSError) as err:
        # the bag reader names the bag and the topic; the map errors name file and key;
        # one line (a YAML parser's message spans two)
        print(f'valve_flow_check: error: {args.flow_map}: {" ".join(str(err).split())}',
              file=sys.stderr)
        return 2
    geometry = {'bore_diameter_m': bore, 'dead_volume_m3': dead,
                'polytropic_exponent': n_poly,
                'defaults_used': [k for k, v in given.items() if v is None]}
    out = Path(args.out)
    try:
        out.mkdir(parents=True, exist_ok=True)
        data = {'bag': str(args.flow_map), 'map': args.map or 'shipped',
                'params_in': args.params or 'map parameters', 'cylinder': geometry,
                **res.as_dict()}
        (out / 'flow_identified.json').write_text(json.dumps(data, indent=1) + '\n',
                                                  encoding='utf-8')
        e = res.estimate
        header = (f'Valve parameters with the orifice constant identified by valve_flow_check '
                  f'--chamber\nfrom {args.flow_map}: C_d*C_A = {e.product_m:.6g} m^2/m '
                  f'({e.confidence:.0%} interval {e.interval_m[0]:.6g} .. '
                  f'{e.interval_m[1]:.6g}),\nC_d kept at {e.discharge_coefficient:g}, '
                  'C_A = product / C_d (only the product is identifiable from flow).')
        write_parameters(res.params, out / 'params.yaml', header)
        recalibrated_map(dmap, res.params, str(args.flow_map)).save(out / 'map.json')
    except (OSError, FlowIdentificationError) as err:
        print(f'valve_flow_check: error: {err}', file=sys.stderr)
        return 1
    e = res.estimate
    print(f'C_d*C_A = {e.product_m:.6g} m^2/m ({e.confidence:.0%} interval '
          f'{e.interval_m[0]:.6g} .. {e.interval_m[1]:.6g}; prior {e.prior_product_m:.6g}), '
          f'bleed C_d A {res.bleed_discharge_area_m2:.3g} m^2 '
          f'({"identified" if res.bleed_identified else "given"}); mass-balance error '
          f'{res.error_before_pct:.2f} % -> {res.error_after_pct:.2f} % of the largest '
          f'windowed valve flow ({e.n_points} windows of {res.window_s:g} s)')
    if geometry['defaults_used']:
        print('cylinder geometry not in the bag: the suite cylinder\'s defaults were used for '
              + ', '.join(geometry['defaults_used']) + f' (bore {bore:g} m, dead volume '
              f'{dead:g} m^3, n {n_poly:g}); give yours for another cylinder')
    print(f'wrote {out / "flow_identified.json"}, {out / "params.yaml"}, {out / "map.json"}')
    return 0


def _write_identification(out: Path, dmap, ident, measured, result,  # noqa: ANN001
                          args: argparse.Namespace) -> None:
    """DIR/flow_identified.json, DIR/params.yaml, DIR/map.json and DIR/comparison.json."""
    from valve_model_pkg.maps.flow_identification import recalibrated_map, write_parameters
    out.mkdir(parents=True, exist_ok=True)
    data = {'flow_map': measured.path, 'map': args.map or 'shipped',
            'params_in': args.params or 'map parameters', **ident.as_dict()}
    (out / 'flow_identified.json').write_text(json.dumps(data, indent=1) + '\n',
                                              encoding='utf-8')
    e = ident.estimate
    header = (f'Valve parameters with the orifice constant identified by valve_flow_check\n'
              f'from {measured.path}: C_d*C_A = {e.product_m:.6g} m^2/m '
              f'({e.confidence:.0%} interval {e.interval_m[0]:.6g} .. {e.interval_m[1]:.6g}),\n'
              f'C_d kept at {e.discharge_coefficient:g}, C_A = product / C_d '
              '(only the product is identifiable from flow).\n'
              f'Start set: {args.params or "the map parameters"}. Loadable with '
              'valve_model_pkg.model.load_parameters (valve_map, valve_simulator, '
              'flow_to_duty).')
    write_parameters(ident.params, out / 'params.yaml', header)
    recalibrated_map(dmap, ident.params, measured.path).save(out / 'map.json')
    (out / 'comparison.json').write_text(json.dumps(result.as_dict(), indent=1) + '\n',
                                         encoding='utf-8')
    print(ident.summary())
    print(f'wrote {out / "flow_identified.json"}, {out / "params.yaml"}, '
          f'{out / "map.json"}, {out / "comparison.json"}')


def _write_outputs(args: argparse.Namespace, dmap, measured, result,  # noqa: ANN001
                   json_file: str | None) -> None:
    """Print the table; write the JSON (``--json``) and the figure (``--plot``)."""
    import numpy as np

    from valve_model_pkg.maps.flow_check import map_flow_fraction
    print(f'{measured.path}: {measured.duty.size} points, {measured.pwm_frequency_hz:g} Hz, '
          f'supply {measured.supply_pressure_pa / 1e5:g} bar, output '
          f'{measured.output_pressure_pa / 1e5:g} bar (gauge)')
    print(result.table())
    if json_file:
        Path(json_file).write_text(json.dumps(result.as_dict(), indent=1) + '\n',
                                   encoding='utf-8')
        print(f'wrote {json_file}')
    if args.plot:
        from valve_model_pkg.maps.plots import plot_flow_comparison
        fine = np.linspace(0.0, 1.0, 401)
        plot_flow_comparison(measured.duty, measured.flow_fraction, fine,
                             map_flow_fraction(dmap, fine, measured.pwm_frequency_hz,
                                               measured.supply_pressure_pa),
                             args.plot,
                             title=f'Measured flow vs simulated average position, '
                                   f'{measured.pwm_frequency_hz:g} Hz, '
                                   f'{measured.supply_pressure_pa / 1e5:g} bar (Fig. 10)')
        print(f'wrote {args.plot}')


if __name__ == '__main__':
    sys.exit(main())
