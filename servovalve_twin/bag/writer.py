"""A rosbag2 (Jazzy) MCAP bag writer on the ``mcap`` library, in exactly rosbag2's layout
(``doc/design/BAGS.md``): ``<dir>/<dir>_0.mcap`` with profile ``ros2``, one ``ros2msg`` schema
per type
carrying the full ``.msg`` text and its dependencies, ``cdr`` channels with
``offered_qos_profiles`` and ``topic_type_hash`` metadata, the embedded ``rosbag2`` metadata
record, and ``metadata.yaml`` version 9 -- so ``ros2 bag``, Foxglove, PlotJuggler and ``rosbags``
open it.

Chunks are uncompressed and CRC-free as rosbag2 writes them. :meth:`BagWriter.flush` closes the
current chunk and flushes the file: the twin calls it every 50 ms of simulated time, so a killed
run loses at most that much (``servovalve-twin reindex`` makes the rest readable).
"""

from __future__ import annotations

import functools
import itertools
import json
import os
import re
import sys
from pathlib import Path
from typing import Any, Mapping

import numpy as np
import yaml

from .. import __version__
from ..errors import BagError
from ..outputs import DISK_FULL, write_failed
from .cdr import CDR_HEADER
from .mcap_file import McapFileWriter

ROS_DISTRO = 'jazzy'
_DEP_RE = re.compile(r'(?:^|\n)\s*([a-zA-Z0-9_/]+)(?:\[[^\]]*\])?\s+')
_PRIMITIVES = {'bool', 'byte', 'char', 'float32', 'float64', 'int8', 'uint8', 'int16', 'uint16',
               'int32', 'uint32', 'int64', 'uint64', 'string', 'wstring'}
_INFINITE = {'sec': 9223372036, 'nsec': 854775807}


def share_dir() -> Path:
    """Where the ROS wheels keep ``share/<pkg>/msg/*.msg`` (the venv's prefix)."""
    for base in (Path(sys.prefix), *(Path(p) for p in os.environ.get('AMENT_PREFIX_PATH', '')
                                     .split(os.pathsep) if p)):
        if (base / 'share' / 'std_msgs' / 'msg').is_dir():
            return base / 'share'
    raise BagError('cannot find the ROS message definitions (share/std_msgs/msg); is '
                   'ros-jazzy-common-interfaces installed?')


def _msg_text(type_name: str) -> str:
    pkg, _, name = type_name.partition('/msg/')
    path = share_dir() / pkg / 'msg' / f'{name}.msg'
    try:
        return path.read_text(encoding='utf-8')
    except OSError:
        raise BagError(f'no message definition for {type_name} at {path}') from None


def message_definition(type_name: str) -> str:
    """The "complete message definition" rosbag2 stores: the root ``.msg`` verbatim, then each
    dependency not yet emitted as ``=`` x 80 / ``MSG: <type as written>`` / its text, sorted and
    depth-first (rosbag2's LocalMessageDefinitionSource)."""
    emitted: set[str] = set()
    parts = [_msg_text(type_name)]

    def deps(pkg: str, text: str) -> list[tuple[str, str]]:
        """(type as written, full type name) of every non-primitive field, sorted."""
        found = set()
        for m in _DEP_RE.finditer(text):
            t = m.group(1)
            if t in _PRIMITIVES:
                continue
            found.add(t if '/' in t else f'{pkg}/{t}')
        return [(w, w.replace('/', '/msg/', 1)) for w in sorted(found)]

    def walk(full: str, text: str) -> None:
        pkg = full.split('/', 1)[0]
        for written, dep_full in deps(pkg, text):
            if written in emitted:
                continue
            emitted.add(written)
            dep_text = _msg_text(dep_full)
            parts.append('\n' + '=' * 80 + '\n' + f'MSG: {written}\n' + dep_text)
            walk(dep_full, dep_text)

    walk(type_name, parts[0])
    return ''.join(parts)


