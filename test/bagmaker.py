"""Small rosbag2 bags in the layouts real rosbag2 writes, built here from scratch so the tests
need no rosbag2: MCAP (uncompressed, zstd, lz4) and sqlite3, metadata.yaml version 9 (QoS by
name, as a YAML list) and version 4 (QoS as a YAML string of integers), one file or split in
two. Their messages are known exactly, so a reader or player can be checked message by
message."""

from __future__ import annotations

import sqlite3
import struct
from pathlib import Path

import yaml

from servovalve_twin.bag.writer import message_definition

F64 = 'std_msgs/msg/Float64'
CLOCK = 'rosgraph_msgs/msg/Clock'
CUSTOM = 'demo_msgs/msg/Reading'          # a type that is not installed: skipped with a warning

QOS_V9 = [dict(history='unknown', depth=0, reliability='reliable', durability='volatile',
               deadline={'sec': 9223372036, 'nsec': 854775807},
               lifespan={'sec': 9223372036, 'nsec': 854775807}, liveliness='automatic',
               liveliness_lease_duration={'sec': 9223372036, 'nsec': 854775807},
               avoid_ros_namespace_conventions=False)]
# what rosbag2 <= Humble wrote: a YAML *string*, integer policies (reliability 2 = best effort)
QOS_V4_BEST_EFFORT = ('- history: 3\n  depth: 0\n  reliability: 2\n  durability: 2\n'
                      '  deadline:\n    sec: 2147483647\n    nsec: 4294967295\n'
                      '  lifespan:\n    sec: 2147483647\n    nsec: 4294967295\n'
                      '  liveliness: 1\n  liveliness_lease_duration:\n    sec: 2147483647\n'
                      '    nsec: 4294967295\n  avoid_ros_namespace_conventions: false\n')


def f64(v: float) -> bytes:
    return b'\x00\x01\x00\x00' + struct.pack('<d', v)


def clock(t_ns: int) -> bytes:
    return b'\x00\x01\x00\x00' + struct.pack('<iI', *divmod(t_ns, 1_000_000_000))


