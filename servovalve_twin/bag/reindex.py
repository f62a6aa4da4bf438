"""Rebuilding a bag: ``metadata.yaml`` and every MCAP file's summary, from what its storage
files hold -- after a killed run (no summary, no ``metadata.yaml``) or a damaged file.

What it must never do is lose data. Each MCAP file is scanned record by record, in constant
memory: a chunk whose CRC fails (or that does not parse) is skipped and reported, and every
intact chunk after it is kept -- a damaged length field is passed by resynchronising on the
next chunk whose CRC holds. The messages are rewritten in log-time order (chunks merged by a
sweep over their time spans, so memory is that of the chunks open at one instant, not the
bag's), read back and counted, and only then moved into place. A file from which anything was
dropped is kept beside the rebuilt one as ``<file>.damaged``. Like ``ros2 bag reindex``, a
sqlite3 bag gets its ``metadata.yaml`` rebuilt from its files (which stay as they are).
"""

from __future__ import annotations

import dataclasses
import heapq
import io
import os
import shutil
import struct
import tempfile
from pathlib import Path
from typing import Any, Iterator

from ..errors import BagError
from . import safe_load
from .storages import STORAGES, crc_of, storage_of
from .writer import READ_ONLY_DIRS, BagWriter, _inside, write_metadata_yaml

_CHUNK, _DATA_END, _FOOTER = 0x06, 0x0F, 0x02
_SCHEMA, _CHANNEL, _MESSAGE, _METADATA = 0x03, 0x04, 0x05, 0x0C
_HEAD = struct.Struct('<BQ')
_BLOCK = 1 << 20


@dataclasses.dataclass
class _Chunk:
    """An intact chunk found by the scan (or a message outside chunks: ``loose``)."""

    offset: int                 # of the record body
    length: int
    start: int
    end: int
    loose: bool = False


@dataclasses.dataclass
class Scan:
    """What one MCAP file holds, by the scan."""

    schemas: dict[int, Any] = dataclasses.field(default_factory=dict)
    channels: dict[int, Any] = dataclasses.field(default_factory=dict)
    metadata: list[Any] = dataclasses.field(default_factory=list)
    chunks: list[_Chunk] = dataclasses.field(default_factory=list)
    damaged: list[tuple[int, int, str]] = dataclasses.field(default_factory=list)  # at, bytes, why


def _stream(body: bytes):
    from mcap.data_stream import ReadDataStream
    return ReadDataStream(io.BytesIO(body))


def _chunk_records(body: bytes) -> list[Any]:
    """The records of a chunk record's body, CRC checked (raises on any damage)."""
    from mcap.records import Chunk
    from mcap.stream_reader import breakup_chunk
    chunk = Chunk.read(_stream(body))
    return breakup_chunk(chunk, validate_crc=True)


def _valid_chunk(body: bytes) -> tuple[int, int, list[Any]] | None:
    """(start, end) log times and the records of an intact chunk; None if it is damaged."""
    from mcap.records import Chunk, Message
    try:
        chunk = Chunk.read(_stream(body))
        records = _chunk_records(body)
    except Exception:  # noqa: BLE001 -- whatever a damaged chunk raises, it is damage
        return None
    times = [r.log_time for r in records if isinstance(r, Message)]
    if not times:
        return chunk.message_start_time, chunk.message_end_time, records
    return min(times), max(times), records