def type_hash(type_name: str) -> str:
    """RIHS01 hash shipped with the wheels (``share/<pkg>/msg/<T>.json``)."""
    pkg, _, name = type_name.partition('/msg/')
    path = share_dir() / pkg / 'msg' / f'{name}.json'
    try:
        for entry in json.loads(path.read_text(encoding='utf-8'))['type_hashes']:
            if entry['type_name'] == type_name:
                return entry['hash_string']
    except (OSError, KeyError, ValueError):
        pass
    return ''


def qos_profiles(reliability: str = 'reliable', durability: str = 'volatile') -> list[dict]:
    """Offered QoS as ``ros2 bag record`` stores it in version 9 (history unknown, depth 0)."""
    return [dict(history='unknown', depth=0, reliability=reliability, durability=durability,
                 deadline=dict(_INFINITE), lifespan=dict(_INFINITE), liveliness='automatic',
                 liveliness_lease_duration=dict(_INFINITE),
                 avoid_ros_namespace_conventions=False)]


def _yaml(data: Any) -> str:
    return yaml.safe_dump(data, sort_keys=False, default_flow_style=False)



def _name_max(directory: Path) -> int:
    """The longest file name the file system of ``directory`` (or its nearest existing
    parent) takes, in bytes."""
    for d in (directory, *directory.parents):
        try:
            return os.pathconf(d, 'PC_NAME_MAX')
        except (OSError, ValueError):
            continue
    return 255


def _disk_full_is_one_line(method):
    """A write of the bag that finds the disk full (or a quota, or the file size limit)
    ends in one line that names what is kept and the command that rebuilds it: the storage
    file holds what was written, and ``metadata.yaml`` cannot be (a run left a bag without
    it and no word of reindex)."""
    @functools.wraps(method)
    def guarded(self, *args, **kwargs):
        if self.disk_full:
            return None        # said once; the shutdown that follows flushes and closes
        try:
            return method(self, *args, **kwargs)
        except OSError as exc:
            if exc.errno not in DISK_FULL:
                raise
            self.closed = self.disk_full = True
            try:
                self._fh.close()
            except OSError:
                pass
            raise BagError(str(write_failed(
                self.dir, exc, f'the messages written before are in {self.file_name}; free '
                f'space, then rebuild the bag: servovalve-twin reindex {self.dir}'))) from None
    return guarded


