"""MCAP files (``.mcap``): chunks uncompressed, zstd or lz4, read in log-time order chunk by
chunk where the chunks allow it, every CRC checked once per state of the file."""

from __future__ import annotations

import inspect
import io
import os
import struct
import zlib
from pathlib import Path
from typing import NamedTuple

from ...errors import BagError
from .base import Storage, Summary, TopicInfo, normalise_qos

# what a damaged file raises inside the mcap library besides its own McapError
_CORRUPT = (EOFError, struct.error, ValueError, KeyError, IndexError, UnicodeDecodeError,
            MemoryError, OverflowError)


def mcap_errors() -> tuple[type[BaseException], ...]:
    """Everything the mcap library raises on a truncated or damaged file -- its own errors,
    and its decompressors' on a damaged chunk (zstandard's ZstdError; lz4's RuntimeError)."""
    from mcap.exceptions import McapError
    extra: tuple[type[BaseException], ...] = (RuntimeError,)
    try:
        from zstandard import ZstdError
        extra += (ZstdError,)
    except ImportError:                     # no zstd: such chunks fail as McapError
        pass
    return (McapError,) + _CORRUPT + extra


def crc_of(fh, start: int, end: int) -> int:
    """CRC32 of bytes [start, end) of an open file, in blocks: memory does not grow with it."""
    fh.seek(start)
    crc, left = 0, end - start
    while left > 0:
        block = fh.read(min(left, 1 << 20))
        if not block:
            break
        crc = zlib.crc32(block, crc)
        left -= len(block)
    return crc


#: files whose CRCs were verified, by identity and state (device, inode, size, modification
#: and change times: any write changes the change time), so that opening a bag again -- a
#: command opens it for its windows, its provenance and its rows -- does not read the whole
#: file again (a 4.3 GB bag: six full reads in one `compare --plot`)
_VERIFIED: set[tuple[int, ...]] = set()


def check_data_crc(file: Path) -> None:
    """Verify an MCAP file's data-section CRC (the DataEnd record's), which covers what lies
    outside the chunks -- the metadata records, the twin's provenance among them -- and its
    summary CRC (the footer's), which covers the statistics and indexes. The mcap reader checks
    chunk CRCs but neither of these. A CRC of 0 means "not computed" (rosbag2 writes 0; so did
    this project before CRCs). Once per state of a file per process (:data:`_VERIFIED`)."""
    st = os.stat(file)
    state = (st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns, st.st_ctime_ns)
    if state in _VERIFIED:
        return
    _verify_crcs(file)
    if len(_VERIFIED) > 1024:               # a long-lived process reading many bags
        _VERIFIED.clear()
    _VERIFIED.add(state)


def _verify_crcs(file: Path) -> None:
    with open(file, 'rb') as fh:
        fh.seek(0, 2)
        size = fh.tell()
        if size < 8 + 29 + 8:
            return                              # no footer: the reader will say what is wrong
        fh.seek(0)
        head = fh.read(8)
        footer_at = size - 8 - 29
        fh.seek(footer_at)
        footer = fh.read(29)
        tail = fh.read(8)
        if tail != head or footer[0] != 0x02:
            return
        summary_start, _, summary_crc = struct.unpack('<QQI', footer[9:29])
        end = summary_start - 13 if summary_start else footer_at - 13
        fh.seek(max(end, 0))
        data_end = fh.read(13)
        if end < 8 or data_end[:1] != b'\x0f':
            raise BagError(f'bag {str(file)!r} is corrupt (no DataEnd record where the footer '
                           'points)')
        if summary_start and summary_crc and crc_of(fh, summary_start,
                                                     footer_at + 25) != summary_crc:
            raise BagError(f'bag {str(file)!r} is corrupt: the CRC of its summary does not '
                           'match (a byte was changed in its statistics or indexes)')
        stored = struct.unpack('<I', data_end[9:13])[0]
        if stored and crc_of(fh, 0, end) != stored:
            raise BagError(f'bag {str(file)!r} is corrupt: the CRC of its data section does '
                           'not match (a byte was changed outside the message chunks)')