def scan_mcap(file: Path) -> Scan:
    """Every intact record of an MCAP file up to its DataEnd, damaged stretches reported."""
    from mcap.records import Channel, Message, Metadata, Schema
    out = Scan()
    size = file.stat().st_size
    with open(file, 'rb') as fh:
        if fh.read(8)[:5] != b'\x89MCAP':
            raise BagError(f'{str(file)!r} is not an MCAP file')
        pos = 8
        while pos + 9 <= size:
            fh.seek(pos)
            opcode, length = _HEAD.unpack(fh.read(9))
            if opcode == _DATA_END and length == 4:
                stored = struct.unpack('<I', fh.read(4))[0]
                if not out.damaged and stored and crc_of(fh, 0, pos) != stored:
                    # every chunk held its CRC: the damage is in a record outside them
                    out.damaged.append((0, 0, 'the data section CRC does not match: a byte '
                                        'changed outside the chunks (schemas, channels, '
                                        'metadata); what parses was kept'))
                break
            if opcode == _FOOTER:
                break
            body_at = pos + 9
            ok = body_at + length <= size
            if ok and opcode == _CHUNK:
                body = fh.read(length)
                valid = _valid_chunk(body)
                ok = valid is not None
                if ok:
                    start, end, records = valid
                    out.chunks.append(_Chunk(body_at, length, start, end))
                    # a chunk may hold schemas and channels too
                    for r in records:
                        if isinstance(r, Schema):
                            out.schemas.setdefault(r.id, r)
                        elif isinstance(r, Channel):
                            out.channels.setdefault(r.id, r)
            elif ok and opcode in (_SCHEMA, _CHANNEL, _MESSAGE, _METADATA):
                body = fh.read(length)
                kind = {_SCHEMA: Schema, _CHANNEL: Channel, _MESSAGE: Message,
                        _METADATA: Metadata}[opcode]
                try:
                    s = _stream(body)
                    rec = kind.read(s, length) if kind is Message else kind.read(s)
                    ok = s.count == length
                except Exception:  # noqa: BLE001 -- a record that does not parse is damage
                    ok = False
                if ok and kind is Schema:
                    out.schemas.setdefault(rec.id, rec)
                elif ok and kind is Channel:
                    out.channels.setdefault(rec.id, rec)
                elif ok and kind is Metadata:
                    if rec.name != 'rosbag2':        # rebuilt from the data instead
                        out.metadata.append(rec)
                elif ok:
                    out.chunks.append(_Chunk(body_at, length, rec.log_time, rec.log_time,
                                             loose=True))
            # other opcodes (header, indexes, attachments) are skipped by their length
            if ok:
                pos = body_at + length
                continue
            nxt = _resync(fh, pos + 1, size)
            why = ('the file ends inside a record (cut short)' if nxt is None
                   and body_at + length > size else
                   f'a damaged record (opcode 0x{opcode:02x}) at byte {pos}')
            out.damaged.append((pos, (nxt or size) - pos, why))
            if nxt is None:
                break
            pos = nxt
    return out


def _resync(fh, start: int, size: int) -> int | None:
    """The offset of the next chunk record at or after ``start`` whose CRC holds (or of the
    DataEnd record after which nothing is data); None when there is none."""
    pos = start
    while pos < size:
        fh.seek(pos)
        block = fh.read(_BLOCK + 9)
        i = 0
        while True:
            j = min((k for k in (block.find(b'\x06', i), block.find(b'\x0f', i)) if k >= 0),
                    default=-1)
            if j < 0 or j + 9 > len(block):
                break
            at = pos + j
            opcode, length = _HEAD.unpack_from(block, j)
            if opcode == _DATA_END and length == 4 and at + 13 <= size:
                return at
            if opcode == _CHUNK and 40 <= length <= size - at - 9:
                fh.seek(at + 9)
                if _valid_chunk(fh.read(length)) is not None:
                    return at
            i = j + 1
        pos += _BLOCK
    return None


def _messages_in_time_order(fh, chunks: list[_Chunk]) -> Iterator[Any]:
    """Every message of the intact chunks in log-time order (equal times: file order), with
    only the chunks open whose span holds the sweep's current time."""
    from mcap.records import Message
    order = sorted(range(len(chunks)), key=lambda k: (chunks[k].start, k))
    heap: list[tuple[int, int, int, Any, Iterator]] = []

    def open_chunk(k: int) -> None:
        c = chunks[k]
        fh.seek(c.offset)
        body = fh.read(c.length)
        if c.loose:
            msgs = [Message.read(_stream(body), c.length)]
        else:
            msgs = [r for r in _chunk_records(body) if isinstance(r, Message)]
            msgs.sort(key=lambda m: m.log_time)          # stable: file order within a time
        it = iter(enumerate(msgs))
        first = next(it, None)
        if first is not None:
            heapq.heappush(heap, (first[1].log_time, k, first[0], first[1], it))

    nxt = 0
    while nxt < len(order) or heap:
        while nxt < len(order) and (not heap or chunks[order[nxt]].start <= heap[0][0]):
            open_chunk(order[nxt])
            nxt += 1
        if not heap:
            continue
        t, k, _, msg, it = heapq.heappop(heap)
        yield msg
        following = next(it, None)
        if following is not None:
            heapq.heappush(heap, (following[1].log_time, k, following[0], following[1], it))


