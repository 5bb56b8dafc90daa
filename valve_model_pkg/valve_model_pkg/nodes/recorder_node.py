"""valve_recorder: record the suite's topics to a rosbag2 bag (MCAP storage), losslessly.

Usage (see docs/recording.md)::

    valve_recorder -o my_bag                      # all of the suite's topics
    valve_recorder -o my_bag /valve/state /valve/duty_command  my/topic:pkg/msg/Type
    valve_recorder --ros-args -p output:=my_bag -p flush_period_s:=0.5
    valve_recorder --info my_bag                  # like `ros2 bag info` (also killed bags)
    valve_recorder --recover my_bag [-o fixed]    # killed recorder: bag up to last chunk

Each topic is subscribed with ``raw=True``: the callback receives the CDR bytes and only
puts them on the queue of a writer thread (:class:`~valve_model_pkg.recording.writer.
QueuedBagWriter`), so the executor keeps up with 1 kHz. The bytes go into the bag as they
arrived, stamped with the middleware's receive time (system clock, ns since the epoch, as
``ros2 bag record`` does); the messages' own ``header.stamp`` is kept inside them.

Subscriptions are RELIABLE (best effort only if a topic's publishers are all best effort
when it is subscribed), VOLATILE, keep-last ``queue_depth`` (default 10000: 10 s of
valve/state for the executor to fall behind before DDS drops anything). The QoS each
publisher offers is read from the graph and stored with the topic, so ``ros2 bag play``
offers RELIABLE again.

Topics given with a type (or known suite topics) are subscribed at start; topics without a
type are subscribed as soon as the graph shows their type. SIGINT and SIGTERM close the
bag (summary + metadata.yaml); after SIGKILL the bag holds everything up to the last flush
(``flush_period_s``) and ``--recover`` makes a complete bag of it.

Publishes ``/diagnostics`` (diagnostic_msgs/DiagnosticArray) every ``diagnostics_period_s``:
messages received, written, flushed to disk, queue depth, gaps in the publishers' sequence
numbers (messages DDS lost before the recorder took them), publishers whose QoS the
recorder's subscription cannot match, and per topic the messages received (``count T``)
and the publishers its subscription has matched (``matched T``).

CPU: rclpy's executor costs a few hundred microseconds of Python per cycle. The callback
therefore takes every message waiting on its subscription, and the spin loop pauses
``batch_period_s`` between cycles, so valve/state is taken in batches of about five: about
a tenth of a core at 1 kHz instead of a third.
"""
from __future__ import annotations

import argparse
import contextlib
import functools
import importlib
import io
import logging
import signal
import sys
import tempfile
import threading
import time
from dataclasses import dataclass, field
from datetime import datetime
from pathlib import Path

import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rcl_interfaces.msg import ParameterDescriptor, ParameterType, SetParametersResult
from rclpy.event_handler import SubscriptionEventCallbacks
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions
from rclpy.utilities import remove_ros_args

from valve_model_pkg.nodes.common import (EXIT_FAILURE, EXIT_OK, EXIT_REFUSED,
                                          STARTUP_ERRORS, TOPIC_DIAGNOSTICS, DiagnosticLevel,
                                          declare_bool, declare_float, declare_int,
                                          declare_string, help_requested, key_values,
                                          print_node_help)
from valve_model_pkg.recording import (DEFAULT_TOPICS, BagWriteError, BagWriter,
                                       PublisherSequenceGaps, QueuedBagWriter, RecordingError,
                                       UnknownMessageTypeError, bag_info, ensure_type,
                                       make_qos, parse_topic_spec, qos_summary, recover_bag,
                                       reliable_qos)

NODE_NAME = 'valve_recorder'
#: Most messages taken from one subscription in one callback (bounds its run time).
_MAX_DRAIN = 1000


@dataclass
class _Topic:
    """What the node knows about one recorded topic."""

    name: str                   # fully qualified
    msgtype: str
    depth: int
    reliable: bool = True
    key: int | None = None      # writer key, set on the first message
    received: int = 0
    gaps: PublisherSequenceGaps = field(default_factory=PublisherSequenceGaps)
    subscription: object = None
    incompatible: tuple[str, ...] = ()  # publishers the subscription cannot match


def _message_class(msgtype: str) -> type:
    """The rosidl Python class of ``pkg/msg/Name`` (the package must be importable)."""
    package, _, name = msgtype.split('/')
    try:
        return getattr(importlib.import_module(f'{package}.msg'), name)
    except (ImportError, AttributeError) as err:
        raise UnknownMessageTypeError(
            f'message type {msgtype!r} has no Python class ({err}); is its package built '
            'and sourced?') from err


