"""Rebuilding a bag that an interrupted or killed run left without its summary or
``metadata.yaml``."""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Any, Iterator

import yaml

from ..errors import BagError
from .reader import _mcap_errors, mcap_path
from .writer import BagWriter


def _salvage(file: Path) -> Iterator[Any]:
    """Records of a possibly truncated MCAP file, in file order, up to the first bad byte."""
    from mcap.stream_reader import StreamReader
    with open(file, 'rb') as fh:
        it = StreamReader(fh, skip_magic=False).records
        while True:
            try:
                record = next(it)
            except StopIteration:
                return
            except _mcap_errors():
                return
            yield record


def reindex(path: str | Path) -> dict[str, Any]:
    """Rebuild a readable bag from what an interrupted or killed run left: every complete record
    of the ``.mcap`` (schemas, channels, messages of complete chunks, metadata) is rewritten
    into a new file with its summary and ``metadata.yaml``. Returns the new bag metadata."""
    from mcap.records import Channel, Message, Metadata, Schema
    p = Path(path)
    file = mcap_path(p)
    bag_dir = p if p.is_dir() else p.parent
    schemas: dict[int, Any] = {}
    channels: dict[int, Any] = {}
    messages: list[Any] = []
    metadata: list[Any] = []
    try:
        for rec in _salvage(file):
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
    messages = [m for m in messages if m.channel_id in channels]
    messages.sort(key=lambda m: m.log_time)
    tmp_dir = bag_dir / '.reindex'
    shutil.rmtree(tmp_dir, ignore_errors=True)
    writer = BagWriter(tmp_dir, file_name=file.name, flush_every_ns=None,
                       library='servovalve_twin reindex')
    try:
        for ch in channels.values():
            schema = schemas.get(ch.schema_id)
            if schema is not None:
                qos = ch.metadata.get('offered_qos_profiles')
                writer.add_topic(ch.topic, schema.name, yaml.safe_load(qos) if qos else None,
                                 definition=schema.data)
        for m in messages:
            topic = channels[m.channel_id].topic
            if topic in writer.channels:
                writer.write(topic, m.data, m.log_time, m.publish_time)
        for md in metadata:
            writer.add_metadata(md.name, md.metadata)
        writer.close()
        shutil.move(str(tmp_dir / file.name), str(file))
        shutil.move(str(tmp_dir / 'metadata.yaml'), str(bag_dir / 'metadata.yaml'))
    finally:
        shutil.rmtree(tmp_dir, ignore_errors=True)
    return writer.bag_metadata()


__all__ = ['reindex']