def _rebuild_mcap(file: Path, out_dir: Path) -> tuple[dict[str, Any], dict[str, Any]]:
    """The file rewritten into ``out_dir`` (same name); returns its bag metadata and report."""
    scan = scan_mcap(file)
    if not scan.channels:
        raise BagError(f'{str(file)!r} holds no readable MCAP channel: nothing to recover')
    writer = BagWriter(out_dir, file_name=file.name, library='servovalve_twin reindex')
    for ch in scan.channels.values():
        schema = scan.schemas.get(ch.schema_id)
        if schema is not None:
            qos = ch.metadata.get('offered_qos_profiles')
            writer.add_topic(ch.topic, schema.name, safe_load(qos) if qos else None,
                             definition=schema.data)
    dropped = 0
    with open(file, 'rb') as fh:
        for m in _messages_in_time_order(fh, scan.chunks):
            ch = scan.channels.get(m.channel_id)
            if ch is None or ch.topic not in writer.channels:
                dropped += 1
                continue
            writer.write(ch.topic, m.data, m.log_time, m.publish_time)
    for md in scan.metadata:
        writer.add_metadata(md.name, md.metadata)
    writer.close()
    meta = writer.bag_metadata()
    report = dict(file=file.name, messages=meta['message_count'], dropped_messages=dropped,
                  damaged=[dict(at=a, bytes=n, reason=why) for a, n, why in scan.damaged])
    # what the file's own summary said it held, where that summary still reads: the messages
    # it indexed that the rebuild could not find were lost silently ("rebuilt, 14831
    # messages", with ~1,300 indexed ones in a missing chunk)
    indexed = _indexed_count(file)
    if indexed is not None and indexed > meta['message_count']:
        report['indexed_missing'] = indexed - meta['message_count']
        report['indexed'] = indexed
    return meta, report


def _indexed_count(file: Path) -> int | None:
    """The message count of an MCAP file's own summary (its Statistics record), or None where
    it has none or it does not read."""
    from mcap.reader import SeekingReader
    try:
        with open(file, 'rb') as fh:
            summary = SeekingReader(fh, validate_crcs=False).get_summary()
    except Exception:  # noqa: BLE001 -- a damaged or absent summary says nothing
        return None
    stats = summary.statistics if summary is not None else None
    return int(stats.message_count) if stats is not None else None


def _count_back(directory: Path, files: list[str]) -> dict[str, int]:
    """Messages per topic of the rebuilt files, read back through the one reader."""
    counts: dict[str, int] = {}
    for name in files:
        for topic, _, _ in STORAGES[storage_of(directory / name).name].messages(
                directory / name, None, None, None):
            counts[topic] = counts.get(topic, 0) + 1
    return counts


def _custom_data(bag_dir: Path) -> dict[str, str] | None:
    """The user's ``custom_data`` of an existing metadata.yaml (kept across a rebuild)."""
    try:
        raw = safe_load((bag_dir / 'metadata.yaml').read_text(encoding='utf-8'))
        custom = raw['rosbag2_bagfile_information'].get('custom_data')
    except Exception:  # noqa: BLE001 -- absent or unreadable: there is nothing to keep
        return None
    return custom if isinstance(custom, dict) else None


def _merged_metadata(storage: str, metas: list[dict[str, Any]],
                     custom: dict[str, str] | None) -> dict[str, Any]:
    """One bag's metadata (rosbag2 version 9) from each file's."""
    topics: dict[str, dict[str, Any]] = {}
    for m in metas:
        for entry in m['topics_with_message_count']:
            name = entry['topic_metadata']['name']
            have = topics.setdefault(name, dict(topic_metadata=entry['topic_metadata'],
                                                message_count=0))
            have['message_count'] += entry['message_count']
    live = [m for m in metas if m['message_count']]
    start = min((m['starting_time']['nanoseconds_since_epoch'] for m in live), default=0)
    end = max((m['starting_time']['nanoseconds_since_epoch'] + m['duration']['nanoseconds']
               for m in live), default=0)
    files = [f for m in metas for f in m['files']]
    return dict(version=9, storage_identifier=storage, duration=dict(nanoseconds=end - start),
                starting_time=dict(nanoseconds_since_epoch=start),
                message_count=sum(m['message_count'] for m in metas),
                topics_with_message_count=list(topics.values()), compression_format='',
                compression_mode='', relative_file_paths=[f['path'] for f in files],
                files=files, custom_data=custom,
                ros_distro=metas[0].get('ros_distro', '') if metas else '')


def _file_metadata(f: Path) -> dict[str, Any]:
    """A sqlite3 file's metadata entry, from reading it (its counts are what it holds)."""
    storage = STORAGES[storage_of(f).name]
    topics, (t0, t1, n) = storage.summary(f)
    return dict(message_count=n, starting_time=dict(nanoseconds_since_epoch=t0),
                duration=dict(nanoseconds=t1 - t0),
                topics_with_message_count=[dict(topic_metadata=dict(
                    name=t.name, type=t.type, serialization_format=t.serialization_format,
                    offered_qos_profiles=t.qos, type_description_hash=''),
                    message_count=t.count) for t in topics.values()],
                files=[dict(path=f.name, starting_time=dict(nanoseconds_since_epoch=t0),
                            duration=dict(nanoseconds=t1 - t0), message_count=n)])


