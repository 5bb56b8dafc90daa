"""Benchmark the command path: a duty command's publication to the duty in force.

For the simulator backend (``valve_simulator``) and the CAN backend
(``valve_controller_emulator`` + ``valve_can_driver`` as ``valve_bringup.backend`` starts
them), idle and beside two CPU hogs (``python3 -c 'while True: pass'``, killed after), this
process publishes ``valve/duty_command`` and measures, on its own monotonic clock, the time
from the publication to the first ``valve/state`` that shows the command in force:

* start: a non-zero duty at 1000 Hz PWM (the highest frequency, so the next period start
  adds at most 1 ms): ``duty`` equals the commanded value;
* stop: duty 0 (acts at once, docs/safety.md "Close semantics"): ``duty`` is 0 and
  ``coil_voltage`` <= 0.

The subscriber keeps only the newest state (depth 1), so a backlog of 1 kHz states in
this process is not counted; its own scheduling delay is (what a controller node that
keeps up sees).
Writes benchmarks/results/latency.json (p50, p99, max per backend, load and kind).
"""
from __future__ import annotations

import json
import os
import random
import signal
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
COMMANDS_PER_KIND = 40           # per backend and load: 40 starts and 40 stops
SETTLE_TIMEOUT_S = 2.0
os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
os.environ['ROS_DOMAIN_ID'] = str(1 + os.getpid() % 100)


def _start(argv: list[str]) -> subprocess.Popen:
    return subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            start_new_session=True)


def _stop(procs: list[subprocess.Popen], sig: int = signal.SIGINT) -> None:
    for proc in procs:
        try:
            os.killpg(proc.pid, sig)
        except ProcessLookupError:
            pass
    for proc in procs:
        try:
            proc.wait(timeout=15)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()


class Probe:
    """Publishes duty commands and watches valve/state (rclpy, spun by the caller)."""

    def __init__(self) -> None:
        import rclpy
        from valve_model_pkg.interface import TOPIC_DUTY_COMMAND, TOPIC_STATE
        from valve_model_pkg.interface.ros import COMMAND_QOS, STATE_QOS
        from rclpy.qos import QoSProfile
        from valve_msgs.msg import DutyCommand, ValveState
        self.rclpy = rclpy
        self.node = rclpy.create_node('bench_latency')
        self._msg_type = DutyCommand
        self.pub = self.node.create_publisher(DutyCommand, TOPIC_DUTY_COMMAND, COMMAND_QOS)
        # Keep only the newest state: a 1 kHz stream queued behind a starved subscriber
        # would measure this process's backlog, not the backend's command path.
        qos = QoSProfile(depth=1, reliability=STATE_QOS.reliability,
                         durability=STATE_QOS.durability)
        self.node.create_subscription(ValveState, TOPIC_STATE, self._on_state, qos)
        self.count = 0
        self.wanted: float | None = None
        self.done_at: float | None = None
        self.sequence = 0

    def _on_state(self, msg) -> None:
        self.count += 1
        if self.wanted is None or self.done_at is not None:
            return
        if self.wanted == 0.0:
            ok = msg.duty == 0.0 and msg.coil_voltage <= 0.0
        else:
            ok = abs(msg.duty - self.wanted) < 1e-3
        if ok:
            self.done_at = time.monotonic()

    def spin_for(self, seconds: float) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self.rclpy.spin_once(self.node, timeout_sec=0.005)

    def command(self, duty: float, freq: float = 1000.0) -> float | None:
        """Publish one command; the latency to its state in s (None: not seen in time)."""
        msg = self._msg_type()
        msg.header.stamp = self.node.get_clock().now().to_msg()
        msg.header.frame_id = 'bench_latency'
        msg.sequence = self.sequence
        self.sequence += 1
        msg.duty = float(duty)
        msg.pwm_frequency = float(freq)
        self.wanted, self.done_at = float(duty), None
        t0 = time.monotonic()
        self.pub.publish(msg)
        end = t0 + SETTLE_TIMEOUT_S
        while self.done_at is None and time.monotonic() < end:
            self.rclpy.spin_once(self.node, timeout_sec=0.002)
        self.wanted = None
        return None if self.done_at is None else self.done_at - t0

    def wait_for_states(self, timeout_s: float = 60.0) -> bool:
        end = time.monotonic() + timeout_s
        while self.count < 200 and time.monotonic() < end:
            self.rclpy.spin_once(self.node, timeout_sec=0.05)
        return self.count >= 200