def _topic_info(channel, schema) -> TopicInfo:
    """A topic as an MCAP channel (and its schema) describes it; the count is added later."""
    return TopicInfo(channel.topic, schema.name if schema else '',
                     normalise_qos(channel.metadata.get('offered_qos_profiles', '')),
                     serialization_format=channel.message_encoding)


#: summary-section record opcodes (MCAP spec)
_OP_FOOTER, _OP_SCHEMA, _OP_CHANNEL, _OP_CHUNK_INDEX = 0x02, 0x03, 0x04, 0x08
_OP_STATISTICS, _OP_METADATA_INDEX = 0x0B, 0x0D
#: a chunk index's fixed head: message start and end time, chunk start offset and length,
#: the byte length of its (channel id uint16, offset uint64) map
_CHUNK_INDEX_HEAD = struct.Struct('<QQQQI')


class _ChunkAt(NamedTuple):
    """What the reader uses of a chunk index (the library's ``ChunkIndex`` costs ~20 x more
    to parse: a read call per field)."""

    message_start_time: int
    message_end_time: int
    chunk_start_offset: int
    channel_ids: frozenset


def _summary_records(fh, start: int, wanted):
    """``(opcode, body)`` of the summary section's records whose opcode is in ``wanted``, the
    others skipped by their length unparsed (a 4 GB bag has ~250 k chunk indexes)."""
    size = fh.seek(0, 2)
    fh.seek(start)
    while True:
        head = fh.read(9)
        if len(head) < 9:
            raise EOFError('the summary section ends without a footer')
        op, length = _RECORD_HEAD.unpack(head)
        if op == _OP_FOOTER:
            return
        if fh.tell() + length > size:       # a damaged length: refused before any read
            raise EOFError('a summary record runs past the end of the file')
        if op in wanted:
            yield op, fh.read(length)
        else:
            fh.seek(length, 1)


def _footer_summary_start(fh) -> int:
    from mcap.records import Footer
    from mcap.stream_reader import MAGIC_SIZE, StreamReader
    fh.seek(0, 2)
    fh.seek(fh.tell() - MAGIC_SIZE - 29)            # the footer: opcode, length, 20 bytes
    footer = next(StreamReader(fh, skip_magic=True).records)
    if not isinstance(footer, Footer):
        raise ValueError('no footer at the end of the file')
    return footer.summary_start


def _lean_summary(fh):
    """An MCAP file's summary section read record by record into the mcap library's
    ``Summary`` -- statistics, schemas, channels, metadata indexes -- without its chunk
    indexes, which the library keeps as one object per chunk (a 4 GB bag of 16 kB chunks:
    ~300 MB) and which are skipped here unread; :func:`_chunk_indexes` streams them. None
    without a summary; its ``start`` is the summary section's offset."""
    from mcap.data_stream import ReadDataStream
    from mcap.records import Channel, MetadataIndex, Schema, Statistics
    from mcap.summary import Summary
    start = _footer_summary_start(fh)
    if start == 0:
        return None
    out = Summary()
    out.start = start
    kinds = {_OP_STATISTICS: Statistics, _OP_SCHEMA: Schema, _OP_CHANNEL: Channel,
             _OP_METADATA_INDEX: MetadataIndex}
    for op, body in _summary_records(fh, start, kinds):
        rec = kinds[op].read(ReadDataStream(io.BytesIO(body)))
        if op == _OP_STATISTICS:
            out.statistics = rec
        elif op == _OP_SCHEMA:
            out.schemas[rec.id] = rec
        elif op == _OP_CHANNEL:
            out.channels[rec.id] = rec
        else:
            out.metadata_indexes.append(rec)
    return out


