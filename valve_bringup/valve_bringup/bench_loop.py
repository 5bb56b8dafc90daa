"""valve_bench_loop: close the loop through the bench, over CAN, from recorded bags.

    valve_bench_loop [--mode bench|operation] [--effect coil_heating] [-o/--out DIR] [--quick]
                     [--plant-discharge-coefficient C_D]

``--mode bench`` (:mod:`valve_bringup.bench`, the default): the controller emulator runs a
valve that carries a physical effect the nominal model lacks (``--effect``), with its drive
electronics bypassed; 24 V and 15 V steps on the bare coil are recorded through the CAN
driver, ``valve_identify --fit <24 V bag> --validate <15 V bag>`` names the missing effect
and reports the error before and after, and the identified set drives ``valve_simulate``,
``valve_map`` and ``valve_simulator``. A position-control run does not serve here: with the
drive electronics on, the coil voltage is a 20 kHz chopper signal that a 1 kHz state stream
cannot carry.

``--mode operation`` (:mod:`valve_bringup.operation_loop`, docs/loop.md): the loop in
service, from the suite's own position-control runs: identify from the before run's bag,
rebuild the map, calibrate the flow scale on the chamber, run again, and compare tracking
and flow prediction before and after (``DIR/loop.json``, ``DIR/loop.md``).
"""
from __future__ import annotations

import argparse
import math
import os
import signal
import sys
from pathlib import Path

from valve_bringup.bench import DEFAULT_EFFECT_PARAMS, run_bench_loop
from valve_bringup.loop_commands import say
from valve_bringup.operation_loop import (OPERATION_DEFAULT_EFFECT, OPERATION_EFFECT_PARAMS,
                                          OPERATION_PLANT_DISCHARGE_COEFFICIENT,
                                          run_operation_loop)
from valve_bringup.supervisor import ChildExited
from valve_model_pkg.model import EFFECTS
from valve_model_pkg.model.parameters import EMULATOR_EFFECTS

__all__ = ['main']


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog='valve_bench_loop',
                                     description=__doc__.split('\n')[0])
    parser.add_argument('--mode', choices=('bench', 'operation'), default='bench',
                        help='bench: bare-coil voltage steps (default); operation: the loop '
                        'in service, from position-control runs of the suite (docs/loop.md)')
    parser.add_argument('--effect', default=None,
                        help='physical effect of the emulated valve (default coil_heating in '
                        'bench mode, eddy_current in operation mode)')
    parser.add_argument('--effect-param', action='append', default=None, metavar='FIELD=VALUE',
                        help='value of an effect parameter, passed to the emulator (default '
                        'for coil_heating in bench mode: a small coil that heats noticeably '
                        'within a second, '
                        + ', '.join(DEFAULT_EFFECT_PARAMS['coil_heating']) + ')')
    parser.add_argument('-o', '--out', type=Path, default=Path('bench_loop_output'),
                        help='directory for the bags, the identification and the map')
    parser.add_argument('--plant-discharge-coefficient', type=float,
                        default=OPERATION_PLANT_DISCHARGE_COEFFICIENT, metavar='C_D',
                        help='(operation) discharge coefficient of the valve in service, '
                        'which the suite does not know (default '
                        f'{OPERATION_PLANT_DISCHARGE_COEFFICIENT:g}; the suite\'s set says '
                        '0.8, and 0.8 here runs the loop on a valve with the suite\'s flow '
                        'scale)')
    parser.add_argument('--quick', action='store_true',
                        help='quick identification settings (fewer starts)')
    return parser


def _effect_args(mode: str, effect: str, effect_params: list[str] | None) -> tuple[str, ...]:
    """The emulator's ``--effect`` and ``--effect-param`` arguments (the mode's defaults
    when no parameter is given)."""
    if not effect or effect == 'none':
        return ()
    if effect_params is None:
        defaults = DEFAULT_EFFECT_PARAMS if mode == 'bench' else OPERATION_EFFECT_PARAMS
        effect_params = list(defaults.get(effect, ()))
    return ('--effect', effect) + tuple(a for item in effect_params
                                        for a in ('--effect-param', item))


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``valve_bench_loop``."""
    parser = _parser()
    args = parser.parse_args(argv)
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')

    def _interrupt(signum: int, _frame: object) -> None:
        raise KeyboardInterrupt(signal.Signals(signum).name)
    signal.signal(signal.SIGTERM, _interrupt)

    c_d = args.plant_discharge_coefficient
    if not (math.isfinite(c_d) and 0.0 < c_d <= 1.0):
        parser.error(f'--plant-discharge-coefficient {c_d!r}: expected a number in (0, 1]')
    effect = args.effect
    if effect is None:
        effect = 'coil_heating' if args.mode == 'bench' else OPERATION_DEFAULT_EFFECT
    if effect != 'none' and effect not in EFFECTS and effect not in EMULATOR_EFFECTS:
        parser.error(f'--effect {effect!r}: expected none or one of {", ".join(EFFECTS)} '
                     f'or an emulator form {", ".join(EMULATOR_EFFECTS)}')
    args.out.mkdir(parents=True, exist_ok=True)
    effect_args = _effect_args(args.mode, effect, args.effect_param)
    try:
        if args.mode == 'operation':
            return run_operation_loop(args.out, effect, effect_args, quick=args.quick,
                                      plant_discharge_coefficient=c_d)
        return run_bench_loop(args.out, effect, effect_args, quick=args.quick)
    except KeyboardInterrupt:
        say('interrupted')
        return 130
    except (ChildExited, RuntimeError, OSError, KeyError, ValueError) as err:
        say(f'error: {err}')
        return 1


if __name__ == '__main__':
    sys.exit(main())
