"""Reading *any* rosbag2 bag, not only the twin's: MCAP (chunks uncompressed, zstd or lz4) and
sqlite3 (``.db3``) storage, split bags, ``metadata.yaml`` versions 4 to 9, a bag directory or a
bare storage file -- as raw messages (topic, log time, exact CDR bytes) in log-time order.

The storage files are read directly with ``mcap`` and ``sqlite3``: ``rosbags`` 0.11.9 opens an
older bag (metadata v4, integer QoS policies) and then yields no messages from it, so a reader
that trusts a library coming back empty loses whole bags without a word. A storage file that
holds no message while its metadata counts some is an error here, never an empty playback.

QoS: version 9 stores policies by name, versions 4-8 as integers (``history: 3``); both become
the v9 names (:func:`normalise_qos`).
"""

from __future__ import annotations

import dataclasses
import heapq
import inspect
import sqlite3
from pathlib import Path
from typing import Any, Iterable, Iterator

import yaml

from ..errors import BagError
from .reader import _mcap_errors, check_data_crc

# rmw's enums, as rosbag2 versions <= 8 wrote them (rmw/types.h)
_HISTORY = {0: 'system_default', 1: 'keep_last', 2: 'keep_all', 3: 'unknown'}
_RELIABILITY = {0: 'system_default', 1: 'reliable', 2: 'best_effort', 3: 'unknown',
                4: 'best_available'}
_DURABILITY = {0: 'system_default', 1: 'transient_local', 2: 'volatile', 3: 'unknown',
               4: 'best_available'}
_LIVELINESS = {0: 'system_default', 1: 'automatic', 2: 'manual_by_node', 3: 'manual_by_topic',
               4: 'unknown', 5: 'best_available'}
_POLICIES = {'history': _HISTORY, 'reliability': _RELIABILITY, 'durability': _DURABILITY,
             'liveliness': _LIVELINESS}


def normalise_qos(raw: Any) -> list[dict[str, Any]]:
    """Offered QoS profiles as v9 stores them (a list of maps with policy names), from a v9
    list, a v4-8 YAML string, integer or name policies; [] when absent or unreadable."""
    if isinstance(raw, str):
        try:
            raw = yaml.safe_load(raw) if raw.strip() else []
        except yaml.YAMLError:
            return []
    if not isinstance(raw, list):
        return []
    out = []
    for prof in raw:
        if not isinstance(prof, dict):
            continue
        prof = dict(prof)
        for key, names in _POLICIES.items():
            v = prof.get(key)
            if isinstance(v, int) and not isinstance(v, bool):
                prof[key] = names.get(v, 'unknown')
            elif isinstance(v, str):
                prof[key] = v.lower()
        out.append(prof)
    return out


@dataclasses.dataclass
class TopicInfo:
    name: str
    type: str
    qos: list[dict[str, Any]]
    count: int = 0
    serialization_format: str = 'cdr'


@dataclasses.dataclass
class AnyBag:
    """A rosbag2 bag opened for reading raw messages."""

    path: Path
    storage: str                          # 'mcap' or 'sqlite3'
    files: list[Path]
    topics: dict[str, TopicInfo]
    version: int | None                   # metadata.yaml version, None without one
    start_ns: int
    end_ns: int
    message_count: int

    @property
    def duration_ns(self) -> int:
        return self.end_ns - self.start_ns

    def messages(self, topics: Iterable[str] | None = None, start_ns: int | None = None,
                 end_ns: int | None = None) -> Iterator[tuple[str, int, bytes]]:
        """(topic, log time [ns], CDR bytes) in log-time order over every file; ``topics``
        keeps only those, ``start_ns``/``end_ns`` bound the log time (inclusive)."""
        keep = None if topics is None else set(topics)
        streams = [_file_messages(f, self.storage, keep, start_ns, end_ns) for f in self.files]
        # files are time-ordered splits, but merging costs nothing and survives overlaps;
        # the file index breaks ties so that equal times keep file order
        tagged = ([(t, i, n, topic, data) for n, (topic, t, data) in enumerate(s)]
                  for i, s in enumerate(streams))
        for t, _, _, topic, data in heapq.merge(*tagged):
            yield topic, t, data


