"""Rebuilding a bag that an interrupted or killed run left without its summary or
``metadata.yaml``."""

from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path
from typing import Any, Iterator

import yaml

from ..errors import BagError
from .reader import _mcap_errors, mcap_path
from .writer import BagWriter


def _salvage(file: Path, report: dict[str, Any]) -> Iterator[Any]:
    """Records of a possibly truncated or damaged MCAP file, in file order, up to the first bad
    byte (a record cut short, or a chunk whose CRC fails); ``report`` gets where it stopped."""
    from mcap.stream_reader import StreamReader
    size = file.stat().st_size
    end = _complete_records_end(file)
    if end < size:
        report.update(stopped_at=end, skipped_bytes=size - end,
                      reason='the file ends inside a record (cut short)')
    with open(file, 'rb') as fh:
        it = StreamReader(fh, skip_magic=False, validate_crcs=True).records
        while True:
            try:
                record = next(it)
            except StopIteration:
                return
            except _mcap_errors() as exc:
                if not report['skipped_bytes']:
                    report.update(stopped_at=None, skipped_bytes=size,
                                  reason=f'{type(exc).__name__}: {str(exc)[:120]}')
                else:
                    report['reason'] += f'; {type(exc).__name__}: {str(exc)[:120]}'
                return
            yield record


def _complete_records_end(file: Path) -> int:
    """The offset after the last whole record (opcode, u64 length, body) of an MCAP file, or
    its size when it ends with its footer and magic."""
    import struct
    with open(file, 'rb') as fh:
        data = fh.read()
    pos = 8
    while pos + 9 <= len(data):
        opcode = data[pos]
        length = struct.unpack_from('<Q', data, pos + 1)[0]
        if pos + 9 + length > len(data):
            break
        pos += 9 + length
        if opcode == 0x02:                        # the footer: the magic follows
            return len(data) if data[pos:pos + 8] == data[:8] else pos
    return pos


def reindex(path: str | Path) -> dict[str, Any]:
    """Rebuild a readable bag from what an interrupted or killed run left: every complete record
    of the ``.mcap`` (schemas, channels, messages of complete chunks whose CRC holds, metadata,
    the twin's provenance among them) is rewritten into a new file with its summary and
    ``metadata.yaml``. The rebuilt bag is read back before it replaces anything; what could not
    be recovered is reported. Returns the new bag metadata with ``report``: messages kept,
    messages of unknown channels dropped, and the bytes skipped from where reading stopped."""
    from mcap.records import Channel, Message, Metadata, Schema
    from .reader import read_bag
    p = Path(path)
    file = mcap_path(p)
    bag_dir = p if p.is_dir() else p.parent
    schemas: dict[int, Any] = {}
    channels: dict[int, Any] = {}
    messages: list[Any] = []
    metadata: list[Any] = []
    report: dict[str, Any] = dict(stopped_at=None, skipped_bytes=0, reason=None)
    try:
        for rec in _salvage(file, report):
            if isinstance(rec, Schema):
                schemas[rec.id] = rec
            elif isinstance(rec, Channel):
                channels[rec.id] = rec
            elif isinstance(rec, Message):
                messages.append(rec)
            elif isinstance(rec, Metadata) and rec.name != 'rosbag2':
                metadata.append(rec)
    except OSError as exc:
        raise BagError(f'cannot read {str(file)!r}: {exc.strerror}') from None
    if not channels:
        raise BagError(f'{str(file)!r} holds no readable MCAP channel: nothing to recover')
    kept = [m for m in messages if m.channel_id in channels]
    report['dropped_messages'] = len(messages) - len(kept)
    kept.sort(key=lambda m: m.log_time)
    tmp_dir = Path(tempfile.mkdtemp(prefix='.reindex-', dir=bag_dir))
    try:
        writer = BagWriter(tmp_dir, file_name=file.name, flush_every_ns=None,
                           library='servovalve_twin reindex')
        for ch in channels.values():
            schema = schemas.get(ch.schema_id)
            if schema is not None:
                qos = ch.metadata.get('offered_qos_profiles')
                writer.add_topic(ch.topic, schema.name, yaml.safe_load(qos) if qos else None,
                                 definition=schema.data)
        for m in kept:
            topic = channels[m.channel_id].topic
            if topic in writer.channels:
                writer.write(topic, m.data, m.log_time, m.publish_time)
        for md in metadata:
            writer.add_metadata(md.name, md.metadata)
        writer.close()
        meta = writer.bag_metadata()
        if meta['message_count'] == 0:
            raise BagError(f'{str(file)!r}: no complete message to recover')
        # the rebuilt bag must read back, whole, before it replaces the original
        back = read_bag(tmp_dir, require_metadata=True) if any(
            t.get('type') == 'std_msgs/msg/Float64' for t in writer.topics.values()) else None
        if back is not None and sum(back.topics.values()) != meta['message_count']:
            raise BagError(f'{str(file)!r}: the rebuilt bag reads back '
                           f'{sum(back.topics.values())} of {meta["message_count"]} messages')
        os.replace(tmp_dir / file.name, file)
        os.replace(tmp_dir / 'metadata.yaml', bag_dir / 'metadata.yaml')
    finally:
        shutil.rmtree(tmp_dir, ignore_errors=True)
    report['messages'] = meta['message_count']
    return dict(meta, report=report)


__all__ = ['reindex']
