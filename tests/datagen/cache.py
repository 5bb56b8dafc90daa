"""Generated data sets for the tests, written once per test session into a temporary folder.

Each entry point writes its records on first use into ``base_dir`` and returns the truth
JSON content (the same object on a second call with the same arguments).
"""
from __future__ import annotations

from pathlib import Path

from .electronics import FORMS, DriveCircuit, DriveElectronics
from .generate import generate_case

__all__ = ['ELECTRONICS_PAIR_NOISE_A', 'dataset', 'electronics_pair', 'operation_dataset',
           'pwm_dataset', 'step_dataset', 'electronics_named']

_CACHE: dict[tuple[str, int, bool], dict[str, object]] = {}


def dataset(base_dir: Path, case: str, seed: int = 1, long: bool | None = None
            ) -> dict[str, object]:
    """The truth.json content of a case (generated on first use into ``base_dir``)."""
    key = (case, seed, bool(long))
    if key not in _CACHE:
        _CACHE[key] = generate_case(base_dir / f'seed{seed}{"-long" if long else ""}', case,
                                    seed=seed, long=long)
    return _CACHE[key]


def electronics_named(electronics: str | DriveCircuit | DriveElectronics | None
                      ) -> tuple[str, DriveCircuit | DriveElectronics]:
    """A file-name tag and the driver: a name of :data:`.electronics.FORMS`, a driver, or
    ``None`` (the default :class:`DriveCircuit`)."""
    if electronics is None:
        return '', DriveCircuit()
    if isinstance(electronics, str):
        if electronics not in FORMS:
            raise ValueError(f'unknown electronics form {electronics!r}; choose from '
                             f'{", ".join(FORMS)}')
        return electronics, FORMS[electronics]
    return f'custom{abs(hash(electronics)) % 10 ** 8}', electronics


_OPERATION_CACHE: dict[tuple, dict[str, object]] = {}


def operation_dataset(base_dir: Path, *, seed: int = 1, effect: str = 'none',
                      noise_a: float = 0.0, duration_s: float = 3.0, spread: float = 0.0,
                      electronics: str | DriveCircuit | DriveElectronics | None = None,
                      coil_voltage_mean: bool = False, lsb_a: float = 0.0,
                      valve_seed: int | None = None) -> dict[str, object]:
    """The truth JSON of an operational record (written on first use into ``base_dir``).

    Parameters
    ----------
    base_dir : pathlib.Path
        Parent folder (records go to ``base_dir/operation``).
    seed : int
        Seeds the duty schedule and the noise (and the valve draw, see ``valve_seed``).
    effect : str
        ``none``, a listed effect or ``coulomb_friction_stiction``.
    noise_a : float
        Gaussian noise of the interval-mean current [A] (the tests use 0, 1, 3, 10 mA).
    duration_s : float
        Record length [s].
    spread : float
        Relative spread of the valve's Table 2 parameters (0: the paper's valve).
    electronics : str, DriveCircuit or DriveElectronics, optional
        A form of :data:`.electronics.FORMS` by name, a driver, or the default driver.
    coil_voltage_mean : bool
        Add the interval-mean terminal voltage column.
    lsb_a : float
        Quantisation step of an 8-bit current channel [A] (0: none; 10-20 mA typical).
    valve_seed : int, optional
        Seed of the valve draw, so a fit and a validation record (two ``seed``) share one
        valve; default ``seed``.
    """
    from .bench import bench_valve
    from .operation import write_operation_record
    tag, circuit = electronics_named(electronics)
    key = (seed, effect, float(noise_a), float(duration_s), float(spread), circuit,
           coil_voltage_mean, float(lsb_a), valve_seed)
    if key not in _OPERATION_CACHE:
        name = (f'operation-{effect}-seed{seed}-{1e3 * noise_a:g}mA-{duration_s:g}s'
                f'-spread{spread:g}')
        name += (f'-{tag}' if tag else '') + ('-vmean' if coil_voltage_mean else '') + \
            (f'-lsb{1e3 * lsb_a:g}mA' if lsb_a else '') + \
            (f'-valve{valve_seed}' if valve_seed is not None else '')
        valve = None if valve_seed is None else bench_valve(valve_seed, effect, spread)
        _OPERATION_CACHE[key] = write_operation_record(
            base_dir / 'operation', name, seed=seed, effect=effect, noise_a=noise_a,
            duration_s=duration_s, spread=spread, valve=valve, circuit=circuit,
            coil_voltage_mean=coil_voltage_mean, lsb_a=lsb_a)
    return _OPERATION_CACHE[key]