def open_any_bag(path: str | Path) -> AnyBag:
    """Open a rosbag2 bag directory (``metadata.yaml`` and its storage files) or a bare
    ``.mcap``/``.db3`` file; every failure is one :class:`BagError` line."""
    p = Path(path)
    if p.is_file():
        storage = _storage_of(p)
        files, meta = [p], None
    elif p.is_dir():
        meta = _read_metadata(p)
        if meta is not None:
            storage = str(meta.get('storage_identifier') or '')
            rel = meta.get('relative_file_paths') or []
            files = [p / Path(f).name if not (p / f).exists() else p / f for f in rel]
            if not storage and files:
                storage = _storage_of(files[0])
            if storage not in ('mcap', 'sqlite3'):
                raise BagError(f'bag {str(p)!r}: storage {storage!r} is not supported; '
                               'expected mcap or sqlite3')
            missing = [str(f) for f in files if not f.is_file()]
            if missing or not files:
                raise BagError(f'bag {str(p)!r}: metadata.yaml lists storage files that are '
                               f'missing: {missing or "none listed"}')
        else:
            files = sorted(p.glob('*.mcap')) or sorted(p.glob('*.db3'))
            if not files:
                raise BagError(f'no bag at {str(p)!r}: no metadata.yaml, .mcap or .db3 file')
            storage = _storage_of(files[0])
    else:
        raise BagError(f'no bag at {str(p)!r}: not a directory, .mcap or .db3 file')
    topics: dict[str, TopicInfo] = {}
    start, end, count = None, None, 0
    for f in files:
        for info, (t0, t1, n) in [_file_summary(f, storage)]:
            for name, ti in info.items():
                have = topics.setdefault(name, TopicInfo(name, ti.type, ti.qos))
                have.count += ti.count
                if not have.qos and ti.qos:
                    have.qos = ti.qos
            if n:
                start = t0 if start is None else min(start, t0)
                end = t1 if end is None else max(end, t1)
                count += n
    if meta is not None:
        for entry in meta.get('topics_with_message_count') or []:
            tm = (entry or {}).get('topic_metadata') or {}
            name = tm.get('name')
            if name in topics and tm.get('offered_qos_profiles') is not None:
                qos = normalise_qos(tm['offered_qos_profiles'])
                if qos:
                    topics[name].qos = qos
        expected = meta.get('message_count')
        if isinstance(expected, int) and expected > 0 and count == 0:
            raise BagError(f'bag {str(p)!r}: metadata.yaml counts {expected} messages but its '
                           'storage files hold none (truncated or corrupt)')
    if count == 0:
        raise BagError(f'bag {str(p)!r} holds no messages')
    version = int(meta['version']) if meta and isinstance(meta.get('version'), int) else None
    return AnyBag(path=p, storage=storage, files=files, topics=topics, version=version,
                  start_ns=int(start), end_ns=int(end), message_count=count)


def _storage_of(f: Path) -> str:
    if f.suffix == '.mcap':
        return 'mcap'
    if f.suffix == '.db3':
        return 'sqlite3'
    with open(f, 'rb') as fh:
        head = fh.read(16)
    if head.startswith(b'\x89MCAP'):
        return 'mcap'
    if head.startswith(b'SQLite format 3'):
        return 'sqlite3'
    if head.startswith(b'#ROSBAG'):
        raise BagError(f'{str(f)!r} is a ROS 1 bag, not a rosbag2 bag')
    raise BagError(f'{str(f)!r} is not a rosbag2 storage file (.mcap or .db3)')


def _read_metadata(d: Path) -> dict[str, Any] | None:
    f = d / 'metadata.yaml'
    if not f.is_file():
        return None
    try:
        raw = yaml.safe_load(f.read_text(encoding='utf-8'))
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as exc:
        raise BagError(f'{str(f)!r} is not readable YAML ({type(exc).__name__})') from None
    info = raw.get('rosbag2_bagfile_information') if isinstance(raw, dict) else None
    if not isinstance(info, dict):
        raise BagError(f'{str(f)!r} has no rosbag2_bagfile_information: not a rosbag2 bag')
    return info


def _file_summary(f: Path, storage: str) -> tuple[dict[str, TopicInfo], tuple[int, int, int]]:
    """Topics of one storage file with their message counts, and (first, last, count): from
    an MCAP file's summary statistics when it has them, else by reading its messages once."""
    if storage == 'mcap':
        fast = _mcap_statistics(f)
        if fast is not None:
            return fast
    topics: dict[str, TopicInfo] = {}
    t0 = t1 = None
    n = 0
    for topic, t, _ in _file_messages(f, storage, None, None, None, topics):
        topics[topic].count += 1
        t0 = t if t0 is None else min(t0, t)
        t1 = t if t1 is None else max(t1, t)
        n += 1
    return topics, (t0 or 0, t1 or 0, n)


def _topic_info(channel, schema) -> TopicInfo:
    """A topic as an MCAP channel (and its schema) describes it; the count is added later."""
    return TopicInfo(channel.topic, schema.name if schema else '',
                     normalise_qos(channel.metadata.get('offered_qos_profiles', '')),
                     serialization_format=channel.message_encoding)