class BagWriter:
    """Writes one bag directory; topics are added before their first message.

    :param directory: the bag directory, created; its name names the ``.mcap`` file
    :param flush_every_ns: close the chunk and flush whenever the log time advanced this much
    """

    def __init__(self, directory: str | Path, *, flush_every_ns: int | None = 50_000_000,
                 overwrite: bool = False, file_name: str | None = None,
                 library: str = f'servovalve_twin {__version__}'):
        self.dir = Path(directory)
        if _inside(self.dir, READ_ONLY_DIRS):
            raise BagError(f'{str(self.dir)!r} is inside the packaged reference bags, which no '
                           'command writes; record somewhere else')
        if self.dir.is_symlink() or (self.dir.exists() and not self.dir.is_dir()):
            raise BagError(f'bag directory {str(self.dir)!r} is not a directory (or is a '
                           'symbolic link): refusing to write there')
        if self.dir.parent.is_symlink():
            # lnk/b would land wherever lnk points (a link planted in a shared directory)
            raise BagError(f'bag directory {str(self.dir)!r}: {str(self.dir.parent)!r} is a '
                           'symbolic link; give the directory it points to')
        try:
            here = Path.cwd().resolve()
        except OSError:                         # a working directory that was removed
            here = Path('/')
        if self.dir.resolve() in (here, *here.parents) or self.dir.name in ('', '.', '..'):
            raise BagError(f'bag directory {str(self.dir)!r} is the working directory or one '
                           'of its parents: give the bag a directory of its own')
        # the storage files are <dir>_<n>.mcap: a name the file system refuses for them left
        # an empty directory behind (a 250-character --bag)
        longest = len(os.fsencode(file_name or f'{self.dir.name}_999999.mcap'))
        if longest > _name_max(self.dir):
            raise BagError(f'bag directory name {self.dir.name[:40]!r}... is too long: its '
                           f'files are named <name>_<n>.mcap, at most {_name_max(self.dir)} '
                           'bytes here; give a shorter name')
        self._created_dir = not self.dir.exists()
        if not self._created_dir and any(self.dir.iterdir()):
            if not overwrite:
                raise BagError(f'bag directory {str(self.dir)!r} exists and is not empty; give '
                               'another directory, or --overwrite to replace the bag in it')
            # only the files the bag owns: metadata.yaml and <dir>_<n>.mcap; nothing else in
            # the directory is touched, and a symbolic link is never followed
            owned = bag_files(self.dir)
            if not owned:
                raise BagError(f'bag directory {str(self.dir)!r} holds files but no bag; '
                               '--overwrite replaces a bag, never other files: give another '
                               'directory')
            links = [f.name for f in owned if f.is_symlink()]
            if links:
                raise BagError(f'bag directory {str(self.dir)!r}: {links[0]} is a symbolic '
                               'link; refusing to replace it')
            for f in owned:
                f.unlink()
        self.dir.mkdir(parents=True, exist_ok=True)
        self.file_name = file_name or f'{self.dir.name}_0.mcap'
        fd = os.open(self.dir / self.file_name,
                     os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, 'O_NOFOLLOW', 0), 0o644)
        self._fh = os.fdopen(fd, 'wb')
        self._mcap = McapFileWriter(self._fh, profile='ros2', library=library)
        self._schemas: dict[str, int] = {}
        self.topics: dict[str, dict[str, Any]] = {}
        self.channels: dict[str, int] = {}
        self.counts: dict[str, int] = {}
        self.first_ns: int | None = None
        self.last_ns = 0
        self._flushed_ns = 0
        self._flush_every = flush_every_ns
        self.closed = False
        #: a write found the disk full: the error was raised, nothing more is written
        self.disk_full = False

    def add_topic(self, topic: str, type_name: str, qos: list[dict] | None = None,
                  definition: bytes | None = None) -> None:
        """Register a topic; ``definition`` (the schema text) defaults to the installed one."""
        if topic in self.channels:
            return
        if type_name not in self._schemas:
            self._schemas[type_name] = self._mcap.register_schema(
                name=type_name, encoding='ros2msg',
                data=definition or message_definition(type_name).encode('utf-8'))
        qos = qos or qos_profiles()
        thash = type_hash(type_name)
        self.channels[topic] = self._mcap.register_channel(
            topic=topic, message_encoding='cdr', schema_id=self._schemas[type_name],
            metadata={'offered_qos_profiles': _yaml(qos), 'topic_type_hash': thash})
        self.topics[topic] = dict(name=topic, type=type_name, serialization_format='cdr',
                                  offered_qos_profiles=qos, type_description_hash=thash)
        self.counts[topic] = 0

    @_disk_full_is_one_line
    def write(self, topic: str, data: bytes, log_ns: int, publish_ns: int | None = None) -> None:
        """One serialized CDR message (with its 4-byte encapsulation header)."""
        self._mcap.add_message(self.channels[topic], log_ns, data,
                               log_ns if publish_ns is None else publish_ns)
        self.counts[topic] += 1
        if self.first_ns is None:
            self.first_ns = log_ns
        if log_ns > self.last_ns:
            self.last_ns = log_ns
        if self._flush_every is not None and self.last_ns - self._flushed_ns >= self._flush_every:
            self.flush()

    def write_float64(self, topic: str, log_ns: np.ndarray, values: np.ndarray) -> None:
        """Many std_msgs/Float64 messages of one topic at once (log = publish time): the CDR
        bytes are the encapsulation header 00 01 00 00 and the little-endian double."""
        self.write_float64_many([(topic, log_ns, values)])

    @_disk_full_is_one_line
    def write_float64_many(self, batches) -> None:
        """:meth:`write_float64` of several topics, ``(topic, log times, values)`` each, into
        the file in that order (one topic's messages after the other's), converted and packed
        at once (one conversion of the concatenated lists, not two per topic)."""
        batches = [b for b in batches if len(b[2])]
        if not batches:
            return
        counts = [len(v) for _, _, v in batches]
        n = sum(counts)
        log_ns = np.fromiter(itertools.chain.from_iterable(t for _, t, _ in batches),
                             dtype=np.int64, count=n)
        values = np.fromiter(itertools.chain.from_iterable(v for _, _, v in batches),
                             dtype='<f8', count=n)
        rows = np.empty((n, 12), dtype=np.uint8)
        rows[:, :4] = np.frombuffer(CDR_HEADER, dtype=np.uint8)
        rows[:, 4:] = values.view(np.uint8).reshape(n, 8)
        self._mcap.add_batches([self.channels[t] for t, _, _ in batches], counts, log_ns, rows)
        for (topic, _, _), k in zip(batches, counts):
            self.counts[topic] += k
        first, last = int(log_ns.min()), int(log_ns.max())
        self.first_ns = first if self.first_ns is None else min(self.first_ns, first)
        self.last_ns = max(self.last_ns, last)

    @_disk_full_is_one_line
    def flush(self) -> None:
        self._mcap.flush()
        self._flushed_ns = self.last_ns

    @_disk_full_is_one_line
    def add_metadata(self, name: str, data: Mapping[str, str]) -> None:
        self._mcap.add_metadata(name, {str(k): str(v) for k, v in data.items()})
        self._mcap.flush()

    def bag_metadata(self) -> dict[str, Any]:
        """rosbag2's BagMetadata (version 9) of what was written."""
        start = self.first_ns or 0
        duration = self.last_ns - start if self.first_ns is not None else 0
        total = sum(self.counts.values())
        return dict(
            version=9, storage_identifier='mcap', duration=dict(nanoseconds=duration),
            starting_time=dict(nanoseconds_since_epoch=start), message_count=total,
            topics_with_message_count=[dict(topic_metadata=self.topics[t],
                                            message_count=self.counts[t]) for t in self.topics],
            compression_format='', compression_mode='', relative_file_paths=[self.file_name],
            files=[dict(path=self.file_name, starting_time=dict(nanoseconds_since_epoch=start),
                        duration=dict(nanoseconds=duration), message_count=total)],
            custom_data=None, ros_distro=os.environ.get('ROS_DISTRO', ROS_DISTRO))

    @_disk_full_is_one_line
    def close(self) -> None:
        """Write the embedded ``rosbag2`` record, the MCAP summary and ``metadata.yaml``."""
        if self.closed:
            return
        self.closed = True
        meta = self.bag_metadata()
        self._mcap.add_metadata('rosbag2', {'serialized_metadata': _yaml(meta)})
        self._mcap.finish()
        self._fh.close()
        write_metadata_yaml(self.dir, meta)


    def abort(self) -> None:
        """Remove what this writer created (a run refused or failed before it started)."""
        if not self.closed:
            self.closed = True
            self._fh.close()
        (self.dir / self.file_name).unlink(missing_ok=True)
        if self._created_dir:
            try:
                self.dir.rmdir()
            except OSError:
                pass                      # something else was put there meanwhile: keep it


