"""Recording the suite's topics to rosbag2 bags (MCAP storage) and reading them back.

ROS-free: this package uses rosbags, numpy and the standard library only; the
``valve_recorder`` node (:mod:`valve_model_pkg.nodes.recorder_node`) feeds it the raw CDR
bytes of its subscriptions.

- :mod:`.typestore`: message definitions (ROS 2 Jazzy types + ``valve_msgs`` ``.msg``).
- :mod:`.writer`: :class:`BagWriter` (flush policy) and :class:`QueuedBagWriter` (thread).
- :mod:`.recovery`: :class:`McapScanner` and :func:`recover_bag` for killed recorders.
- :mod:`.reader`: :func:`load_bag` into numpy arrays, :func:`bag_info`.
- :mod:`.topics`: the suite's topics and types; :mod:`.qos`: QoS profiles for metadata.
"""
from __future__ import annotations

from ..errors import BagFormatError, BagWriteError, RecordingError, UnknownMessageTypeError
from .qos import make_qos, qos_summary, reliable_qos
from .reader import TopicData, bag_info, is_complete_bag, load_bag, sequence_gaps
from .recovery import McapScanner, RecoveryReport, ScanReport, recover_bag
from .topics import DEFAULT_TOPICS, SUITE_TOPICS, parse_topic_spec
from .typestore import build_typestore, ensure_type, msgdef_and_hash
from .writer import BAG_VERSION, BagWriter, QueuedBagWriter, WriterStats, absolute_topic

__all__ = [
    'BAG_VERSION', 'BagFormatError', 'BagWriteError', 'BagWriter', 'DEFAULT_TOPICS',
    'McapScanner', 'QueuedBagWriter', 'RecordingError', 'RecoveryReport', 'SUITE_TOPICS',
    'ScanReport', 'TopicData', 'UnknownMessageTypeError', 'WriterStats', 'absolute_topic',
    'bag_info', 'build_typestore', 'ensure_type', 'is_complete_bag', 'load_bag', 'make_qos',
    'msgdef_and_hash', 'parse_topic_spec', 'qos_summary', 'recover_bag', 'reliable_qos',
    'sequence_gaps',
]
