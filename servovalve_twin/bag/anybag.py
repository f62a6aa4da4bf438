"""The one bag reader: *any* rosbag2 bag, not only the twin's -- every storage of
:data:`~.storages.STORAGES` (MCAP with chunks uncompressed, zstd or lz4; sqlite3), split bags,
``metadata.yaml`` versions 4 to 9, a bag directory or a bare storage file -- as raw messages
(topic, log time, exact CDR bytes) in log-time order, with the bag's validated provenance
record. Every command that takes a bag opens it here (:func:`open_any_bag`); the 1 ms signal
table of the twin's topics is :func:`~.reader.read_bag`, a thin builder on it.

The storage files are read directly with ``mcap`` and ``sqlite3``: ``rosbags`` 0.11.9 opens an
older bag (metadata v4, integer QoS policies) and then yields no messages from it, so a reader
that trusts a library coming back empty loses whole bags without a word. A storage file that
holds no message while its metadata counts some is an error here, never an empty playback.

QoS: version 9 stores policies by name, versions 4-8 as integers (``history: 3``); both become
the v9 names (:func:`~.storages.normalise_qos`).
"""

from __future__ import annotations

import dataclasses
import heapq
from pathlib import Path
from typing import Any, Iterable, Iterator

import yaml

from ..errors import BagError
from . import safe_load
from .provenance import PROVENANCE, Provenance, from_custom_data
from .storages import STORAGES, Storage, TopicInfo, normalise_qos, storage_of


@dataclasses.dataclass
class AnyBag:
    """A rosbag2 bag opened for reading raw messages."""

    path: Path
    storage: str                          # a key of STORAGES: 'mcap' or 'sqlite3'
    files: list[Path]
    topics: dict[str, TopicInfo]
    version: int | None                   # metadata.yaml version, None without one
    start_ns: int
    end_ns: int
    message_count: int
    custom_data: dict[str, Any] = dataclasses.field(default_factory=dict)
    _provenance: Provenance | None = dataclasses.field(default=None, repr=False)

    @property
    def duration_ns(self) -> int:
        return self.end_ns - self.start_ns

    @property
    def reader(self) -> Storage:
        return STORAGES[self.storage]

    @property
    def provenance(self) -> Provenance:
        """The twin's provenance record (falsy for a bag without one), validated, read once:
        the first storage file's metadata record, else ``metadata.yaml``'s ``custom_data``."""
        if self._provenance is None:
            record: dict[str, str] = {}
            for f in self.files:
                # open_any_bag's summary of every file verified its CRCs
                record = self.reader.metadata(f, checked=True).get(PROVENANCE, {})
                if record:
                    break
            record = record or from_custom_data(self.custom_data)
            self._provenance = Provenance.from_record(record, self.path)
        return self._provenance

    def messages(self, topics: Iterable[str] | None = None, start_ns: int | None = None,
                 end_ns: int | None = None) -> Iterator[tuple[str, int, bytes]]:
        """(topic, log time [ns], CDR bytes) in log-time order over every file; ``topics``
        keeps only those, ``start_ns``/``end_ns`` bound the log time (inclusive)."""
        keep = None if topics is None else set(topics)
        streams = [self.reader.messages(f, keep, start_ns, end_ns) for f in self.files]
        if len(streams) == 1:
            yield from streams[0]
            return
        # files are time-ordered splits, but merging costs nothing and survives overlaps;
        # the file index breaks ties so that equal times keep file order. Each file is
        # pulled as the merge needs it (a list per file held every message of the bag)
        for t, _, _, topic, data in heapq.merge(*(_tagged(s, i) for i, s in enumerate(streams))):
            yield topic, t, data

    def topics_of_type(self, type_name: str) -> list[str]:
        return [name for name, info in self.topics.items() if info.type == type_name]


def _tagged(stream, i: int):
    """A file's messages as (log time, file index, position, topic, data), lazily."""
    for n, (topic, t, data) in enumerate(stream):
        yield t, i, n, topic, data