def bag_files(directory: Path) -> list[Path]:
    """The files a bag directory's bag owns: metadata.yaml and <dir>_<n>.mcap."""
    own = re.compile(re.escape(directory.name) + r'_\d+\.mcap')
    return [f for f in directory.iterdir()
            if f.name == 'metadata.yaml' or own.fullmatch(f.name)]


def _inside(path: Path, roots) -> bool:
    p = path.resolve()
    return any(p == r or r in p.parents for r in (Path(x).resolve() for x in roots))


#: directories no command writes into (the packaged reference bags; config.py adds them)
READ_ONLY_DIRS: list[Path] = [Path(__file__).resolve().parents[1] / 'data']


def write_metadata_yaml(directory: Path, meta: Mapping[str, Any]) -> None:
    """metadata.yaml, written to a fresh temporary file (never through a planted link) and
    moved into place, so that a reader never sees half of it."""
    from ..outputs import new_temporary
    fd, tmp = new_temporary(directory, '.metadata-', '.yaml.tmp')
    try:
        with os.fdopen(fd, 'w', encoding='utf-8') as fh:
            fh.write(_yaml({'rosbag2_bagfile_information': dict(meta)}))
        target = directory / 'metadata.yaml'
        if target.is_symlink():
            raise BagError(f'{str(target)!r} is a symbolic link; refusing to replace it')
        os.replace(tmp, target)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
