"""Small bags for unit tests: one writer loop and one header builder for the tests that
build a suite bag message by message (the suite's BagWriter), and :func:`write_rosbag2`
for bags laid out as ``ros2 bag record`` writes them in every storage, split, compression
and metadata version (rosbags' writer)."""
from __future__ import annotations

from pathlib import Path
from typing import Iterable


class FakeClock:
    """A monotonic clock for a BagWriter that the test sets (``clock.t = ...``) [s]."""

    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


def header(types: dict, ns: int, frame: str = '') -> object:
    """A std_msgs/Header stamped ``ns`` [ns]."""
    return types['std_msgs/msg/Header'](
        stamp=types['builtin_interfaces/msg/Time'](sec=ns // 10**9, nanosec=ns % 10**9),
        frame_id=frame)


def write_bag(path: Path, store: object,
              messages: Iterable[tuple[str, str, int, object]]) -> None:
    """Write ``messages`` = (topic, message type, log time [ns], message) in the order given,
    one connection per topic (reliable, keep last 1000, as the recorder offers them)."""
    from valve_model_pkg.recording import BagWriter, reliable_qos
    with BagWriter(path, store) as w:
        conns = {}
        for topic, msgtype, log_ns, msg in messages:
            if topic not in conns:
                conns[topic] = w.add_topic(topic, msgtype, [reliable_qos(1000)])
            w.write(conns[topic], log_ns, bytes(store.serialize_cdr(msg, msgtype)))


#: Bus time of a bench bag's first state [ns] (:func:`write_bench_state_bag`).
BENCH_T0_NS = 1_795_820_000 * 10**9


def write_bench_state_bag(path: Path, t_s, voltage_v, current_a, voltage_mean_v=None,
                          sequence=None) -> Path:
    """A bench step's ``valve/state`` as the CAN driver publishes it in bench mode: duty 1
    while the unchopped coil voltage is on, 50 Hz, the current's mean = its sample. Times
    [s] from :data:`BENCH_T0_NS`; ``voltage_mean_v`` defaults to the voltage, ``sequence``
    to 0, 1, 2, ..."""
    from valve_model_pkg.recording import build_typestore
    store = build_typestore()
    ty = store.types
    v_mean = voltage_v if voltage_mean_v is None else voltage_mean_v
    seq = range(len(t_s)) if sequence is None else sequence
    msgs = []
    for tj, vj, ij, mj, sj in zip(t_s, voltage_v, current_a, v_mean, seq):
        ns = BENCH_T0_NS + int(round(tj * 1e9))
        msgs.append(('valve/state', 'valve_msgs/msg/ValveState', ns,
                     ty['valve_msgs/msg/ValveState'](
                         header=header(ty, ns, 'valve'), sequence=int(sj),
                         coil_voltage=float(vj), coil_current=float(ij),
                         coil_current_mean=float(ij), coil_voltage_mean=float(mj),
                         spool_position=0.0, spool_velocity=0.0, spool_position_avg=0.0,
                         mass_flow=0.0, duty=1.0 if vj > 0.0 else 0.0, pwm_frequency=50.0,
                         supply_pressure=4e5, output_pressure=0.0, source=2,
                         position_measured=False)))
    write_bag(path, store, msgs)
    return path


#: rosbag2 storage-file layouts :func:`write_rosbag2` writes.
COMPRESSIONS = ('none', 'file', 'message', 'chunk')


def _write_part(path: Path, store: object, topics: dict[str, str],
                messages: list[tuple[str, str, int, object]], storage: str,
                compression: str, version: int) -> None:
    from rosbags.rosbag2 import CompressionFormat, CompressionMode, StoragePlugin, Writer

    from valve_model_pkg.recording import reliable_qos
    plugin = StoragePlugin.MCAP if storage == 'mcap' else StoragePlugin.SQLITE3
    w = Writer(path, version=max(version, 8), storage_plugin=plugin)
    mode = {'none': CompressionMode.NONE, 'file': CompressionMode.FILE,
            'message': CompressionMode.MESSAGE, 'chunk': CompressionMode.STORAGE}[compression]
    w.set_compression(mode, CompressionFormat.ZSTD)
    with w:
        conns = {topic: w.add_connection(topic, msgtype, typestore=store,
                                         offered_qos_profiles=[reliable_qos(100)])
                 for topic, msgtype in topics.items()}
        for topic, msgtype, log_ns, msg in messages:
            w.write(conns[topic], log_ns, bytes(store.serialize_cdr(msg, msgtype)))


def _as_older_version(info: dict, version: int) -> dict:
    """``metadata.yaml`` content as ros2 wrote version ``version`` (4..7) of it: keys added
    later dropped (v5 files, v6 custom_data, v7 type_description_hash, v8 ros_distro), the
    QoS profiles a YAML string (before v9)."""
    info = dict(info, version=version)
    info.pop('ros_distro', None)
    if version < 7:
        for t in info['topics_with_message_count']:
            t['topic_metadata'].pop('type_description_hash', None)
    if version < 6:
        info.pop('custom_data', None)
    if version < 5:
        info.pop('files', None)
    return info


def write_rosbag2(path: Path, store: object, messages: Iterable[tuple[str, str, int, object]],
                  *, storage: str = 'mcap', split: int = 1, compression: str = 'none',
                  version: int = 9, metadata: bool = True) -> Path:
    """Write ``messages`` = (topic, type, log time [ns], message) as ``ros2 bag record``
    lays a bag out, with rosbags' writer.

    Parameters
    ----------
    storage : {'mcap', 'sqlite3'}
    split : int
        Number of storage files ``<name>_<i>.<ext>`` the messages are split into, in order
        (each file registers every topic, as rosbag2's splitting does).
    compression : {'none', 'file', 'message', 'chunk'}
        zstd compression of whole files (``.zstd``), of each message, or of MCAP chunks.
    version : int
        ``metadata.yaml`` version, 4..9 (below 8 the keys of later versions are removed
        as ros2 wrote them).
    metadata : bool
        False deletes ``metadata.yaml`` (a bag to reindex).
    """
    import shutil
    import tempfile

    import yaml
    messages = list(messages)
    topics = {topic: msgtype for topic, msgtype, _, _ in messages}
    bounds = [round(k * len(messages) / split) for k in range(split + 1)]
    path.mkdir(parents=True)
    infos = []
    with tempfile.TemporaryDirectory(dir=path.parent) as tmp:
        for k in range(split):
            part = Path(tmp) / f'{path.name}_{k}'
            _write_part(part, store, topics, messages[bounds[k]:bounds[k + 1]], storage,
                        compression, version)
            info = yaml.safe_load((part / 'metadata.yaml').read_text())
            info = info['rosbag2_bagfile_information']
            (name,) = info['relative_file_paths']
            shutil.move(part / name, path / name)
            infos.append(info)
    info = infos[0]
    info['relative_file_paths'] = [i['relative_file_paths'][0] for i in infos]
    info['files'] = [f for i in infos for f in i['files']]
    info['message_count'] = sum(i['message_count'] for i in infos)
    start = min(i['starting_time']['nanoseconds_since_epoch'] for i in infos)
    end = max(i['starting_time']['nanoseconds_since_epoch'] + i['duration']['nanoseconds']
              for i in infos)
    info['starting_time'] = {'nanoseconds_since_epoch': start}
    info['duration'] = {'nanoseconds': end - start}
    for t in info['topics_with_message_count']:
        name = t['topic_metadata']['name']
        t['message_count'] = sum(u['message_count'] for i in infos
                                 for u in i['topics_with_message_count']
                                 if u['topic_metadata']['name'] == name)
    if version < 8:
        info = _as_older_version(info, version)
    if metadata:
        (path / 'metadata.yaml').write_text(
            yaml.safe_dump({'rosbag2_bagfile_information': info}, sort_keys=False))
    return path
