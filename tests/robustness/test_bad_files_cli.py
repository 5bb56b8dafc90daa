"""Every documented command over a table of bad files: exit 2, one line naming the file.

Commands (see their ``--help``): valve_simulate and valve_map (``--params``),
valve_identify (``--fit``, ``--params``), valve_flow_check (the flow map, ``--params``),
valve_report (the bag). Each bad file must give exit status 2, exactly one non-empty
stderr line that names the file, and no traceback; memory stays bounded.

The table runs in one child process (this file run as a script calls each command's
``main`` with stderr captured), which keeps it fast; a few cases also run through the real
console scripts.
"""
from __future__ import annotations

import contextlib
import io
import json
import logging
import os
import shutil
import subprocess
import sys
import traceback
from pathlib import Path

import pytest

#: Largest peak memory of the child running the whole table [bytes].
MEMORY_BOUND = 1.5e9

CSV_HEAD = ('# experiment: step\n# supply_pressure_pa: 400000\n# sample_rate_hz: 50000\n'
            't,voltage,current\n')
FLOW_HEAD = ('# experiment: flow_map\n# pwm_frequency_hz: 50\n# supply_pressure_pa: 400000\n'
             'duty,flow_fraction\n')


def _yaml_with(key: str, value: str) -> bytes:
    from valve_model_pkg.model import default_parameters_path
    out = []
    for line in default_parameters_path().read_text(encoding='utf-8').splitlines():
        if line.strip().startswith(f'{key}:'):
            line = f'{line[:len(line) - len(line.lstrip())]}{key}: {value}'
        out.append(line)
    return ('\n'.join(out) + '\n').encode()


def _rows(n: int, fmt: str) -> str:
    return ''.join(fmt.format(t=k * 2e-5, k=k) for k in range(n))


#: name -> content (bytes), or an int: a sparse file of that many bytes
COMMON: dict[str, bytes | int] = {
    'empty': b'',
    'binary': bytes(range(256)) * 64,
    'non_utf8': b'# experiment: step\n# valve: b\xe9nch 7\nt,voltage,current\n0,24,0\n',
    'hash_only': b'# experiment: step\n# supply_pressure_pa: 400000\n',
    'one_million_columns': b'1.0,' * 1_000_000 + b'1.0\n',
    'sparse_600mb': 600 << 20,
}

#: per input kind: its own bad files on top of COMMON
KIND: dict[str, dict[str, bytes | int]] = {
    'yaml': {
        'only_a_header': b'valve:\n',
        'huge_number': _yaml_with('spool_mass_kg', '1e400'),
        'tiny_mass': _yaml_with('spool_mass_kg', '1.0e-300'),
        'stiffness_1e300': _yaml_with('spring_stiffness_n_per_m', '1e300'),
        'coil_turns_1e12': _yaml_with('coil_turns', '1e12'),
        'spool_1000_kg': _yaml_with('spool_mass_kg', '1000'),
        'nan': _yaml_with('damping_n_s_per_m', '.nan'),
        'duplicate_key': _yaml_with('coil_turns', '1250\n  coil_turns: 1300'),
        'not_a_mapping': b'- 1\n- 2\n',
    },
    'trace': {
        'only_a_header': b't,voltage,current\n',
        'huge_numbers': (CSV_HEAD + _rows(20, '{t:.6g},1e400,0.1\n')).encode(),
        'nan_cells': (CSV_HEAD + _rows(20, '{t:.6g},nan,0.1\n')).encode(),
        'time_in_ms': (CSV_HEAD + _rows(20, '{k}e-2,24,0.1\n')).encode(),
        'current_1e6_a': (CSV_HEAD + _rows(20, '{t:.6g},24,0.1\n')
                          + '4e-4,24,1e6\n').encode(),
        'no_excitation': (CSV_HEAD + _rows(50, '{t:.6g},0,0\n')).encode(),
        # 15 V on, the current stays 0 (a broken channel, a step that did not happen)
        'current_zero_while_on': (CSV_HEAD + _rows(20, '{t:.6g},0,0\n')
                                  + _rows(200, '{t:.6g},15,0\n')).encode(),
        # the current stays within its +-2 mA noise while 15 V is on
        'current_in_its_noise_while_on': (
            CSV_HEAD + ''.join(f'{k * 2e-5:.6g},{15 if k >= 40 else 0},'
                               f'{2e-3 * ((k * 7919) % 11 - 5) / 5:.6g}\n'
                               for k in range(400))).encode(),
    },
    'flow_map': {
        'only_a_header': FLOW_HEAD.encode(),
        'huge_numbers': (FLOW_HEAD + '0,0\n0.5,1e400\n1,1\n').encode(),
        'nan_cells': (FLOW_HEAD + '0,0\n0.5,nan\n1,1\n').encode(),
    },
    'bag': {
        'only_a_header': b'\x89MCAP0\r\n',
        'flipped_mcap': b'\x89MCAP0\r\n' + bytes(range(256)) * 16,
    },
}

#: command -> (input kind, argv with FILE and OUT)
COMMANDS: dict[str, tuple[str, list[str]]] = {
    'valve_simulate': ('yaml', ['--params', 'FILE', '-o', 'OUT/x.csv', '--no-plot', '-q']),
    'valve_map': ('yaml', ['--params', 'FILE', '-o', 'OUT/m.json', '--no-figures', '-q']),
    'valve_identify': ('trace', ['--fit', 'FILE', '-o', 'OUT/ident', '--quick']),
    'valve_identify --params': ('yaml', ['--fit', 'GOOD_TRACE', '--params', 'FILE', '-o',
                                         'OUT/ident', '--quick']),
    'valve_flow_check': ('flow_map', ['FILE', '-o', 'OUT/cmp.json']),
    'valve_flow_check --params': ('yaml', ['GOOD_FLOW', '--params', 'FILE', '-o',
                                           'OUT/cmp.json']),
    'valve_report': ('bag', ['FILE', '-o', 'OUT/report']),
}