#: the bags opened in this process whose storage keeps no checksums (sqlite3): what was read
#: from them cannot be verified, which the command's report says (:func:`..cli.main`)
UNVERIFIED: list[str] = []


def _checked_against(p: Path, meta: dict, topics: dict[str, TopicInfo], count: int) -> dict:
    """The storage files' counts held against ``metadata.yaml``'s (a disagreement is
    corruption: sqlite3 keeps no checksum, and a count is what can be checked), its offered
    QoS taken over; returns its ``custom_data``."""
    entries = meta.get('topics_with_message_count') or []
    for entry in entries if isinstance(entries, list) else []:
        tm = entry.get('topic_metadata') if isinstance(entry, dict) else None
        if not isinstance(tm, dict):
            continue
        name = tm.get('name')
        n_meta = entry.get('message_count')
        if isinstance(name, str) and isinstance(n_meta, int) and not isinstance(n_meta, bool) \
                and n_meta != (topics[name].count if name in topics else 0):
            # sqlite3 keeps no checksum: a count that disagrees is what can be checked
            raise BagError(f'bag {str(p)!r} is corrupt: metadata.yaml counts {n_meta} '
                           f'messages on {name}, its storage files hold '
                           f'{topics[name].count if name in topics else 0}')
        if isinstance(name, str) and name in topics and tm.get('offered_qos_profiles') \
                is not None:
            qos = normalise_qos(tm['offered_qos_profiles'])
            if qos:
                topics[name].qos = qos
    expected = meta.get('message_count')
    if isinstance(expected, int) and expected > 0 and count == 0:
        raise BagError(f'bag {str(p)!r}: metadata.yaml counts {expected} messages but its '
                       'storage files hold none (truncated or corrupt)')
    return meta.get('custom_data') if isinstance(meta.get('custom_data'), dict) else {}


def _storage_files(p: Path, require_metadata: bool
                   ) -> tuple[dict | None, str, list[Path]]:
    """A bag's ``metadata.yaml`` (None: none), its storage's name and its files."""
    if p.is_file():
        return None, storage_of(p).name, [p]
    if not p.is_dir():
        raise BagError(f'no bag at {str(p)!r}: not a directory or a storage file ('
                       + ', '.join(s.suffix for s in STORAGES.values()) + ')')
    meta = _read_metadata(p)
    if meta is not None:
        return (meta, *_listed_files(p, meta))
    if require_metadata:
        raise BagError(f'bag {str(p)!r} has no metadata.yaml (an interrupted run?); '
                       f'rebuild it with: servovalve-twin reindex {p}')
    files = []
    for s in STORAGES.values():
        files = sorted(p.glob('*' + s.suffix))
        if files:
            break
    special = [f for f in files if not f.is_file()]
    if special:
        # a FIFO (or a device) named like a storage file blocked every reader on its first
        # read
        raise BagError(f'bag {str(p)!r}: {special[0].name} is not a regular file; a '
                       'storage file must be one')
    if not files:
        raise BagError(f'no bag at {str(p)!r}: no metadata.yaml or storage file ('
                       + ', '.join(s.suffix for s in STORAGES.values()) + ')')
    return None, storage_of(files[0]).name, files