def _qos_time_ns(duration: object) -> int:
    return int(getattr(duration, 'nanoseconds', 2**63 - 1))


class RecorderNode(Node):
    """Subscribe to topics raw and hand the bytes to a bag writer thread."""

    def __init__(self, parameter_overrides: list[Parameter] | None = None) -> None:
        super().__init__(NODE_NAME, parameter_overrides=parameter_overrides or [])
        output = declare_string(
            self, 'output', '',
            'Bag directory to create (must not exist); empty = valve_<YYYYmmdd-HHMMSS> '
            'inside output_dir')
        output_dir = declare_string(
            self, 'output_dir', '.',
            'Where a bag named after the time goes when output is empty (created if needed)')
        topics = self._declare_string_array(
            'topics', list(DEFAULT_TOPICS),
            'Topics to record: "name" (suite topics know their type; others are discovered '
            'from the graph) or "name:pkg/msg/Type"')
        self._flush_period_s = declare_float(
            self, 'flush_period_s', 1.0,
            'Close and flush the pending MCAP chunk at least this often [s]: the most a '
            'killed recorder loses; 0 = only at 1 MiB chunks and on close', 0.0, 600.0)
        fsync = declare_bool(self, 'fsync', True,
                             'fsync after each flush (also survive a power cut)')
        self._depth = declare_int(
            self, 'queue_depth', 10_000,
            'History depth of each subscription: messages DDS holds while the executor is '
            'busy (10000 = 10 s of valve/state)', 1, 1_000_000)
        compression = declare_string(self, 'compression', 'none',
                                     'MCAP chunk compression: none or zstd')
        discovery_period = declare_float(
            self, 'discovery_period_s', 0.5,
            'How often to look for the type of topics given without one [s]', 0.05, 60.0)
        diag_period = declare_float(self, 'diagnostics_period_s', 1.0,
                                    'Period of the recorder\'s diagnostics [s]', 0.05, 60.0)
        self.batch_period_s = declare_float(
            self, 'batch_period_s', 0.005,
            'Pause of the spin loop between executor cycles [s]; messages wait in DDS '
            '(queue_depth) and are taken in batches, which saves CPU', 0.0, 0.1)
        if compression not in ('none', 'zstd'):
            raise ValueError(f"parameter 'compression' = {compression!r} is not none or zstd")

        path = Path(output) if output else \
            Path(output_dir) / f'valve_{datetime.now():%Y%m%d-%H%M%S}'
        writer = BagWriter(path, flush_period_s=self._flush_period_s, fsync=fsync,
                           compression=compression,
                           custom_data={'recorder': NODE_NAME,
                                        'timestamp': 'middleware receive time (system clock)',
                                        'flush_period_s': f'{self._flush_period_s:g}'})
        self._store = writer.typestore
        self._bag_path = path
        self._topics: dict[str, _Topic] = {}
        self._pending: list[str] = []  # fully qualified names waiting for a type
        # Check every typed topic before creating the bag: a wrong type fails the start.
        typed: list[tuple[str, str]] = []
        for spec in topics:
            name, msgtype = parse_topic_spec(spec)
            full = self.resolve_topic_name(name)
            if msgtype is None:
                self._pending.append(full)
            else:
                ensure_type(self._store, msgtype)
                _message_class(msgtype)
                typed.append((full, msgtype))
        self._writer = QueuedBagWriter(writer).start()
        try:
            for full, msgtype in typed:
                self._subscribe(full, msgtype)
        except BaseException:
            self._writer.close()  # a complete (if short) bag rather than a dangling one
            raise

        # Every parameter is read once, above; refuse run-time changes rather than
        # pretend to apply them to a bag already being written.
        self.add_on_set_parameters_callback(self._refuse_parameter_changes)
        self._diag_pub = self.create_publisher(DiagnosticArray, TOPIC_DIAGNOSTICS, 10)
        self.create_timer(diag_period, self._publish_diagnostics)
        if self._pending:
            self._discovery_timer = self.create_timer(discovery_period, self._discover)
        self.get_logger().info(
            f'recording {len(typed)} topics to {path} (flush every '
            f'{self._flush_period_s:g} s, fsync {fsync}, queue depth {self._depth}, '
            f'compression {compression})'
            + (f'; waiting for the type of {self._pending}' if self._pending else ''))

    # --- set-up ---------------------------------------------------------------------------
    def _declare_string_array(self, name: str, default: list[str], description: str
                              ) -> list[str]:
        descriptor = ParameterDescriptor(description=description,
                                         type=ParameterType.PARAMETER_STRING_ARRAY)
        value = self.declare_parameter(name, default, descriptor).value
        return [str(v) for v in value]

    @staticmethod
    def _refuse_parameter_changes(params: list[Parameter]) -> SetParametersResult:
        names = ', '.join(p.name for p in params)
        return SetParametersResult(
            successful=False, reason=f'{NODE_NAME} reads its parameters at start ({names} '
            'not changed); restart it to record with other settings')

    def _subscribe(self, topic: str, msgtype: str) -> None:
        """Subscribe ``topic`` raw, matching what its publishers offer if any exist yet."""
        pubs = self.get_publishers_info_by_topic(topic)
        reliable = not pubs or any(
            p.qos_profile.reliability == ReliabilityPolicy.RELIABLE for p in pubs)
        if pubs and not all(p.qos_profile.reliability == ReliabilityPolicy.RELIABLE
                            for p in pubs):
            reliable = False  # a reliable reader would not match the best-effort ones
        state = _Topic(topic, msgtype, self._depth, reliable=reliable)
        qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=self._depth,
                         reliability=(ReliabilityPolicy.RELIABLE if reliable
                                      else ReliabilityPolicy.BEST_EFFORT),
                         durability=DurabilityPolicy.VOLATILE)
        # No event handlers: rclpy's executor polls every one of them in Python on every
        # cycle (three per subscription by default), which costs more CPU at 1 kHz than
        # recording does. Losses show as publisher sequence gaps instead, and QoS
        # incompatibilities are checked in the diagnostics timer.
        events = SubscriptionEventCallbacks(use_default_callbacks=False)
        state.subscription = self.create_subscription(
            _message_class(msgtype), topic, functools.partial(self._on_message, state), qos,
            raw=True, event_callbacks=events)
        self._topics[topic] = state
        self.get_logger().debug(f'subscribed {topic} ({msgtype}, '
                                f'{"reliable" if reliable else "best effort"})')

    def _discover(self) -> None:
        """Subscribe pending topics whose type the graph now shows."""
        if not self._pending:
            return
        known = dict(self.get_topic_names_and_types())
        for topic in list(self._pending):
            types = known.get(topic)
            if not types:
                continue
            if len(types) > 1:
                self.get_logger().error(f'{topic} has several types {types}; give one as '
                                        f'"{topic}:pkg/msg/Type"; not recorded')
                self._pending.remove(topic)
                continue
            try:
                ensure_type(self._store, types[0])
                self._subscribe(topic, types[0])
            except UnknownMessageTypeError as err:
                self.get_logger().error(f'{topic} not recorded: {err}')
            self._pending.remove(topic)
        if not self._pending:
            self._discovery_timer.cancel()

    def _offered_qos(self, state: _Topic) -> list:
        """The QoS profiles the topic's publishers offer, as rosbag2 stores them."""
        out = []
        for info in self.get_publishers_info_by_topic(state.name):
            q = info.qos_profile
            out.append(make_qos(int(q.history), int(q.depth), int(q.reliability),
                                int(q.durability), deadline_ns=_qos_time_ns(q.deadline),
                                lifespan_ns=_qos_time_ns(q.lifespan),
                                liveliness=int(q.liveliness),
                                liveliness_lease_duration_ns=_qos_time_ns(
                                    q.liveliness_lease_duration),
                                avoid_ros_namespace_conventions=bool(
                                    q.avoid_ros_namespace_conventions)))
        return out or [reliable_qos(state.depth)]

    # --- hot path -------------------------------------------------------------------------
    def _on_message(self, state: _Topic, raw: bytes, info: dict) -> None:
        self._record(state, raw, info)
        # Take what else is waiting on this subscription now, instead of one message per
        # executor cycle: rclpy's executor costs several hundred microseconds a cycle, the
        # take itself a few. Under load the batches grow and the cost per message falls.
        sub = state.subscription
        for _ in range(_MAX_DRAIN):
            with sub.handle:
                taken = sub.handle.take_message(sub.msg_type, True)
            if taken is None:
                break
            self._record(state, taken[0], taken[1])

    def _record(self, state: _Topic, raw: bytes, info: dict) -> None:
        if state.key is None:
            qos = self._offered_qos(state)
            state.key = self._writer.add_topic(state.name, state.msgtype, qos)
            self.get_logger().info(f'recording {state.name} ({state.msgtype}, offered '
                                   f'{qos_summary(qos)})')
        state.received += 1
        state.gaps.observe(info.get('publication_sequence_number'),
                           state.subscription.get_publisher_count())
        stamp = info.get('received_timestamp') or time.time_ns()
        self._writer.put(state.key, stamp, raw)  # raises if the writer thread has died

    # --- diagnostics and shutdown ---------------------------------------------------------
    def _check_publishers(self) -> None:
        """Warn of best-effort publishers a reliable subscription cannot match."""
        for state in self._topics.values():
            pubs = self.get_publishers_info_by_topic(state.name)
            if state.reliable:
                bad = tuple(sorted(f'{p.node_namespace.rstrip("/")}/{p.node_name}'
                                   for p in pubs if p.qos_profile.reliability
                                   == ReliabilityPolicy.BEST_EFFORT))
                if bad and bad != state.incompatible:
                    self.get_logger().warning(
                        f'{state.name}: best-effort publisher(s) {list(bad)} do not match the '
                        'reliable subscription and are not recorded; restart the recorder '
                        'after they are up (it then subscribes best effort)')
                state.incompatible = bad

    def _publish_diagnostics(self) -> None:
        s = self._writer.stats()
        self._check_publishers()
        gaps = sum(t.gaps.lost for t in self._topics.values())
        unmatched = [f'{t.name} from {", ".join(t.incompatible)}'
                     for t in self._topics.values() if t.incompatible]
        level, text = DiagnosticLevel.OK, f'recording to {self._bag_path}'
        if s.error:
            level, text = DiagnosticLevel.ERROR, f'bag writer stopped: {s.error}'
        elif gaps:
            level = DiagnosticLevel.WARN
            text = f'{gaps} messages lost before the recorder (publisher sequence gaps)'
        elif unmatched:
            level = DiagnosticLevel.WARN
            text = f'best-effort publishers not recorded: {"; ".join(unmatched)}'
        elif self._pending:
            level = DiagnosticLevel.WARN
            text = f'waiting for the type of {self._pending}'
        status = DiagnosticStatus(level=level, name=f'{self.get_name()}: bag writer',
                                  message=text, hardware_id=str(self._bag_path))
        status.values = key_values(
            bag=str(self._bag_path), received=s.received, written=s.written,
            flushed=s.flushed, queued=s.queued, queue_high_water=s.queue_high_water,
            bytes_written=s.bytes_written, chunks_flushed=s.chunks_flushed,
            publisher_sequence_gaps=gaps,
            flush_period_s=self._flush_period_s)
        status.values += key_values(**{f'count {t.name}': t.received
                                       for t in self._topics.values()})
        # publishers each subscription has matched in DDS (the graph can list a reader
        # before the writers match it): a lockstep run starts once every publisher is
        # matched, so the bag holds the run from its first message
        status.values += key_values(**{
            f'matched {t.name}': t.subscription.get_publisher_count()
            for t in self._topics.values() if t.subscription is not None})
        array = DiagnosticArray()
        array.header.stamp = self.get_clock().now().to_msg()
        array.status = [status]
        self._diag_pub.publish(array)

    @property
    def bag_path(self) -> Path:
        """The bag directory being written."""
        return self._bag_path

    def close_bag(self) -> None:
        """Write what is queued and close the bag (metadata.yaml). Idempotent.

        Raises
        ------
        BagWriteError
            The writer failed; the MCAP file is recoverable up to its last flushed chunk.
        """
        s = self._writer.close()
        gaps = sum(t.gaps.lost for t in self._topics.values())
        self.get_logger().info(
            f'closed {self._bag_path}: {s.written} messages, {s.bytes_written / 1e6:.1f} MB, '
            f'queue high water {s.queue_high_water}, {gaps} messages lost before the '
            'recorder (publisher sequence gaps)')