def _mains() -> dict:
    from valve_model_pkg.cli import flow_check, identify, map, report, simulate
    return {'valve_simulate': simulate.main, 'valve_map': map.main,
            'valve_identify': identify.main, 'valve_flow_check': flow_check.main,
            'valve_report': report.main}


def cases() -> list[tuple[str, str]]:
    """(command key, bad file name) of the whole table."""
    return [(cmd, name) for cmd, (kind, _) in COMMANDS.items()
            for name in list(COMMON) + list(KIND[kind])]


def _make(path: Path, content: bytes | int) -> Path:
    if isinstance(content, int):
        with open(path, 'wb') as fh:
            fh.truncate(content)  # sparse: no real write
    else:
        path.write_bytes(content)
    return path


def _good_inputs(work: Path) -> dict[str, str]:
    import numpy as np
    from valve_model_pkg.dataformat import write_table
    t = np.arange(100) * 2e-5
    trace = write_table(work / 'good_trace.csv',
                        {'experiment': 'step', 'supply_pressure_pa': 4e5,
                         'sample_rate_hz': 5e4},
                        {'t': t, 'voltage': np.full(100, 24.0), 'current': t * 1e3})
    flow = write_table(work / 'good_flow.csv',
                       {'experiment': 'flow_map', 'pwm_frequency_hz': 50,
                        'supply_pressure_pa': 4e5},
                       {'duty': np.linspace(0, 1, 11), 'flow_fraction': np.linspace(0, 1, 11)})
    return {'GOOD_TRACE': str(trace), 'GOOD_FLOW': str(flow)}


def run_table(work: Path) -> dict[str, dict]:
    """Run every case in this process; returns {'cmd|file': {code, stderr, traceback}}."""
    mains = _mains()
    good = _good_inputs(work)
    results = {}
    for cmd, name in cases():
        kind, template = COMMANDS[cmd]
        content = COMMON.get(name, KIND[kind].get(name))
        case_dir = work / f'{cmd.replace(" ", "_")}__{name}'
        case_dir.mkdir()
        suffix = {'yaml': '.yaml', 'bag': '.mcap'}.get(kind, '.csv')
        bad = _make(case_dir / f'bad_{name}{suffix}', content)
        out = case_dir / 'out'
        out.mkdir()
        argv = [good.get(a, a.replace('FILE', str(bad)).replace('OUT', str(out)))
                for a in template]
        err = io.StringIO()
        tb = ''
        code = None
        root = logging.getLogger()
        root.handlers[:] = []  # a command's basicConfig binds the stderr of its own run
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            try:
                code = mains[cmd.split()[0]](argv)
            except SystemExit as exc:
                code = exc.code
            except BaseException:  # noqa: BLE001 - a traceback is what the test looks for
                tb = traceback.format_exc()
        results[f'{cmd}|{name}'] = {'code': code, 'stderr': err.getvalue(), 'traceback': tb,
                                    'file': str(bad)}
    return results


@pytest.fixture(scope='module')
def table(tmp_path_factory: pytest.TempPathFactory) -> dict:
    work = tmp_path_factory.mktemp('bad_files')
    proc = subprocess.Popen([sys.executable, __file__, str(work)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE)
    _, status, usage = os.wait4(proc.pid, 0)
    out, err = proc.stdout.read(), proc.stderr.read()
    assert os.waitstatus_to_exitcode(status) == 0, err.decode()[-3000:]
    results = json.loads(out)
    results['__peak_bytes__'] = usage.ru_maxrss * 1024
    return results


def test_memory_of_the_whole_table_stays_bounded(table: dict) -> None:
    print(f'peak memory of the bad-file table: {table["__peak_bytes__"] / 1e6:.0f} MB')
    assert table['__peak_bytes__'] < MEMORY_BOUND


@pytest.mark.parametrize('cmd, name', cases())
def test_bad_file_gives_exit_2_and_one_line_naming_it(table: dict, cmd: str,
                                                      name: str) -> None:
    r = table[f'{cmd}|{name}']
    assert not r['traceback'], r['traceback']
    lines = [ln for ln in r['stderr'].splitlines() if ln.strip()]
    assert r['code'] == 2, (r['code'], r['stderr'])
    assert len(lines) == 1, r['stderr']
    assert r['file'] in lines[0] and lines[0].startswith(f'{cmd.split()[0]}: ')
    assert 'Traceback' not in r['stderr']


@pytest.mark.parametrize('script, argv', [
    ('valve_simulate', ['--params', 'FILE', '-o', 'OUT/x.csv', '--no-plot']),
    ('valve_map', ['--params', 'FILE', '-o', 'OUT/m.json', '--no-figures']),
    ('valve_identify', ['--fit', 'FILE', '-o', 'OUT/ident']),
])
def test_console_scripts_refuse_a_binary_file_in_one_line(tmp_path: Path, script: str,
                                                          argv: list[str]) -> None:
    path = shutil.which(script)
    assert path, 'source ros2_ws/env.bash'
    bad = _make(tmp_path / 'bad.bin', COMMON['binary'])
    proc = subprocess.run([path] + [a.replace('FILE', str(bad)).replace('OUT', str(tmp_path))
                                    for a in argv],
                          capture_output=True, text=True, timeout=120, stdin=subprocess.DEVNULL)
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert proc.returncode == 2 and len(lines) == 1 and str(bad) in lines[0], proc.stderr
    assert 'Traceback' not in proc.stderr


if __name__ == '__main__':
    print(json.dumps(run_table(Path(sys.argv[1]))))