def messages(n: int = 60, t0_ns: int = 1_000_000_000, dt_ns: int = 10_000_000):
    """(topic, type, log time, bytes): /value (Float64, reliable), /fast (Float64, best
    effort in v4 bags), /clock (Clock, the bag's own), /custom (uninstalled type)."""
    out = []
    for i in range(n):
        t = t0_ns + i * dt_ns
        out.append(('/value', F64, t, f64(0.5 * i)))
        out.append(('/fast', F64, t + dt_ns // 2, f64(-float(i))))
        if i % 5 == 0:
            out.append(('/clock', CLOCK, t, clock(t)))
            out.append(('/custom', CUSTOM, t, b'\x00\x01\x00\x00' + struct.pack('<i', i)))
    return sorted(out, key=lambda m: m[2])


def reference_messages(end_ns: int) -> tuple[list, dict[str, str]]:
    """The packaged HD reference bag's messages up to ``end_ns`` (as :func:`write_bag` takes
    them) and its provenance record, read with the mcap library alone."""
    from mcap.reader import make_reader
    from servovalve_twin.config import reference_dir
    msgs, record = [], {}
    with open(next((reference_dir() / 'paper_HD').glob('*.mcap')), 'rb') as fh:
        reader = make_reader(fh)
        for schema, ch, m in reader.iter_messages(log_time_order=True):
            if m.log_time <= end_ns:
                msgs.append((ch.topic, schema.name, m.log_time, bytes(m.data)))
        for meta in reader.iter_metadata():
            if meta.name == 'servovalve_twin':
                record = dict(meta.metadata)
    return msgs, record


def _qos(topic: str, version: int):
    if version >= 9:
        return QOS_V9
    return QOS_V4_BEST_EFFORT if topic == '/fast' else QOS_V4_BEST_EFFORT.replace(
        'reliability: 2', 'reliability: 1')


def write_bag(directory: Path, *, storage: str = 'mcap', version: int = 9, split: int = 1,
              compression: str = 'none', msgs=None, provenance=None) -> list:
    """Write a bag directory; returns the messages written (in log-time order).
    ``provenance``: the twin's record, as an MCAP metadata record in the first file, or for
    sqlite3 (no metadata records) in metadata.yaml's custom_data (versions >= 6)."""
    directory.mkdir(parents=True)
    msgs = msgs if msgs is not None else messages()
    types = {}
    for topic, typ, _, _ in msgs:
        types[topic] = typ
    parts = [msgs[i * len(msgs) // split:(i + 1) * len(msgs) // split] for i in range(split)]
    ext = '.mcap' if storage == 'mcap' else '.db3'
    files = []
    for i, part in enumerate(parts):
        f = directory / f'{directory.name}_{i}{ext}'
        files.append(f.name)
        record = provenance if i == 0 and storage == 'mcap' else None
        if storage == 'mcap':
            _write_mcap(f, part, types, version, compression, record)
        else:
            _write_sqlite(f, part, types, version, compression)
    counts = {t: sum(1 for m in msgs if m[0] == t) for t in types}
    info = dict(version=version, storage_identifier=storage,
                duration={'nanoseconds': msgs[-1][2] - msgs[0][2]},
                starting_time={'nanoseconds_since_epoch': msgs[0][2]},
                message_count=len(msgs),
                topics_with_message_count=[dict(topic_metadata=dict(
                    name=t, type=types[t], serialization_format='cdr',
                    offered_qos_profiles=_qos(t, version)), message_count=counts[t])
                    for t in types],
                compression_format='', compression_mode='', relative_file_paths=files)
    if provenance and storage != 'mcap':
        assert version >= 6, 'custom_data exists from metadata version 6'
        info['custom_data'] = {f'servovalve_twin.{k}': v for k, v in provenance.items()}
    (directory / 'metadata.yaml').write_text(yaml.safe_dump(
        {'rosbag2_bagfile_information': info}, sort_keys=False))
    return msgs


def _write_mcap(f: Path, part, types, version, compression, provenance=None):
    from mcap.writer import CompressionType, Writer
    comp = {'none': CompressionType.NONE, 'zstd': CompressionType.ZSTD,
            'lz4': CompressionType.LZ4}[compression]
    with open(f, 'wb') as fh:
        w = Writer(fh, compression=comp, chunk_size=512)
        w.start(profile='ros2', library='bagmaker')
        channels = {}
        for topic, typ in types.items():
            try:
                text = message_definition(typ).encode()
            except Exception:  # noqa: BLE001 -- the uninstalled type: a made-up definition
                text = b'int32 value\n'
            sid = w.register_schema(name=typ, encoding='ros2msg', data=text)
            qos = _qos(topic, version)
            channels[topic] = w.register_channel(
                topic=topic, message_encoding='cdr', schema_id=sid,
                metadata={'offered_qos_profiles': qos if isinstance(qos, str)
                          else yaml.safe_dump(qos, sort_keys=False), 'topic_type_hash': ''})
        for topic, _, t, data in part:
            w.add_message(channels[topic], log_time=t, data=data, publish_time=t)
        if provenance:
            w.add_metadata('servovalve_twin', dict(provenance))
        w.finish()


def _write_sqlite(f: Path, part, types, version, compression):
    con = sqlite3.connect(f)
    qos_col = ', offered_qos_profiles TEXT NOT NULL' if version >= 4 else ''
    con.execute('CREATE TABLE topics(id INTEGER PRIMARY KEY, name TEXT NOT NULL, type TEXT NOT '
                f'NULL, serialization_format TEXT NOT NULL{qos_col})')
    con.execute('CREATE TABLE messages(id INTEGER PRIMARY KEY, topic_id INTEGER NOT NULL, '
                'timestamp INTEGER NOT NULL, data BLOB NOT NULL)')
    ids = {}
    # topic ids in reverse name order: a reader must map ids by name, file by file
    for i, topic in enumerate(sorted(types, reverse=True)):
        ids[topic] = i + 1
        qos = _qos(topic, version)
        con.execute('INSERT INTO topics VALUES (?, ?, ?, ?, ?)',
                    (ids[topic], topic, types[topic], 'cdr',
                     qos if isinstance(qos, str) else yaml.safe_dump(qos, sort_keys=False)))
    con.executemany('INSERT INTO messages(topic_id, timestamp, data) VALUES (?, ?, ?)',
                    [(ids[topic], t, data) for topic, _, t, data in part])
    con.commit()
    con.close()


def write_long_bag(path: Path, seconds: int) -> Path:
    """The packaged 1 s run repeated ``seconds`` times end to end, with its provenance (512-byte
    chunks, as :func:`write_bag` writes them: many chunk indexes)."""
    msgs, record = reference_messages(1_000_000_000)
    period = 1_001_000_000                      # the 1 s run has ticks 0..1000 ms
    out = [(t, typ, ns + k * period, d) for k in range(seconds) for t, typ, ns, d in msgs]
    write_bag(path, msgs=out, provenance=record)
    return path