def _chunk_indexes(f: Path, start: int):
    """The summary section's chunk indexes one at a time (as :class:`_ChunkAt`), from their
    own handle on ``f``."""
    with open(f, 'rb', buffering=1 << 20) as fh:
        for _, body in _summary_records(fh, start, (_OP_CHUNK_INDEX,)):
            t0, t1, offset, _, n = _CHUNK_INDEX_HEAD.unpack_from(body)
            if _CHUNK_INDEX_HEAD.size + n > len(body) or n % 10:
                raise ValueError('a chunk index whose channel map runs past its end')
            ids = frozenset(struct.unpack_from('<H', body, _CHUNK_INDEX_HEAD.size + k)[0]
                            for k in range(0, n, 10))
            yield _ChunkAt(t0, t1, offset, ids)


def _chunks_in_time_order(chunk_indexes) -> bool:
    """The chunks, listed in file order, follow each other in time (each starts at or after
    the end of the one before): what a recorder writes, and where log-time order is file
    order within each chunk, chunk after chunk. Streams over ``chunk_indexes``."""
    prev = None
    for c in chunk_indexes:
        if prev is not None and (c.chunk_start_offset <= prev.chunk_start_offset
                                 or c.message_start_time < prev.message_end_time):
            return False
        prev = c
    return prev is not None


#: a message record's fixed head after the record's opcode and length: channel id, sequence,
#: log time, publish time (MCAP spec, little-endian)
_MESSAGE_HEAD = struct.Struct('<HIQQ')
_RECORD_HEAD = struct.Struct('<BQ')
_OP_MESSAGE = 0x05


def _in_chunk_order(fh, summary, chunk_indexes, keep, start_ns, end_ns, topics_out):
    """The messages of a file whose chunks follow each other in time, chunk by chunk, each
    chunk's in log-time order (a stable sort: equal times in file order) -- the order of the
    mcap library's log-time merge, which keeps every message in a Python heap (half the time
    of reading a long bag: measured). Each chunk's CRC is checked, and a message outside the
    time its chunk's index claims, which would break the order, is corruption."""
    from mcap.data_stream import ReadDataStream
    from mcap.records import Chunk
    from mcap.stream_reader import get_chunk_data_stream
    channels = summary.channels
    wanted = {cid for cid, ch in channels.items() if keep is None or ch.topic in keep}
    last = -1
    for ci in chunk_indexes:
        if start_ns is not None and ci.message_end_time < start_ns:
            continue
        if end_ns is not None and ci.message_start_time > end_ns:
            continue
        if ci.channel_ids and not wanted.intersection(ci.channel_ids):
            continue
        fh.seek(ci.chunk_start_offset + 1 + 8)
        stream, size = get_chunk_data_stream(Chunk.read(ReadDataStream(fh)), validate_crc=True)
        data = stream.read(size)
        got = []
        pos = 0
        while pos < size:
            op, length = _RECORD_HEAD.unpack_from(data, pos)
            pos += 9
            if op == _OP_MESSAGE:
                if length < _MESSAGE_HEAD.size:
                    raise ValueError(f'a message record of {length} bytes, shorter than its '
                                     'head')
                cid, _, t, _ = _MESSAGE_HEAD.unpack_from(data, pos)
                if cid not in channels:
                    raise KeyError(f'message on channel {cid}, which the file does not define')
                if cid in wanted and (start_ns is None or t >= start_ns) and (
                        end_ns is None or t <= end_ns):
                    got.append((t, cid, data[pos + 22:pos + length]))
            pos += length
        if pos != size:
            raise EOFError('a record runs past the end of its chunk')
        if any(a[0] > b[0] for a, b in zip(got, got[1:])):
            got.sort(key=lambda m: m[0])
        if got and (got[0][0] < max(last, ci.message_start_time)
                    or got[-1][0] > ci.message_end_time):
            raise ValueError('a message lies outside the time its chunk\'s index gives')
        for t, cid, payload in got:
            ch = channels[cid]
            if topics_out is not None and ch.topic not in topics_out:
                topics_out[ch.topic] = _topic_info(
                    ch, summary.schemas.get(ch.schema_id) if ch.schema_id else None)
            yield ch.topic, t, payload
        if got:
            last = got[-1][0]


