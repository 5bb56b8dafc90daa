"""Benchmark the simulator node: peak memory and real-time behaviour at 1 kHz.

Peak resident memory (VmHWM) of ``valve_simulator`` publishing at
1 kHz for DURATION_S, against a bare rclpy node process measured in the same run (what
rclpy + DDS cost before any valve code). Also records the achieved publish rate seen by a
subscriber and the ticks the node itself reported as fallen behind.
Writes benchmarks/results/node.json.
"""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
DURATION_S = 20.0
os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
os.environ['ROS_DOMAIN_ID'] = str(1 + os.getpid() % 100)

BARE_NODE = (
    'import rclpy, time\n'
    'rclpy.init()\n'
    'n = rclpy.create_node("bare")\n'
    'try:\n'
    '    rclpy.spin(n)\n'
    'except KeyboardInterrupt:\n'
    '    pass\n'
)


def _peak_rss_mb(pid: int) -> float:
    for line in Path(f'/proc/{pid}/status').read_text().splitlines():
        if line.startswith('VmHWM:'):
            return int(line.split()[1]) / 1024.0
    return float('nan')


def _run(argv: list[str], seconds: float, during=None) -> tuple[float, object]:
    proc = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            start_new_session=True)
    try:
        result = during(seconds) if during else time.sleep(seconds)
        peak = _peak_rss_mb(proc.pid)
    finally:
        os.killpg(proc.pid, signal.SIGINT)
        proc.wait(timeout=20)
    return peak, result


def _observe(seconds: float) -> dict:
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray

    from valve_model_pkg.nodes.common import TOPIC_DIAGNOSTICS
    from valve_model_pkg.nodes.probe import StateProbe
    rclpy.init()
    probe = StateProbe('bench_probe')
    behind = {'value': 0}

    def on_diag(msg: DiagnosticArray) -> None:
        for status in msg.status:
            for kv in status.values:
                if kv.key == 'ticks_behind':
                    behind['value'] = max(behind['value'], int(kv.value))
    probe.create_subscription(DiagnosticArray, TOPIC_DIAGNOSTICS, on_diag, 10)
    end = time.monotonic() + 60
    while probe.count < 100 and time.monotonic() < end:
        rclpy.spin_once(probe, timeout_sec=0.1)
    behind_at_start = behind['value']  # start-up (imports, JIT load) is not steady state
    probe.reset_window()
    start = time.monotonic()
    while time.monotonic() - start < seconds:
        rclpy.spin_once(probe, timeout_sec=0.05)
    w = probe.window()
    out = {'rate_hz': w.count / (time.monotonic() - start), 'stamp_rate_hz': w.rate_hz,
           'gaps': probe.gaps, 'ticks_behind': behind['value'] - behind_at_start}
    probe.destroy_node()
    rclpy.shutdown()
    return out


def main() -> int:
    bare_peak, _ = _run([sys.executable, '-c', BARE_NODE], 5.0)
    sim_peak, obs = _run(['valve_simulator', '--ros-args', '-p', 'publish_rate_hz:=1000.0'],
                         DURATION_S, _observe)
    records = [
        {'name': 'simulator node peak memory (VmHWM) at 1 kHz', 'value': sim_peak,
         'unit': 'MB', 'reference_name': 'bare rclpy node', 'reference_value': bare_peak,
         'ratio': sim_peak / bare_peak, 'target': '< 200 MB', 'passed': sim_peak < 200.0,
         'notes': f'{DURATION_S:g} s at 1 kHz'},
        {'name': 'simulator node state rate seen by a subscriber', 'value': obs['rate_hz'],
         'unit': 'Hz', 'reference_name': 'configured rate', 'reference_value': 1000.0,
         'ratio': obs['rate_hz'] / 1000.0, 'target': '1000 Hz +-20 %',
         'passed': abs(obs['rate_hz'] - 1000.0) <= 200.0,
         'notes': f"sequence gaps {obs['gaps']}, stamp rate {obs['stamp_rate_hz']:.1f} Hz"},
        {'name': 'simulator node ticks fallen behind (steady state)',
         'value': float(obs['ticks_behind']), 'unit': 'ticks',
         'reference_name': 'ticks in the window', 'reference_value': DURATION_S * 1000.0,
         'ratio': obs['ticks_behind'] / (DURATION_S * 1000.0), 'target': '0 (no overruns)',
         'passed': obs['ticks_behind'] == 0, 'notes': 'as reported in /diagnostics'},
    ]
    (HERE / 'results').mkdir(exist_ok=True)
    (HERE / 'results' / 'node.json').write_text(json.dumps(records, indent=2) + '\n')
    for r in records:
        print(f"{r['name']}: {r['value']:.4g} {r['unit']} (target {r['target']})")
    return 0


if __name__ == '__main__':
    sys.exit(main())