def _mcap_statistics(f: Path):
    """The MCAP summary's channels and statistics, CRCs checked; None without a summary."""
    from mcap.reader import make_reader
    try:
        check_data_crc(f)
        with open(f, 'rb') as fh:
            summary = make_reader(fh, validate_crcs=True).get_summary()
    except OSError as exc:
        raise BagError(f'cannot read {str(f)!r}: {exc.strerror}') from None
    except _mcap_errors():
        return None                          # no usable summary: read the messages instead
    if summary is None or summary.statistics is None:
        return None
    st = summary.statistics
    topics = {}
    for cid, ch in summary.channels.items():
        info = topics.setdefault(ch.topic, _topic_info(ch, summary.schemas.get(ch.schema_id)))
        info.count += st.channel_message_counts.get(cid, 0)
    n = st.message_count
    return topics, (st.message_start_time if n else 0, st.message_end_time if n else 0, n)


def _file_messages(f: Path, storage: str, keep, start_ns, end_ns,
                   topics_out: dict[str, TopicInfo] | None = None
                   ) -> Iterator[tuple[str, int, bytes]]:
    if storage == 'mcap':
        yield from _mcap_messages(f, keep, start_ns, end_ns, topics_out)
    else:
        yield from _sqlite_messages(f, keep, start_ns, end_ns, topics_out)


def _mcap_messages(f, keep, start_ns, end_ns, topics_out):
    from mcap.reader import make_reader
    try:
        if topics_out is not None:              # the summary scan, when the bag is opened
            check_data_crc(f)
        with open(f, 'rb') as fh:
            reader = make_reader(fh, validate_crcs=True)
            # mcap 1.6 names the bounds starting_at / ending_at (inclusive) and deprecates
            # start_time / end_time (end exclusive), which older releases alone have
            if 'starting_at' in inspect.signature(reader.iter_messages).parameters:
                span = dict(starting_at=start_ns, ending_at=end_ns)
            else:
                span = dict(start_time=start_ns,
                            end_time=None if end_ns is None else end_ns + 1)
            for schema, ch, msg in reader.iter_messages(
                    topics=None if keep is None else sorted(keep), log_time_order=True,
                    **span):
                if topics_out is not None and ch.topic not in topics_out:
                    topics_out[ch.topic] = _topic_info(ch, schema)
                yield ch.topic, msg.log_time, bytes(msg.data)
    except OSError as exc:
        raise BagError(f'cannot read {str(f)!r}: {exc.strerror}') from None
    except _mcap_errors() as exc:
        raise BagError(f'{str(f)!r} is truncated or corrupt ({type(exc).__name__}: '
                       f'{str(exc)[:120]}); try: servovalve-twin reindex') from None


def _sqlite_messages(f, keep, start_ns, end_ns, topics_out):
    try:
        con = sqlite3.connect(f'file:{f}?mode=ro', uri=True)
    except sqlite3.Error as exc:
        raise BagError(f'cannot open {str(f)!r} as sqlite3: {exc}') from None
    try:
        cols = {r[1] for r in con.execute('PRAGMA table_info(topics)')}
        if not {'id', 'name', 'type'} <= cols:
            raise BagError(f'{str(f)!r} is not a rosbag2 sqlite3 file (no topics table)')
        qcol = 'offered_qos_profiles' if 'offered_qos_profiles' in cols else "''"
        fcol = 'serialization_format' if 'serialization_format' in cols else "'cdr'"
        names = {}
        for tid, name, typ, fmt, qos in con.execute(
                f'SELECT id, name, type, {fcol}, {qcol} FROM topics'):
            names[tid] = name
            if topics_out is not None:
                topics_out.setdefault(name, TopicInfo(name, typ, normalise_qos(qos),
                                                      serialization_format=fmt))
        where, args = [], []
        if keep is not None:
            ids = [i for i, n in names.items() if n in keep]
            where.append(f'topic_id IN ({",".join("?" * len(ids)) or "NULL"})')
            args += ids
        if start_ns is not None:
            where.append('timestamp >= ?')
            args.append(int(start_ns))
        if end_ns is not None:
            where.append('timestamp <= ?')
            args.append(int(end_ns))
        sql = ('SELECT topic_id, timestamp, data FROM messages'
               + (' WHERE ' + ' AND '.join(where) if where else '') + ' ORDER BY timestamp, id')
        for tid, t, data in con.execute(sql, args):
            yield names[tid], int(t), bytes(data)
    except sqlite3.DatabaseError as exc:
        raise BagError(f'{str(f)!r} is not a readable rosbag2 sqlite3 file ({exc})') from None
    finally:
        con.close()


__all__ = ['AnyBag', 'TopicInfo', 'open_any_bag', 'normalise_qos']
