"""Recording the suite's topics to rosbag2 bags (MCAP storage) and reading any bag back.

ROS-free: this package uses rosbags, numpy and the standard library only; the
``valve_recorder`` node (:mod:`valve_model_pkg.nodes.recorder_node`) feeds it the raw CDR
bytes of its subscriptions. It is the one place that opens bags: identification, maps,
reports and the bench loop read through :func:`load_bag` and :func:`read_fields`.

- :mod:`.typestore`: message definitions (ROS 2 Jazzy types + ``valve_msgs`` ``.msg``, and
  a bag's own embedded definitions).
- :mod:`.writer`: :class:`BagWriter` (flush policy) and :class:`QueuedBagWriter` (thread).
- :mod:`.recovery`: :class:`McapScanner` and :func:`recover_bag` for killed recorders.
- :mod:`.reader`: :func:`load_bag` into numpy arrays (:mod:`.arrays`), :func:`bag_info`;
  :mod:`.reindex` reads bags without ``metadata.yaml``.
- :mod:`.fields`: :func:`read_fields`, chosen fields of a user's topics
  (``/coil/current``, ``/valve/state.coil_current``) as time series.
- :mod:`.topics`: the suite's topics and types; :mod:`.qos`: QoS profiles for metadata.
"""
from __future__ import annotations

from ..errors import BagFormatError, BagWriteError, RecordingError, UnknownMessageTypeError
from .arrays import PublisherSequenceGaps, TopicData, sequence_gaps
from .fields import FieldRecord, FieldSeries, FieldSpec, read_fields
from .qos import make_qos, qos_summary, reliable_qos
from .reader import BagContents, bag_info, is_complete_bag, load_bag, load_bag_contents
from .recovery import McapScanner, RecoveryReport, ScanReport, recover_bag
from .reindex import BagIndex, reindex_bag
from .topics import DEFAULT_TOPICS, SUITE_TOPICS, parse_topic_spec
from .typestore import (TypeDefinition, build_typestore, ensure_type, msgdef_and_hash,
                        typestore_for_bag)
from .writer import BAG_VERSION, BagWriter, QueuedBagWriter, WriterStats, absolute_topic

__all__ = [
    'BAG_VERSION', 'BagContents', 'BagFormatError', 'BagIndex', 'BagWriteError', 'BagWriter',
    'DEFAULT_TOPICS', 'FieldRecord', 'FieldSeries', 'FieldSpec', 'McapScanner',
    'PublisherSequenceGaps', 'QueuedBagWriter', 'RecordingError', 'RecoveryReport',
    'SUITE_TOPICS', 'ScanReport',
    'TopicData', 'TypeDefinition', 'UnknownMessageTypeError', 'WriterStats', 'absolute_topic',
    'bag_info', 'build_typestore', 'ensure_type', 'is_complete_bag', 'load_bag',
    'load_bag_contents', 'make_qos', 'msgdef_and_hash', 'parse_topic_spec', 'qos_summary',
    'read_fields', 'recover_bag', 'reindex_bag', 'reliable_qos', 'sequence_gaps',
    'typestore_for_bag',
]