_PWM_CACHE: dict[tuple, dict[str, object]] = {}


#: Noise of :func:`electronics_pair`'s records [A].
ELECTRONICS_PAIR_NOISE_A = 3e-3


def electronics_pair(base_dir: Path, form: str) -> tuple[str, str]:
    """A fit (1.5 s) and a validation record (1.2 s) of one valve (the paper's, no effect)
    through the generator's electronics ``form``, 1 kHz interval means with
    :data:`ELECTRONICS_PAIR_NOISE_A` of noise and no mean voltage: the files' paths."""
    fit = operation_dataset(base_dir, seed=11, noise_a=ELECTRONICS_PAIR_NOISE_A,
                            duration_s=1.5, electronics=form, valve_seed=11)
    val = operation_dataset(base_dir, seed=12, noise_a=ELECTRONICS_PAIR_NOISE_A,
                            duration_s=1.2, electronics=form, valve_seed=11)
    return str(fit['file']), str(val['file'])


def pwm_dataset(base_dir: Path, *, seed: int = 1, effect: str = 'none',
                noise_a: float = 0.0, duration_s: float = 0.4, spread: float = 0.0,
                electronics: str | DriveCircuit | DriveElectronics | None = None,
                coil_voltage: bool = False, lsb_a: float = 0.0, rate_hz: float = 20_000.0,
                frequency_hz: float = 50.0, valve_seed: int | None = None
                ) -> dict[str, object]:
    """The truth JSON of a bench ``pwm`` record (written on first use into ``base_dir``).

    Arguments as :func:`operation_dataset`, and ``coil_voltage`` (the instantaneous
    terminal voltage column), ``rate_hz`` (sample rate, 10-50 kHz) and ``frequency_hz``
    (main PWM frequency); see :func:`.bench.write_pwm_record`.
    """
    from .bench import bench_valve, write_pwm_record
    tag, circuit = electronics_named(electronics)
    key = (seed, effect, float(noise_a), float(duration_s), float(spread), circuit,
           coil_voltage, float(lsb_a), float(rate_hz), float(frequency_hz), valve_seed)
    if key not in _PWM_CACHE:
        name = (f'pwm-{effect}-seed{seed}-{1e3 * noise_a:g}mA-{duration_s:g}s-spread{spread:g}'
                f'-{rate_hz / 1e3:g}kHz-{frequency_hz:g}Hz')
        name += (f'-{tag}' if tag else '') + ('-vcoil' if coil_voltage else '') + \
            (f'-lsb{1e3 * lsb_a:g}mA' if lsb_a else '') + \
            (f'-valve{valve_seed}' if valve_seed is not None else '')
        valve = None if valve_seed is None else bench_valve(valve_seed, effect, spread)
        _PWM_CACHE[key] = write_pwm_record(
            base_dir / 'pwm', name, seed=seed, effect=effect, spread=spread, valve=valve,
            circuit=circuit, frequency_hz=frequency_hz, duration_s=duration_s,
            rate_hz=rate_hz, noise_a=noise_a, lsb_a=lsb_a, coil_voltage=coil_voltage)
    return _PWM_CACHE[key]


_STEP_CACHE: dict[tuple, dict[str, object]] = {}


def step_dataset(base_dir: Path, *, seed: int = 1, effect: str = 'coulomb_friction_stiction',
                 noise_a: float = 3e-3, spread: float = 0.0, lsb_a: float = 0.0
                 ) -> dict[str, object]:
    """The truth JSON of a 24 V fit and a 15 V validation ``step`` record of the bare coil
    (written on first use into ``base_dir``); see :func:`.bench.write_step_records`."""
    from .bench import write_step_records
    key = (seed, effect, float(noise_a), float(spread), float(lsb_a))
    if key not in _STEP_CACHE:
        name = (f'step-{effect}-seed{seed}-{1e3 * noise_a:g}mA-spread{spread:g}'
                + (f'-lsb{1e3 * lsb_a:g}mA' if lsb_a else ''))
        _STEP_CACHE[key] = write_step_records(
            base_dir / 'step', name, seed=seed, effect=effect, spread=spread,
            noise_a=noise_a, lsb_a=lsb_a)
    return _STEP_CACHE[key]