def _measure(probe: Probe, rng: random.Random) -> dict[str, list[float]]:
    out: dict[str, list[float]] = {'start': [], 'stop': [], 'missed': []}
    for _ in range(COMMANDS_PER_KIND):
        duty = round(rng.uniform(0.2, 0.8), 3)
        for kind, value in (('start', duty), ('stop', 0.0)):
            lat = probe.command(value)
            if lat is None:
                out['missed'].append(value)
            else:
                out[kind].append(lat)
            probe.spin_for(rng.uniform(0.02, 0.05))
    return out


def _percentile(values: list[float], q: float) -> float:
    if not values:
        return float('nan')
    s = sorted(values)
    k = min(len(s) - 1, max(0, int(round(q / 100.0 * (len(s) - 1)))))
    return s[k]


def _backend(name: str) -> list[list[str]]:
    if name == 'simulator':
        return [['valve_simulator', '--ros-args', '-p', 'publish_rate_hz:=1000.0']]
    from valve_bringup.backend import can_backend_commands
    commands = can_backend_commands(1000.0)
    return [commands['valve_controller_emulator'], commands['valve_can_driver']]


def main() -> int:
    import rclpy
    rclpy.init()
    rng = random.Random(11)
    results: dict[tuple[str, str], dict] = {}
    try:
        for backend in ('simulator', 'can'):
            procs = []
            for argv in _backend(backend):
                procs.append(_start(argv))
                time.sleep(0.5)                       # the emulator hosts the bus first
            probe = Probe()
            try:
                if not probe.wait_for_states():
                    print(f'{backend}: no valve/state', file=sys.stderr)
                    return 1
                probe.command(0.0)
                for load in ('idle', 'two CPU hogs'):
                    hogs = []
                    if load != 'idle':
                        hogs = [_start([sys.executable, '-c', 'while True: pass'])
                                for _ in range(2)]
                        time.sleep(1.0)
                    try:
                        results[(backend, load)] = _measure(probe, rng)
                    finally:
                        _stop(hogs, signal.SIGKILL)
            finally:
                probe.node.destroy_node()
                _stop(procs)
    finally:
        rclpy.shutdown()
    load_avg = os.getloadavg()[0]
    records = []
    for (backend, load), data in results.items():
        for kind in ('start', 'stop'):
            values = [v * 1e3 for v in data[kind]]
            what = ('non-zero duty at 1 kHz PWM: duty field equal' if kind == 'start'
                    else 'duty 0: duty field 0 and coil voltage <= 0')
            for stat, q in (('p50', 50.0), ('p99', 99.0), ('max', 100.0)):
                value = _percentile(values, q)
                records.append({
                    'name': f'latency_{backend}_{kind}_{stat}_{load.replace(" ", "_")}',
                    'value': value, 'unit': 'ms',
                    'reference_name': 'one 1 kHz state period', 'reference_value': 1.0,
                    'ratio': value / 1.0, 'target': 'informative', 'passed': True,
                    'notes': (f'{backend} backend, {load}: publication of a DutyCommand to '
                              f'the first valve/state with it in force ({what}); '
                              f'{len(values)} commands, {len(data["missed"])} not seen '
                              f'within {SETTLE_TIMEOUT_S:g} s; load average {load_avg:.1f} '
                              f'on {os.cpu_count()} CPUs')})
    (HERE / 'results').mkdir(exist_ok=True)
    (HERE / 'results' / 'latency.json').write_text(json.dumps(records, indent=1) + '\n')
    print(f'{"backend":10} {"load":13} {"kind":6} {"p50 ms":>8} {"p99 ms":>8} {"max ms":>8}')
    for (backend, load), data in results.items():
        for kind in ('start', 'stop'):
            v = [x * 1e3 for x in data[kind]]
            print(f'{backend:10} {load:13} {kind:6} {_percentile(v, 50):8.2f} '
                  f'{_percentile(v, 99):8.2f} {_percentile(v, 100):8.2f}'
                  + (f'  ({len(data["missed"])} missed)' if data['missed'] else ''))
    return 0


if __name__ == '__main__':
    sys.exit(main())
