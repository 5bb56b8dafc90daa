"""valve_controller_emulator: the valve controller firmware stand-in as a program.

Examples::

    # The bus for driver + emulator on one machine (no vcan needed): the emulator hosts a
    # tcp_loopback hub on 127.0.0.1:29536 and answers as node 0.
    valve_controller_emulator --interface tcp_loopback --channel 127.0.0.1:29536

    # On real hardware (SocketCAN), node 3, a valve whose coil heats up:
    valve_controller_emulator --interface socketcan --channel can0 --node-id 3 \\
        --effect coil_heating --effect-param thermal_resistance_k_per_w=80

    # Scheduled faults: go silent 2 s after start for 0.5 s; drop 10 % of telemetry from 4 s.
    valve_controller_emulator --fault silent:2:0.5 --fault drop_telemetry:4:0:0.1

With ``--fault-injection``, faults can also be switched at run time with
``EmulatorControl`` frames (id 0x6D0 + node id, defined in the test-only
``valve_test.dbc``; see the package README), e.g. from a test with
:class:`valve_driver_pkg.emulator.EmulatorRemote`. Without it (the default) such frames
are counted and ignored: anyone on the bus could send them.

The program prints ``valve_controller_emulator ready: <interface> <channel> node <n>`` once
it answers on the bus (with the real port when ``--channel`` asks for port 0) and stops
cleanly on SIGINT/SIGTERM.
"""
from __future__ import annotations

import argparse
import dataclasses
import gc
import importlib
import logging
import signal
import sys
import threading

import can

from valve_driver_pkg.canbus.cli import add_bus_arguments, open_device_bus
from valve_driver_pkg.emulator.config import DEFAULT_COMMAND_TIMEOUT_S
from valve_driver_pkg.emulator.controller import ControllerEmulator, EmulatorConfig
from valve_driver_pkg.emulator.faults import FAULT_NAMES, parse_fault_spec
from valve_driver_pkg.errors import BusOpenError

__all__ = ['main', 'build_parser', 'make_stepper', 'apply_effects', 'EFFECT_DEMO_FRACTION']

logger = logging.getLogger('valve_controller_emulator')

#: An ``--effect`` given without values sets the effect's switching field to this fraction
#: of its identification range (e.g. coil_heating: R_th = 100 K/W of (0, 200)).
EFFECT_DEMO_FRACTION = 0.5


