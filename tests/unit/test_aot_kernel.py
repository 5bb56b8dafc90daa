"""The ahead-of-time kernel (model/aot.py, model/aot_build.py) against the numba jit.

The AOT module must give the jit's numbers bit for bit (same compiled functions, same
flags) for the streaming entries and the batches, fall back to the jit when it is missing,
stale or broken, and keep numba out of any process that only simulates when it is there.
"""
from __future__ import annotations

import dataclasses
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from valve_model_pkg.model import (ElectronicsConfig, ValveBank, ValveSample, ValveStepper,
                                   aot, load_parameters)
from valve_model_pkg.model.bank import SAMPLE_COLUMNS
from valve_model_pkg.model.parameters import EMULATOR_EFFECTS, ValveParameters

N_TICKS = 400          # 1 kHz ticks: 0.4 s of model time, 20 PWM periods at 50 Hz
TICK_S = 1e-3


@pytest.fixture(scope='module')
def aot_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A directory holding the AOT module of the current kernel key.

    The set-up's module (ros2_ws/build/valve_kernel_aot) when it is there and current;
    otherwise one built for this test run (about 30 s of CPU).
    """
    key = aot.kernel_key()
    default = aot.default_dir()
    if default is not None and aot.find_module(default, key) is not None:
        return default
    out = tmp_path_factory.mktemp('kernel_aot')
    env = dict(os.environ, VALVE_KERNEL_AOT_DIR=str(out))
    done = subprocess.run([sys.executable, '-m', 'valve_model_pkg.model.aot_build',
                           '--out', str(out)], env=env, capture_output=True, text=True,
                          timeout=900)
    assert done.returncode == 0, done.stderr
    assert aot.find_module(out, key) is not None
    return out


@pytest.fixture()
def backends(aot_dir: Path) -> dict:
    """The AOT and the jit backend of this process, side by side."""
    key = aot.kernel_key()
    module = aot._load_module(aot.find_module(aot_dir, key), key)
    return {'aot': aot._aot_backend(module, 'test'), 'jit': aot._jit_backend('test')}


def _use(monkeypatch: pytest.MonkeyPatch, backend) -> None:
    monkeypatch.setattr(aot, '_backend', backend)


def _scenario(step) -> list[list[float]]:
    """Drive a stepper-like object through PWM, duty/pressure changes and a stop.

    ``step(k)`` is called each tick after the inputs of tick k are applied; returns the
    samples (rows of floats).
    """
    rows = []
    for k in range(N_TICKS):
        rows.append(step(k))
    return rows


def _stepper_rows(electronics: ElectronicsConfig, params: ValveParameters) -> np.ndarray:
    s = ValveStepper(params, electronics, supply_voltage_v=24.0,
                     supply_pressure_pa=4.0e5)
    s.set_command(0.6, 50.0)

    def step(k: int) -> list[float]:
        if k == 90:
            s.set_command(0.3, 80.0)
        if k == 150:
            s.set_pressures(2.5e5, 0.5e5)
        if k == 200:
            s.set_command(0.0, 80.0)     # stop: acts at once
        if k == 260:
            s.set_command(0.8, 50.0)
        if k == 300:
            s.set_pressures(1.0e5, 3.0e5)  # reversed flow
        if k == 330:
            s.set_electronics(ElectronicsConfig())  # a drive-mode switch while high
        s.advance_to((k + 1) * TICK_S)
        return [float(v) for v in dataclasses.astuple(s.sample())]

    return np.array(_scenario(step))


def _bank_rows(electronics: ElectronicsConfig, params: ValveParameters) -> np.ndarray:
    b = ValveBank([load_parameters(), params, params], electronics, 24.0, n_valves=3,
                  duty=[0.6, 0.2, 0.0], pwm_frequency_hz=[50.0, 100.0, 50.0])

    def step(k: int) -> list[float]:
        if k == 90:
            b.set_command(0, 0.3, 80.0)
            b.set_command(2, 0.9, 50.0)
        if k == 150:
            b.set_pressures(1, 2.5e5, 0.5e5)
        if k == 200:
            b.set_command(0, 0.0, 80.0)
        if k == 300:
            b.set_pressures(2, 1.0e5, 3.0e5)
        b.advance_to((k + 1) * TICK_S)
        return b.sample_array().ravel().tolist()

    return np.array(_scenario(step))


ELECTRONICS = {
    'current_control': ElectronicsConfig(),
    'bare_coil_capacitor': ElectronicsConfig(current_control=False, negative_voltage=True),
    # the other forms of the family: level events (threshold, Zener), comparator ticks
    'threshold_hysteresis_zener': ElectronicsConfig(
        peak_end='threshold', peak_current_a=0.8, hold='hysteresis', hold_decay='fast',
        release='zener'),
    'dip_rise_pwm_capacitor_peak': ElectronicsConfig(
        peak_end='dip_rise', hold='pwm', hold_decay='diode', release='capacitor_peak'),
}


def _with_effects() -> ValveParameters:
    """Every optional effect on, and both emulator forms (the kernel's other code path)."""
    p = load_parameters().replace(saturation_coefficient_per_a=0.5, eddy_conductance_s=0.01,
                                  coulomb_friction_n=1.0, thermal_resistance_k_per_w=100.0,
                                  leakage_inductance_h=0.02, restitution_coefficient=0.5)
    for form in EMULATOR_EFFECTS.values():
        p = p.replace(**form.demo)
    return p


#: (electronics, parameter set) of each comparison
CASES = {
    'paper_current_control': ('current_control', False),
    'paper_bare_coil_capacitor': ('bare_coil_capacitor', False),
    'effects_current_control': ('current_control', True),
    'effects_bare_coil_capacitor': ('bare_coil_capacitor', True),
    'effects_threshold_hysteresis_zener': ('threshold_hysteresis_zener', True),
    'paper_dip_rise_pwm_capacitor_peak': ('dip_rise_pwm_capacitor_peak', False),
}


def _case(name: str) -> tuple[ElectronicsConfig, ValveParameters]:
    elec, effects = CASES[name]
    return ELECTRONICS[elec], _with_effects() if effects else load_parameters()


@pytest.mark.parametrize('name', sorted(CASES))
def test_stepper_aot_is_bit_identical_to_jit(name: str, backends: dict,
                                             monkeypatch: pytest.MonkeyPatch) -> None:
    out = {}
    for kind, backend in backends.items():
        _use(monkeypatch, backend)
        out[kind] = _stepper_rows(*_case(name))
    assert out['aot'].shape == (N_TICKS, len(dataclasses.fields(ValveSample)))
    # the scenario moves the spool (else the comparison proves little)
    assert np.ptp(out['jit'][:, 3]) > 1e-4
    assert np.array_equal(out['aot'], out['jit']), \
        f'max difference {np.max(np.abs(out["aot"] - out["jit"]))}'


@pytest.mark.parametrize('name', sorted(CASES))
def test_bank_aot_is_bit_identical_to_jit(name: str, backends: dict,
                                          monkeypatch: pytest.MonkeyPatch) -> None:
    out = {}
    for kind, backend in backends.items():
        _use(monkeypatch, backend)
        out[kind] = _bank_rows(*_case(name))
    assert out['aot'].shape == (N_TICKS, 3 * len(SAMPLE_COLUMNS))
    assert np.ptp(out['jit']) > 0.0
    assert np.array_equal(out['aot'], out['jit']), \
        f'max difference {np.max(np.abs(out["aot"] - out["jit"]))}'


def _batch_outputs() -> dict[str, np.ndarray]:
    """Every batch entry of model/kernel.py on a few parameter sets, effects included."""
    from valve_model_pkg.model import kernel

    params = [load_parameters(), _with_effects(), load_parameters().replace(
        coulomb_friction_n=1.5, restitution_coefficient=0.6)]
    raw = np.array([p.to_vector() for p in params for _ in range(3)])
    raw[:, 0] *= np.linspace(0.9, 1.1, len(raw))   # a different mass in every row
    n = len(raw)
    elec = ElectronicsConfig().to_vector()
    bare = ElectronicsConfig.off().to_vector()
    p_sup = np.linspace(1e5, 5e5, n)
    p_out = np.zeros(n)
    res = {}
    res['step_cur'], res['step_pos'] = kernel.step_batch(
        raw, bare, np.linspace(12.0, 26.0, n), p_sup, p_out, 0.01, 0.0, 2e-5, 501)
    res['pwm'] = kernel.pwm_batch(raw, elec, np.full(n, 24.0), np.linspace(0.2, 0.8, n),
                                  1.0 / np.linspace(40.0, 150.0, n), p_sup, p_out, 5)
    t_samp = np.arange(1, 151) * 1e-3
    for parallel in (True, False):
        out = np.zeros((n, t_samp.size, kernel.N_OUT))
        stats = np.zeros((n, 2))
        kernel.trace_batch(raw, elec, np.array([0.0, 0.05, 0.09]), np.full(3, 24.0),
                           np.array([0.3, 0.7, 0.0]), np.full(3, 0.0125), p_sup, p_out,
                           t_samp, 1e-5, 1e-4, out, stats, parallel=parallel)
        res[f'trace_{parallel}'] = out
        res[f'trace_stats_{parallel}'] = stats
    return res


def test_batches_aot_are_bit_identical_to_jit(backends: dict,
                                              monkeypatch: pytest.MonkeyPatch) -> None:
    out = {}
    for kind, backend in backends.items():
        _use(monkeypatch, backend)
        out[kind] = _batch_outputs()
    # the runs move the spool and differ between rows (else the comparison proves little)
    assert np.ptp(out['jit']['step_cur'][:, -1]) > 0.0
    assert np.ptp(out['jit']['trace_True'][:, :, 2]) > 1e-4
    for name, value in out['jit'].items():
        assert np.array_equal(out['aot'][name], value), name
    assert np.array_equal(out['jit']['trace_True'], out['jit']['trace_False'])


def test_batch_rows_on_threads_equal_one_thread(backends: dict,
                                                monkeypatch: pytest.MonkeyPatch) -> None:
    """The rows of a batch shared over threads give the numbers of one thread."""
    from valve_model_pkg.model import kernel

    _use(monkeypatch, backends['aot'])
    out = {}
    for threads in ('1', '3'):
        monkeypatch.setenv('NUMBA_NUM_THREADS', threads)
        assert kernel.batch_threads() == int(threads)
        out[threads] = _batch_outputs()
    for name, value in out['1'].items():
        assert np.array_equal(out['3'][name], value), name


def test_the_simulation_entries_on_the_aot_module_never_import_numba(aot_dir: Path) -> None:
    """A cold simulate_step (and every other entry) runs without numba or llvmlite."""
    code = (
        'import sys\n'
        'import valve_model_pkg.model as m\n'
        'from valve_model_pkg.model import aot\n'
        'p = m.load_parameters()\n'
        'assert m.simulate_step(p).spool_position_m[-1] > 0.0\n'
        'm.simulate_pwm(p, duration_s=0.05)\n'
        'm.simulate_trace_batch([p, p], m.InputTrace.step(), [0.001, 0.005])\n'
        'm.simulate_trace_batch([p, p], m.InputTrace.pwm_commands([0.0], duty=[0.5]),\n'
        '                       n_periods=2)\n'
        'm.simulate_trace_batch([p] * 9, m.InputTrace.pwm_commands([0.0], duty=[0.5]),\n'
        '                       [0.01, 0.02])\n'
        'print(aot.backend_name(), sorted(n for n in sys.modules\n'
        '      if n.split(".")[0] in ("numba", "llvmlite")))\n'
    )
    env = dict(os.environ, **{aot.ENV_DIR: str(aot_dir)})
    done = subprocess.run([sys.executable, '-c', code], env=env, capture_output=True,
                          text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == 'aot []', done.stdout


def test_layout_constants_are_the_kernels() -> None:
    from valve_model_pkg.model import kernel
    layout = aot.layout()
    assert {'D_T', 'N_D', 'N_OUT', 'S_I_MEAN', 'IV_DONE', 'DEFAULT_H_FREE_S'} <= set(layout)
    for name, value in layout.items():
        assert getattr(kernel, name) == value, name
    public = {n for n in dir(kernel) if n.isupper() and type(getattr(kernel, n)) in (int, float)}
    assert public <= set(layout)  # every integer constant of the kernel's layouts is read


def _select_in(directory: Path | str, monkeypatch: pytest.MonkeyPatch):
    monkeypatch.setenv(aot.ENV_DIR, str(directory))
    monkeypatch.setattr(aot, '_backend', None)
    return aot.backend()


def test_the_aot_module_is_chosen_when_current(aot_dir: Path,
                                               monkeypatch: pytest.MonkeyPatch) -> None:
    chosen = _select_in(aot_dir, monkeypatch)
    assert chosen.name == 'aot' and str(aot_dir) in chosen.origin


def test_missing_module_falls_back_to_jit(tmp_path: Path,
                                          monkeypatch: pytest.MonkeyPatch) -> None:
    chosen = _select_in(tmp_path, monkeypatch)
    assert chosen.name == 'jit' and 'no AOT module' in chosen.origin
    s = ValveStepper(load_parameters())
    s.set_command(0.5, 50.0)
    s.advance_to(0.03)
    assert s.sample().spool_position_m > 0.0


def test_stale_module_falls_back_to_jit(aot_dir: Path, tmp_path: Path,
                                        monkeypatch: pytest.MonkeyPatch) -> None:
    """A module built from another kernel (another key) is never loaded."""
    current = aot.find_module(aot_dir, aot.kernel_key())
    stale = tmp_path / current.name.replace(aot.kernel_key(), '0123456789abcdef')
    shutil.copyfile(current, stale)
    chosen = _select_in(tmp_path, monkeypatch)
    assert chosen.name == 'jit' and aot.kernel_key() in chosen.origin


def test_broken_module_falls_back_to_jit(tmp_path: Path,
                                         monkeypatch: pytest.MonkeyPatch) -> None:
    import importlib.machinery
    broken = tmp_path / (aot.module_name(aot.kernel_key())
                         + importlib.machinery.EXTENSION_SUFFIXES[0])
    broken.write_bytes(b'not an ELF file')
    chosen = _select_in(tmp_path, monkeypatch)
    assert chosen.name == 'jit' and 'failed' in chosen.origin


def test_switched_off_uses_jit(monkeypatch: pytest.MonkeyPatch) -> None:
    chosen = _select_in('off', monkeypatch)
    assert chosen.name == 'jit'


def test_the_node_with_the_aot_module_never_imports_numba(aot_dir: Path) -> None:
    code = (
        'import sys\n'
        'import valve_model_pkg.nodes.simulator_node\n'
        'import valve_model_pkg.nodes.bank_simulator_node\n'
        'from valve_model_pkg.model import ValveStepper, ValveBank, load_parameters, aot\n'
        's = ValveStepper(load_parameters())\n'
        's.set_command(0.5, 50.0)\n'
        'for k in range(1, 46):  # to 45 ms: inside the second high phase\n'
        '    s.advance_to(k * 1e-3)\n'
        '    s.sample()\n'
        'b = ValveBank(load_parameters(), n_valves=2)\n'
        'b.advance_to(0.01)\n'
        'b.sample_array()\n'
        'assert s.sample().spool_position_m > 0.0\n'
        'print(aot.backend_name(), sorted(n for n in sys.modules\n'
        '      if n.split(".")[0] in ("numba", "llvmlite")))\n'
    )
    env = dict(os.environ, **{aot.ENV_DIR: str(aot_dir)})
    done = subprocess.run([sys.executable, '-c', code], env=env, capture_output=True,
                          text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == 'aot []', done.stdout


def test_build_refuses_a_file_as_output_dir(tmp_path: Path) -> None:
    target = tmp_path / 'a_file'
    target.write_text('x')
    done = subprocess.run([sys.executable, '-m', 'valve_model_pkg.model.aot_build', '--out',
                           str(target)], capture_output=True, text=True, timeout=120)
    assert done.returncode == 2
    assert 'not a directory' in done.stderr and 'Traceback' not in done.stderr


def test_steppers_and_banks_on_the_aot_module_pickle(backends: dict,
                                                     monkeypatch: pytest.MonkeyPatch) -> None:
    """The module's functions do not pickle; the objects drop and re-pick the backend."""
    import pickle
    _use(monkeypatch, backends['aot'])
    s = ValveStepper(load_parameters(), duty=0.5)
    s.advance_to(0.03)
    copy = pickle.loads(pickle.dumps(s))
    for obj in (s, copy):
        obj.advance_to(0.05)
    assert copy.sample() == s.sample() and s.sample().spool_position_m > 0.0
    b = ValveBank(load_parameters(), n_valves=2, duty=0.5)
    b.advance_to(0.03)
    b_copy = pickle.loads(pickle.dumps(b))
    for obj in (b, b_copy):
        obj.advance_to(0.05)
    assert np.array_equal(b_copy.sample_array(), b.sample_array())
