"""The live view: the suite's topics on a Foxglove WebSocket server (loopback by default).

    python -m valve_bringup.live [--host 127.0.0.1] [--port 8765] [TOPIC[:TYPE] ...]

``make demo LIVE=1`` (``valve_demo --live``) starts it beside the suite. It subscribes to
each topic (default: the suite's topics) with ``raw=True`` and relays the CDR bytes
unchanged on a ``foxglove-sdk`` WebSocket channel whose schema is the message definition
(``ros2msg``), so Foxglove decodes them as it decodes a bag; a topic whose type is not
given is relayed once the ROS graph shows its type. In Foxglove: *Open connection ->
Foxglove WebSocket -> ws://127.0.0.1:8765*, then *Layout -> Import from file* with
``layouts/valve_suite.foxglove.json``.

The server binds 127.0.0.1 unless ``--host`` says otherwise (docs/safety.md: nothing of the
suite listens beyond the machine by default). SIGINT/SIGTERM end it with exit 0.
"""
from __future__ import annotations

import argparse
import importlib
import signal
import sys
import threading

import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.signals import SignalHandlerOptions

from valve_model_pkg.interface.ros import RELAY_QOS
from valve_model_pkg.recording import (DEFAULT_TOPICS, build_typestore, msgdef_and_hash,
                                       parse_topic_spec)

__all__ = ['main']


def _parse(argv: list[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog='valve_live', description=__doc__.split('\n')[0])
    parser.add_argument('--host', default='127.0.0.1',
                        help='address to bind (default: loopback only)')
    parser.add_argument('--port', type=int, default=8765, help='WebSocket port')
    parser.add_argument('topics', nargs='*',
                        help='topics to relay, NAME or NAME:pkg/msg/Type (default: the '
                        'suite\'s topics)')
    return parser.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    """Relay until SIGINT/SIGTERM; 0 on a normal end, 2 on a refused argument."""
    args = _parse(argv)
    if not 1 <= args.port <= 65535:
        print(f'valve_live: error: --port {args.port!r}: expected 1 .. 65535', file=sys.stderr)
        return 2
    # foxglove-sdk has no rosdep key (package.xml): a ROS install without the pip
    # requirements still answers --help and refuses a bad port
    import foxglove

    stop = threading.Event()
    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, lambda *_: stop.set())
    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    node = rclpy.create_node('valve_live_view')
    server = foxglove.start_server(name='valve suite', host=args.host, port=args.port)
    store = build_typestore()
    wanted = [parse_topic_spec(t) for t in (args.topics or DEFAULT_TOPICS)]
    relayed: dict[str, object] = {}

    def relay(topic: str, msgtype: str) -> None:
        pkg, _, name = msgtype.split('/')
        cls = getattr(importlib.import_module(f'{pkg}.msg'), name)
        text, _ = msgdef_and_hash(store, msgtype)
        channel = foxglove.Channel(topic, schema=foxglove.Schema(
            name=msgtype, encoding='ros2msg', data=text.encode()), message_encoding='cdr')

        def forward(raw: bytes) -> None:
            channel.log(raw)
        relayed[topic] = node.create_subscription(cls, topic, forward, RELAY_QOS,
                                                  raw=True)
        node.get_logger().info(f'relaying {topic} ({msgtype})')

    def discover() -> None:
        known = dict(node.get_topic_names_and_types())
        for name, msgtype in wanted:
            topic = name if name.startswith('/') else '/' + name
            if topic in relayed:
                continue
            if msgtype is None and known.get(topic):
                msgtype = known[topic][0]
            if msgtype is not None:
                try:
                    relay(topic, msgtype)
                except (ImportError, AttributeError, KeyError, ValueError) as err:
                    node.get_logger().warning(f'cannot relay {topic}: {err}')
                    relayed[topic] = None
    discover()
    node.create_timer(1.0, discover)
    node.get_logger().info(f'live view: ws://{args.host}:{server.port} (Foxglove WebSocket)')
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    try:
        while not stop.is_set() and rclpy.ok():
            executor.spin_once(timeout_sec=0.1)
    finally:
        server.stop()
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == '__main__':
    sys.exit(main())