def open_any_bag(path: str | Path, *, require_metadata: bool = False) -> AnyBag:
    """Open a rosbag2 bag directory (``metadata.yaml`` and its storage files) or a bare storage
    file; every failure is one :class:`BagError` line. ``require_metadata``: a directory
    without ``metadata.yaml`` (a run killed before it closed its bag) is refused with the
    advice to rebuild it, rather than read from its storage files alone."""
    p = Path(path)
    meta, storage, files = _storage_files(p, require_metadata)
    if storage == 'sqlite3' and str(p) not in UNVERIFIED:
        UNVERIFIED.append(str(p))
    topics: dict[str, TopicInfo] = {}
    start, end, count = None, None, 0
    for f in files:
        info, (t0, t1, n) = STORAGES[storage].summary(f)
        for name, ti in info.items():
            have = topics.setdefault(name, TopicInfo(name, ti.type, ti.qos))
            have.count += ti.count
            if not have.qos and ti.qos:
                have.qos = ti.qos
        if n:
            start = t0 if start is None else min(start, t0)
            end = t1 if end is None else max(end, t1)
            count += n
    custom = _checked_against(p, meta, topics, count) if meta is not None else {}
    if count == 0:
        raise BagError(f'bag {str(p)!r} holds no messages')
    version = int(meta['version']) if meta and isinstance(meta.get('version'), int) else None
    return AnyBag(path=p, storage=storage, files=files, topics=topics, version=version,
                  start_ns=int(start), end_ns=int(end), message_count=count,
                  custom_data=custom)


def _listed_files(p: Path, meta: dict[str, Any]) -> tuple[str, list[Path]]:
    """The storage files metadata.yaml lists: each one a file inside the bag directory (no
    absolute path, no ``..``, no link out of it), each once -- a metadata file is written by
    whoever made the bag, and must not make a command read another bag or any other file."""
    storage = meta.get('storage_identifier') or ''
    rel = meta.get('relative_file_paths') or []
    if not isinstance(storage, str) or not isinstance(rel, list) or not all(
            isinstance(f, str) and f for f in rel):
        raise BagError(f'bag {str(p)!r}: metadata.yaml\'s storage_identifier must be a name and '
                       'relative_file_paths a list of file names')
    root = p.resolve()
    files = []
    for f in rel:
        # rosbag2 before Humble wrote the bag directory into each path: <bag>/<bag>_0.db3
        cand = p / f if (p / f).exists() else p / Path(f).name
        where = cand.resolve()
        if Path(f).is_absolute() or where.parent != root:
            raise BagError(f'bag {str(p)!r}: metadata.yaml lists {f!r}, which is not a file of '
                           'the bag directory')
        if where in {x.resolve() for x in files}:
            raise BagError(f'bag {str(p)!r}: metadata.yaml lists {f!r} twice')
        files.append(cand)
    if not storage and files:
        storage = storage_of(files[0]).name
    if storage not in STORAGES:
        raise BagError(f'bag {str(p)!r}: storage {storage!r} is not supported; expected one '
                       f'of {sorted(STORAGES)}')
    missing = [str(f) for f in files if not f.is_file()]
    if missing or not files:
        raise BagError(f'bag {str(p)!r}: metadata.yaml lists storage files that are missing: '
                       f'{missing or "none listed"}')
    return storage, files


#: the largest metadata.yaml read (rosbag2's, for any bag of this project's size, is a few kB)
METADATA_LIMIT = 16 * 2 ** 20


def _read_metadata(d: Path) -> dict[str, Any] | None:
    f = d / 'metadata.yaml'
    if not f.is_file():
        return None
    if f.stat().st_size > METADATA_LIMIT:
        raise BagError(f'{str(f)!r} is {f.stat().st_size / 2 ** 20:.0f} MiB; a rosbag2 '
                       f'metadata.yaml is at most {METADATA_LIMIT // 2 ** 20} MiB here')
    try:
        raw = safe_load(f.read_text(encoding='utf-8'))
    except (OSError, UnicodeDecodeError, yaml.YAMLError, RecursionError) as exc:
        why = (str(exc).strip().splitlines() or [type(exc).__name__])[0][:100]
        raise BagError(f'{str(f)!r} is not readable YAML ({why})') from None
    info = raw.get('rosbag2_bagfile_information') if isinstance(raw, dict) else None
    if not isinstance(info, dict):
        raise BagError(f'{str(f)!r} has no rosbag2_bagfile_information: not a rosbag2 bag')
    return info


__all__ = ['AnyBag', 'TopicInfo', 'open_any_bag', 'normalise_qos']