def _metadata_records(fh):
    """The file's Metadata records: at the summary's metadata indexes, else read through the
    file (what the mcap library's ``iter_metadata`` does, without loading every chunk
    index)."""
    from mcap.reader import NonSeekingReader
    from mcap.records import Metadata
    from mcap.stream_reader import StreamReader
    summary = _lean_summary(fh)
    if summary is None:
        fh.seek(0)
        yield from NonSeekingReader(fh).iter_metadata()
        return
    for index in summary.metadata_indexes:
        fh.seek(index.offset)
        rec = next(StreamReader(fh, skip_magic=True).records)
        if not isinstance(rec, Metadata):
            raise ValueError(f'expected a metadata record at {index.offset}')
        yield rec


class McapStorage(Storage):
    """MCAP files, chunks uncompressed, zstd or lz4; chunk, summary and data CRCs checked."""

    name, suffix, magic = 'mcap', '.mcap', b'\x89MCAP'

    def summary(self, f: Path) -> Summary:
        """From the summary's statistics when the file has them, else by reading it once."""
        try:
            check_data_crc(f)
            with open(f, 'rb') as fh:
                summary = _lean_summary(fh)
        except OSError as exc:
            raise BagError(f'cannot read {str(f)!r}: {exc.strerror}') from None
        except mcap_errors():
            summary = None                      # no usable summary: read the messages instead
        if summary is None or summary.statistics is None:
            return super().summary(f)
        st = summary.statistics
        topics: dict[str, TopicInfo] = {}
        for cid, ch in summary.channels.items():
            info = topics.setdefault(ch.topic,
                                     _topic_info(ch, summary.schemas.get(ch.schema_id)))
            info.count += st.channel_message_counts.get(cid, 0)
        n = st.message_count
        return topics, (st.message_start_time if n else 0, st.message_end_time if n else 0, n)

    def messages(self, f, keep, start_ns, end_ns, topics_out=None):
        from mcap.reader import make_reader
        try:
            with open(f, 'rb') as fh:
                reader = make_reader(fh, validate_crcs=True)
                # mcap 1.6 names the bounds starting_at / ending_at (inclusive) and deprecates
                # start_time / end_time (end exclusive), which older releases alone have
                if 'starting_at' in inspect.signature(reader.iter_messages).parameters:
                    span = dict(starting_at=start_ns, ending_at=end_ns)
                else:
                    span = dict(start_time=start_ns,
                                end_time=None if end_ns is None else end_ns + 1)
                summary = _lean_summary(fh)
                if summary is not None and _chunks_in_time_order(
                        _chunk_indexes(f, summary.start)):
                    yield from _in_chunk_order(fh, summary, _chunk_indexes(f, summary.start),
                                               keep, start_ns, end_ns, topics_out)
                    return
                for schema, ch, msg in reader.iter_messages(
                        topics=None if keep is None else sorted(keep), log_time_order=True,
                        **span):
                    if topics_out is not None and ch.topic not in topics_out:
                        topics_out[ch.topic] = _topic_info(ch, schema)
                    yield ch.topic, msg.log_time, bytes(msg.data)
        except OSError as exc:
            raise BagError(f'cannot read {str(f)!r}: {exc.strerror}') from None
        except mcap_errors() as exc:
            raise BagError(f'{str(f)!r} is truncated or corrupt ({type(exc).__name__}: '
                           f'{str(exc)[:120]}); try: servovalve-twin reindex') from None

    def metadata(self, f: Path, *, checked: bool = False) -> dict[str, dict[str, str]]:
        out: dict[str, dict[str, str]] = {}
        try:
            if not checked:                     # the data CRC streams over the whole file
                check_data_crc(f)
            with open(f, 'rb') as fh:
                for meta in _metadata_records(fh):
                    out.setdefault(meta.name, dict(meta.metadata))
        except OSError as exc:
            raise BagError(f'cannot read bag {str(f)!r}: {exc.strerror}') from None
        except mcap_errors() as exc:
            raise BagError(f'bag {str(f)!r} is truncated or corrupt ({type(exc).__name__}: '
                           f'{str(exc)[:120]})') from None
        return out


__all__ = ['McapStorage', 'check_data_crc', 'crc_of', 'mcap_errors']