def _parse_cli(argv: list[str]) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        prog=NODE_NAME,
        description='Record the valve suite\'s topics to a rosbag2 bag (MCAP storage); '
        'inspect or recover bags. ROS parameters (--ros-args -p name:=value) work too.')
    parser.add_argument('topics', nargs='*',
                        help='topics to record, "name" or "name:pkg/msg/Type" (default: all '
                        'of the suite\'s topics)')
    parser.add_argument('-o', '--out', dest='output',
                        help='bag directory to create (parameter output); with --recover, '
                        'the recovered bag')
    parser.add_argument('--output', dest='output', help=argparse.SUPPRESS)  # old spelling
    parser.add_argument('--flush-period', type=float, metavar='S',
                        help='flush period [s] (parameter flush_period_s)')
    parser.add_argument('--no-fsync', action='store_true', help='do not fsync after flushes')
    parser.add_argument('--compression', choices=('none', 'zstd'),
                        help='MCAP chunk compression')
    mode = parser.add_mutually_exclusive_group()
    mode.add_argument('--recover', metavar='BAG',
                      help='write a complete bag from a killed recorder\'s BAG (to -o, '
                      'default BAG_recovered) and exit')
    mode.add_argument('--info', metavar='BAG', help='print a summary of BAG and exit')
    return parser.parse_args(argv)