def _storage_files(p: Path) -> tuple[Path, list[Path]]:
    if p.is_file():
        listed = _listed_files(p.parent)
        if listed is not None and listed != [p.name]:
            # rebuilding this file alone would write a metadata.yaml that lists it alone,
            # over the one of the bag beside it (another bag's, or this file's with others)
            raise BagError(f'{str(p.parent / "metadata.yaml")!r} describes a bag of '
                           f'{listed or "no files"}, not of {p.name} alone: reindex the '
                           f'directory, or move {p.name} into a directory of its own')
        return p.parent, [p]
    if not p.is_dir():
        raise BagError(f'no bag at {str(p)!r}: not a directory or a storage file')
    for s in STORAGES.values():
        files = sorted(f for f in p.glob('*' + s.suffix) if not f.is_symlink())
        if files:
            return p, files
    raise BagError(f'no bag at {str(p)!r}: no storage file ('
                   + ', '.join(s.suffix for s in STORAGES.values()) + ')')


def _listed_files(bag_dir: Path) -> list[str] | None:
    """The storage files an existing metadata.yaml of ``bag_dir`` lists (None: there is none;
    [] where it lists none or cannot be read)."""
    f = bag_dir / 'metadata.yaml'
    if not f.is_file():
        return None
    try:
        raw = safe_load(f.read_text(encoding='utf-8'))
        files = raw['rosbag2_bagfile_information'].get('relative_file_paths') or []
        return sorted(Path(str(x)).name for x in files)
    except Exception:  # noqa: BLE001 -- unreadable: it is still not ours to replace
        return []


def reindex(path: str | Path) -> dict[str, Any]:
    """Rebuild the bag at ``path`` (a directory, or one of its storage files). Returns the new
    bag metadata with ``report``: per file, messages kept, messages of unknown channels
    dropped, damaged stretches skipped (offset, bytes, reason), and where a damaged original
    was kept."""
    bag_dir, files = _storage_files(Path(path))
    if _inside(bag_dir, READ_ONLY_DIRS):
        raise BagError(f'{str(bag_dir)!r} is inside the packaged reference bags, which no '
                       'command writes')
    storage = storage_of(files[0]).name
    if any(storage_of(f).name != storage for f in files):
        raise BagError(f'bag {str(bag_dir)!r} mixes storages; reindex one file at a time')
    custom = _custom_data(bag_dir)
    if storage != 'mcap':
        metas = [_file_metadata(f) for f in files]
        meta = _merged_metadata(storage, metas, custom)
        if meta['message_count'] == 0:
            raise BagError(f'bag {str(bag_dir)!r}: no message to index')
        write_metadata_yaml(bag_dir, meta)
        return dict(meta, report=dict(files=[dict(file=f.name, messages=m['message_count'],
                                                  dropped_messages=0, damaged=[])
                                             for f, m in zip(files, metas)]))
    tmp_dir = Path(tempfile.mkdtemp(prefix='.reindex-', dir=bag_dir))
    try:
        metas, reports = [], []
        for f in files:
            sub = tmp_dir / f'{len(metas)}'
            meta, rep = _rebuild_mcap(f, sub)
            metas.append(meta)
            reports.append(rep)
        meta = _merged_metadata('mcap', metas, custom)
        if meta['message_count'] == 0:
            raise BagError(f'bag {str(bag_dir)!r}: no complete message to recover')
        # the rebuilt files must read back, whole, before anything is replaced
        back: dict[str, int] = {}
        for k, f in enumerate(files):
            for t, n in _count_back(tmp_dir / str(k), [f.name]).items():
                back[t] = back.get(t, 0) + n
        want = {e['topic_metadata']['name']: e['message_count']
                for e in meta['topics_with_message_count'] if e['message_count']}
        if back != want:
            raise BagError(f'bag {str(bag_dir)!r}: the rebuilt bag reads back '
                           f'{sum(back.values())} of {meta["message_count"]} messages; the '
                           'original is left as it was')
        for k, (f, rep) in enumerate(zip(files, reports)):
            if rep['damaged'] or rep['dropped_messages']:
                keep = _free_name(f.with_name(f.name + '.damaged'))
                try:
                    os.link(f, keep)              # the original stays, under another name
                except OSError:
                    shutil.copy2(f, keep)
                rep['original_kept_as'] = keep.name
            os.replace(tmp_dir / str(k) / f.name, f)
        write_metadata_yaml(bag_dir, meta)
    finally:
        shutil.rmtree(tmp_dir, ignore_errors=True)
    return dict(meta, report=dict(files=reports))


def _free_name(p: Path) -> Path:
    n = 1
    out = p
    while out.exists():
        out = p.with_name(f'{p.name}.{n}')
        n += 1
    return out


__all__ = ['reindex', 'scan_mcap']
