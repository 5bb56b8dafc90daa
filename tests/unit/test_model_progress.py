"""The kernel always advances time, also where a release and an impact fall on one instant.

At 200 Hz, duty 0.311875, 2 bar the falling edge of the second period (t = 6.559375 ms,
i = 0.5007 A) finds the spool on the closed stop with a force margin of +0.15 mN. The
kernel releases it; the capacitor pulse makes the force fall at once, so the first free
step ends below the stop and the Hermite interpolant puts the impact at the step start
(the real lift, 4e-19 m for 32 ns, is far below its resolution). A spool that re-crosses
its stop at the instant it left it is held there (``kernel._HOLD_ON_RECROSS``), and a
no-progress guard forces a step if events keep falling on one instant. Runs that could
loop run in a subprocess with a timeout, so a loop fails the test instead of hanging
pytest.
"""
from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2] / 'valve_model_pkg'
#: Generous: a fresh machine compiles the kernel first (about 13 s, more when busy).
TIMEOUT_S = 240.0
DUTY, FREQ_HZ, P_SUP_PA = 0.311875, 200.0, 2e5


def _run(code: str) -> list[str]:
    script = f'import sys; sys.path.insert(0, {str(ROOT)!r})\n' + textwrap.dedent(code)
    try:
        out = subprocess.run([sys.executable, '-c', script], capture_output=True, text=True,
                             timeout=TIMEOUT_S)
    except subprocess.TimeoutExpired:
        pytest.fail(f'the kernel did not return within {TIMEOUT_S:.0f} s (endless loop)')
    assert out.returncode == 0, out.stderr
    return out.stdout.split()


def test_falling_edge_with_just_positive_margin_returns() -> None:
    """The case above as a period batch and on the stepper, and points around it."""
    words = _run(f'''
        import numpy as np
        from valve_model_pkg.model import (ElectronicsConfig, InputTrace, ValveStepper,
                                           load_parameters, simulate_trace_batch)
        P, E = load_parameters(), ElectronicsConfig()
        res = simulate_trace_batch(P, InputTrace.pwm_commands([0.0], {DUTY}, {FREQ_HZ}),
                                   None, electronics=E, supply_pressure_pa={P_SUP_PA},
                                   n_periods=2, validate=False)
        print(res.period_avg_position_m.shape[1], int(res.n_forced_steps[0]))
        s = ValveStepper(P, E)
        s.set_pressures({P_SUP_PA}, 0.0)
        s.set_command({DUTY}, {FREQ_HZ})
        s.advance_to(0.02)
        print(repr(s.t_s))
        # neighbours: duties within 1e-4 of it, 1-3 bar, 200 and 100 Hz
        duty = np.repeat(np.linspace({DUTY} - 1e-4, {DUTY} + 1e-4, 21), 6)
        freq = np.tile(np.repeat([200.0, 100.0], 3), 21)
        p_sup = np.tile([1e5, 2e5, 3e5], 42)
        traces = [InputTrace.pwm_commands([0.0], d, f) for d, f in zip(duty, freq)]
        res = simulate_trace_batch(P, traces, None, electronics=E, supply_pressure_pa=p_sup,
                                   n_periods=4, validate=False)
        print(int(np.isfinite(res.period_avg_position_m).all()),
              int(res.n_forced_steps.max()))
    ''')
    assert words == ['2', '0', '0.02', '1', '0']


def test_stall_guard_breaks_the_original_loop() -> None:
    """Without holding the re-crossing spool the same state loops; the guard forces progress.

    ``_advance.py_func`` runs the kernel's loop as plain Python (the constant is frozen in
    the compiled code), in a subprocess in case the guard ever fails. The state is the
    one ``ValveStepper`` starts from (``kernel.new_drive_state``).
    """
    words = _run(f'''
        import numpy as np
        from valve_model_pkg.model import ElectronicsConfig, load_parameters
        from valve_model_pkg.model import kernel as K, kernel_jit as KJ
        p = K.derive_parameters(load_parameters().to_vector())
        e = ElectronicsConfig().to_vector()
        y = np.zeros(K.N_Y)
        d = K.new_drive_state(24.0, {DUTY}, 1.0 / {FREQ_HZ}, 0.0, {P_SUP_PA})
        K.advance(p, e, y, d, 0.0065)  # compiled, to just before the falling edge at 6.559375 ms
        KJ._HOLD_ON_RECROSS = False  # let the spool leave again at the same instant
        KJ._advance.py_func(p, e, y, d, 0.007, K.DEFAULT_H_FREE_S,
                           K.DEFAULT_H_STOP_S, np.zeros((0, K.N_OUT)), np.zeros(0))
        print(repr(float(d[K.D_T])), int(d[K.D_N_FORCED] >= 1), repr(float(y[K.Y_X])))
    ''')
    assert words == ['0.007', '1', '0.0']  # the spool stays closed, as when it is held


def test_event_storm_below_the_time_resolution_cannot_hang() -> None:
    """Controller ticks every 0.1 ps (below the 1 ps event tolerance): forced steps."""
    words = _run('''
        import numpy as np
        from valve_model_pkg.model import ElectronicsConfig, load_parameters
        from valve_model_pkg.model import electronics as el, kernel as K
        p = K.derive_parameters(load_parameters().to_vector())
        e = ElectronicsConfig().to_vector()
        e[el.E_CHOPPER_HZ] = 1e13
        y = np.zeros(K.N_Y)
        d = K.new_drive_state(24.0, 0.5, 0.02, 0.0, 4e5)
        K.advance(p, e, y, d, 1e-3)
        print(repr(float(d[K.D_T])), int(d[K.D_N_FORCED] > 0))
    ''')
    assert words == ['0.001', '1']