def _offline(ns: argparse.Namespace) -> int:
    """--info / --recover: no ROS needed. Returns the exit code."""
    try:
        if ns.info:
            print(bag_info(ns.info))
        else:
            report = recover_bag(ns.recover, ns.output,
                                 compression=ns.compression or 'none')
            print(report.summary())
    except BagWriteError as err:  # writing the recovered bag failed: a failure inside
        print(f'{NODE_NAME}: {err}', file=sys.stderr)
        return EXIT_FAILURE
    except (RecordingError, OSError) as err:  # no such bag, not a bag: refused input
        print(f'{NODE_NAME}: {err}', file=sys.stderr)
        return EXIT_REFUSED
    return EXIT_OK


def _print_help(argv: list[str]) -> int:
    """--help: the command line, then the node's parameters (from its declarations)."""
    with contextlib.redirect_stdout(io.StringIO()) as text, \
            contextlib.suppress(SystemExit):
        _parse_cli(['--help'])
    usage, _, rest = text.getvalue().partition('\n\n')
    # The parameters are read from a node built as at start-up; its bag would be created
    # on construction, so it goes to a scratch directory that is removed again.
    with tempfile.TemporaryDirectory(prefix='valve_recorder_help_') as scratch:
        def close(node: RecorderNode) -> None:
            with contextlib.suppress(RecordingError, OSError):
                node.close_bag()
        return print_node_help(
            lambda: RecorderNode([Parameter('output_dir', value=scratch)]), NODE_NAME, argv,
            description=rest.strip(), usage=usage, cleanup=close)