def build_parser() -> argparse.ArgumentParser:
    """The command-line interface."""
    p = argparse.ArgumentParser(prog='valve_controller_emulator',
                                description=__doc__.split('\n')[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter,
                                epilog=__doc__.split('\n', 2)[2])
    bus = add_bus_arguments(p)
    bus.add_argument('--node-id', type=int, default=0, help='node id 0..15 (default 0)')
    fw = p.add_argument_group('firmware')
    fw.add_argument('--telemetry-rate-hz', type=float, default=1000.0)
    fw.add_argument('--status-rate-hz', type=float, default=10.0)
    fw.add_argument('--command-timeout-s', type=float, default=DEFAULT_COMMAND_TIMEOUT_S,
                    help='firmware watchdog (host loss): no valid command this long switches '
                         f'the coil off at once (default {DEFAULT_COMMAND_TIMEOUT_S:g} s; '
                         '0 = off)')
    fw.add_argument('--no-position-estimate', action='store_true',
                    help='report PositionValid=0 (a controller without an estimator)')
    fw.add_argument('--fault-injection', action='store_true',
                    help='obey EmulatorControl (fault injection) frames from the bus; off by '
                         'default: they are then counted and ignored')
    fw.add_argument('--no-control-frames', action='store_true',
                    help=argparse.SUPPRESS)   # the default now; kept for old command lines
    model = p.add_argument_group('valve model')
    model.add_argument('--params-file', default='',
                       help='valve parameter YAML (default: valve_model_pkg config/valve.yaml)')
    # The emulated hardware. A bench run needs none of the two --no-* flags: the host asks
    # for the bench mode in ValveCommand.DriveMode (driver parameter drive_mode:=bench).
    model.add_argument('--supply-voltage-v', type=float, default=24.0,
                       help='drive supply voltage of the emulated hardware [V] (default 24)')
    model.add_argument('--current-noise-a', type=float, default=0.0,
                       help='standard deviation of the current ADC noise on the reported '
                            'coil current and its interval mean [A] (default 0; seeded)')
    model.add_argument('--electronics', default='', metavar='FILE',
                       help='drive electronics of the hardware (description YAML, '
                            "valve_model_pkg docs/model.md; default: the paper's driver); "
                            'the two flags below switch its parts off')
    model.add_argument('--no-current-control', action='store_true',
                       help='hardware built without the boost/holding-current chopper (its '
                            'normal mode is bare PWM voltage); the bench mode is asked for '
                            'over the bus (ValveCommand.DriveMode), not with this flag')
    model.add_argument('--no-capacitor', action='store_true',
                       help='hardware built without the capacitor\'s negative release pulse; '
                            'see --no-current-control for the bench mode')
    model.add_argument('--supply-pressure-pa', type=float, default=400_000.0,
                       help='supply pressure, gauge [Pa], until a ValvePressure frame arrives')
    model.add_argument('--output-pressure-pa', type=float, default=0.0,
                       help='output pressure, gauge [Pa], until a ValvePressure frame arrives')
    model.add_argument('--effect', action='append', default=[], metavar='NAME',
                       help='switch on a physical effect the nominal model lacks '
                            '(repeatable). The identification\'s own candidate '
                            'equations: magnetic_saturation, eddy_current, '
                            'coulomb_friction, coil_heating, leakage_inductance, '
                            'end_stop_bounce. Emulator forms written independently of '
                            'the candidates (not candidate equations; docs/effects.md): '
                            'saturation_tanh (tanh flux-linkage law, fixed saturation '
                            'flux; a form of magnetic_saturation), eddy_ladder (two-'
                            'time-constant ladder; a form of eddy_current)')
    model.add_argument('--effect-param', action='append', default=[], metavar='FIELD=VALUE',
                       help='value of an effect parameter (repeatable), e.g. '
                            'thermal_resistance_k_per_w=80')
    model.add_argument('--stepper', default='valve_model_pkg.model:ValveStepper',
                       help=argparse.SUPPRESS)   # module:callable, for tests
    faults = p.add_argument_group('faults')
    faults.add_argument('--fault', action='append', default=[],
                        metavar='NAME[:START_S[:DURATION_S[:PROBABILITY]]]',
                        help='schedule a fault (repeatable); names: '
                             + ', '.join(sorted(FAULT_NAMES)))
    faults.add_argument('--seed', type=int, default=None, help='seed of the fault draws')
    clock = p.add_argument_group('clock')
    clock.add_argument('--clock', choices=('wall', 'sim'), default='wall',
                       help='wall: the model runs in real time (default, as firmware); sim: '
                            'it advances on the simulation clock (/clock of '
                            'valve_lockstep_sim, in lockstep; emulator/lockstep.py)')
    clock.add_argument('--step-s', type=float, default=0.001,
                       help='(sim) simulation step [s]')
    clock.add_argument('--control-period-s', type=float, default=0.005,
                       help='(sim) control tick: the model waits for each tick\'s command')
    clock.add_argument('--lockstep-timeout-s', type=float, default=10.0,
                       help='(sim) wall time to wait for a tick\'s command [s]')
    clock.add_argument('--valve-namespace', default='',
                       help='(sim) namespace of the valve\'s duty_command topic')
    p.add_argument('--duration-s', type=float, default=0.0,
                   help='stop after this long (0 = until SIGINT/SIGTERM)')
    p.add_argument('--log-level', default='info', choices=('debug', 'info', 'warning', 'error'))
    return p


def apply_effects(params, effects: list[str], values: list[str]):
    """Return ``params`` with the named effects switched on.

    Parameters
    ----------
    params : ValveParameters
    effects : list of str
        Effect names: the identification's candidates (``valve_model_pkg.model.EFFECTS``)
        or the emulator forms written independently of them
        (``valve_model_pkg.model.parameters.EMULATOR_EFFECTS``: ``saturation_tanh``,
        ``eddy_ladder``).
    values : list of str
        ``FIELD=VALUE`` items; a field of a named candidate effect without a value gets
        :data:`EFFECT_DEMO_FRACTION` of its identification range (switching field only),
        the fields of an emulator form their ``demo`` values (visible in a 24 V step).

    Raises
    ------
    ValueError
        Unknown effect or field, a bad number, or a field of an effect not named.
    """
    from valve_model_pkg.model import EFFECTS
    from valve_model_pkg.model.parameters import EMULATOR_EFFECTS

    changes: dict[str, float] = {}
    for item in values:
        field, sep, text = item.partition('=')
        if not sep:
            raise ValueError(f'--effect-param {item!r}: expected FIELD=VALUE')
        try:
            changes[field.strip()] = float(text)
        except ValueError as err:
            raise ValueError(f'--effect-param {item!r}: {text!r} is not a number') from err
    named_fields: set[str] = set()
    for name in effects:
        if name in EMULATOR_EFFECTS:
            spec = EMULATOR_EFFECTS[name]
            named_fields.update(spec.fields)
            for field, value in spec.demo.items():
                changes.setdefault(field, value)
            continue
        if name not in EFFECTS:
            raise ValueError(f'unknown effect {name!r}; expected one of {", ".join(EFFECTS)} '
                             f'or an emulator form {", ".join(EMULATOR_EFFECTS)}')
        spec = EFFECTS[name]
        named_fields.update(spec.fields)
        switch = spec.fields[0]
        if switch not in changes:
            low, high = spec.bounds[switch]
            changes[switch] = low + EFFECT_DEMO_FRACTION * (high - low)
    unknown = sorted(set(changes) - named_fields)
    if unknown:
        raise ValueError(f'--effect-param {", ".join(unknown)}: not a parameter of the '
                         f'effects named with --effect ({", ".join(effects) or "none"})')
    return params.replace(**changes) if changes else params


def make_stepper(args: argparse.Namespace):
    """Build the valve model from the arguments (parameters, effects, electronics)."""
    module_name, _, attr = args.stepper.partition(':')
    factory = getattr(importlib.import_module(module_name), attr)
    if args.stepper != 'valve_model_pkg.model:ValveStepper':
        return factory(None, None, supply_voltage_v=args.supply_voltage_v)
    from valve_model_pkg.model import ElectronicsConfig, load_electronics, load_parameters

    params = load_parameters(args.params_file or None)
    params = apply_effects(params, args.effect, args.effect_param)
    base = load_electronics(args.electronics) if args.electronics else ElectronicsConfig()
    electronics = dataclasses.replace(
        base, current_control=base.current_control and not args.no_current_control,
        negative_voltage=base.negative_voltage and not args.no_capacitor)
    active = params.active_effects() if hasattr(params, 'active_effects') else ()
    logger.info('valve model: %s; effects: %s', args.params_file or 'default parameters',
                ', '.join(active) or 'none (the nominal model)')
    return factory(params, electronics, supply_voltage_v=args.supply_voltage_v)


def main(argv: list[str] | None = None) -> int:
    """Entry point; returns the exit code (0 on a clean stop)."""
    args = build_parser().parse_args(argv)
    logging.basicConfig(level=getattr(logging, args.log_level.upper()),
                        format='[%(name)s] %(levelname)s: %(message)s')
    try:
        scheduled = [parse_fault_spec(text) for text in args.fault]
        config = EmulatorConfig(node_id=args.node_id, telemetry_rate_hz=args.telemetry_rate_hz,
                                status_rate_hz=args.status_rate_hz,
                                command_timeout_s=args.command_timeout_s,
                                position_estimate=not args.no_position_estimate,
                                fault_injection=(args.fault_injection
                                                 and not args.no_control_frames),
                                supply_voltage_v=args.supply_voltage_v,
                                current_noise_a=args.current_noise_a)
        stepper = make_stepper(args)
    except (ValueError, OSError, ImportError, AttributeError) as err:
        logger.error('cannot start: %s', err)
        return 2

    try:
        device_bus = open_device_bus(args)
    except (BusOpenError, OSError, ValueError) as err:
        logger.error('cannot open the bus: %s', err)
        return 1
    bus, channel = device_bus.bus, device_bus.channel

    stop = threading.Event()

    def _on_signal(signum: int, _frame: object) -> None:
        stop.set()

    signal.signal(signal.SIGINT, _on_signal)
    signal.signal(signal.SIGTERM, _on_signal)
    code = 0
    try:
        emulator = ControllerEmulator(bus, stepper, config, fault_seed=args.seed,
                                      supply_pressure_pa=args.supply_pressure_pa,
                                      output_pressure_pa=args.output_pressure_pa)
        timers = []
        for fault, start_s, duration_s, probability in scheduled:
            timer = threading.Timer(start_s, emulator.inject,
                                    kwargs={'fault': fault, 'probability': probability,
                                            'duration_s': duration_s})
            timer.daemon = True
            timers.append(timer)
        gc.collect()
        gc.freeze()   # keep start-up objects out of the collector: fewer pauses at 1 kHz
        # A thread waiting for the GIL waits up to the switch interval (5 ms by default),
        # longer than the telemetry period; 0.5 ms keeps the 1 kHz timing.
        sys.setswitchinterval(0.0005)
        print(f'valve_controller_emulator ready: {args.interface} {channel} '
              f'node {args.node_id}', flush=True)
        for timer in timers:
            timer.start()
        if args.clock == 'sim':
            from valve_driver_pkg.emulator.lockstep import run_on_simulation_clock
            emulator.stats.update(run_on_simulation_clock(
                emulator, stop, step_s=args.step_s, control_period_s=args.control_period_s,
                timeout_s=args.lockstep_timeout_s, valve_namespace=args.valve_namespace))
        else:
            emulator.run(stop, duration_s=args.duration_s)
        for timer in timers:
            timer.cancel()
        logger.info('stopped: %s', emulator.stats)
    except can.CanError as err:
        logger.error('bus failed: %s', err)
        code = 1
    finally:
        device_bus.close()
    return code


if __name__ == '__main__':
    sys.exit(main())