def main(args: list[str] | None = None) -> None:
    """Record until Ctrl-C / SIGTERM, or run --info / --recover / --help.

    Exit codes: 0 success (also after SIGINT/SIGTERM), 2 refused input (a bad parameter,
    an existing output directory, no such bag), 1 a failure inside (the writer failed).
    """
    argv = list(sys.argv if args is None else args)
    if help_requested(argv):
        sys.exit(_print_help(argv))
    ns = _parse_cli(remove_ros_args(argv)[1:])
    logging.basicConfig(level=logging.INFO, format='[%(levelname)s] [%(name)s]: %(message)s')
    if ns.info or ns.recover:
        sys.exit(_offline(ns))
    overrides = []
    if ns.output:
        overrides.append(Parameter('output', value=ns.output))
    if ns.topics:
        overrides.append(Parameter('topics', value=list(ns.topics)))
    if ns.flush_period is not None:
        overrides.append(Parameter('flush_period_s', value=float(ns.flush_period)))
    if ns.no_fsync:
        overrides.append(Parameter('fsync', value=False))
    if ns.compression:
        overrides.append(Parameter('compression', value=ns.compression))

    # The recorder handles SIGINT and SIGTERM itself: the handler only sets a flag, the
    # spin loop ends, and the bag is closed while the context is still valid. (rclpy's own
    # handlers shut the context down under a running executor, which can raise from
    # inside spin_once and lose the queued messages.)
    rclpy.init(args=argv, signal_handler_options=SignalHandlerOptions.NO)
    stop = threading.Event()
    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, lambda *_: stop.set())
    node = None
    code = EXIT_OK
    log = rclpy.logging.get_logger(NODE_NAME)
    executor = SingleThreadedExecutor()
    try:
        try:
            node = RecorderNode(overrides)
        except STARTUP_ERRORS + (RecordingError,) as err:
            # A bad parameter, an existing output directory, an unknown type: say which.
            log.fatal(f'cannot record: {err}')
            code = EXIT_REFUSED
        if node is not None:
            executor.add_node(node)
            while not stop.is_set() and rclpy.ok():
                executor.spin_once(timeout_sec=0.1)
                if node.batch_period_s:
                    stop.wait(node.batch_period_s)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except (ValueError, RecordingError, OSError) as err:
        # A dead writer while recording: say which and fail.
        log.fatal(f'cannot record: {err}')
        code = EXIT_FAILURE
    finally:
        if node is not None:
            try:
                node.close_bag()
            except BagWriteError as err:
                log.fatal(f'{err}; recover what was flushed with '
                          f'`{NODE_NAME} --recover {node.bag_path}`')
                code = EXIT_FAILURE
            executor.remove_node(node)
            node.destroy_node()
        executor.shutdown()
        rclpy.try_shutdown()
    if code:
        sys.exit(code)


if __name__ == '__main__':
    main()
