"""servovalve_twin.bag.storages.mcap_storage: an MCAP file's messages in log-time order, chunk
by chunk where the chunks follow each other in time, through the mcap library's merge where
they overlap -- each checked against the mcap library's own log-time reader on files written by
its writer."""

from __future__ import annotations

import dataclasses

import pytest
from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer

from servovalve_twin.bag.storages import mcap_storage as storages
from servovalve_twin.bag.cdr import encode_float64_value
from servovalve_twin.bag.storages import McapStorage
from servovalve_twin.errors import BagError


def _write(path, chunks, compression=CompressionType.NONE):
    """An MCAP file with one chunk per list of (topic, log time) in ``chunks``, in that
    order, each message's value its index in the file."""
    with open(path, 'wb') as fh:
        w = Writer(fh, chunk_size=1 << 30, compression=compression)
        w.start(profile='ros2', library='test')
        sid = w.register_schema('std_msgs/msg/Float64', 'ros2msg', b'float64 data')
        cids = {}
        k = 0
        for chunk in chunks:
            for topic, t in chunk:
                if topic not in cids:
                    cids[topic] = w.register_channel(topic, 'cdr', sid)
                w.add_message(cids[topic], t, encode_float64_value(float(k)), t)
                k += 1
            w.flush()                   # the chunk ends here
        w.finish()
    return path


def _library(path, keep=None, start=None, end=None):
    with open(path, 'rb') as fh:
        return [(ch.topic, m.log_time, bytes(m.data)) for _, ch, m in make_reader(
            fh, validate_crcs=True).iter_messages(
                topics=None if keep is None else sorted(keep), log_time_order=True,
                starting_at=start, ending_at=end)]


@pytest.mark.parametrize('compression', [CompressionType.NONE, CompressionType.ZSTD,
                                         CompressionType.LZ4])
def test_chunks_in_time_order_are_read_in_log_time_order(tmp_path, compression):
    """Three chunks following each other in time (two sharing an instant at their seam), the
    middle one's messages out of order with equal times among them: the fast path's order
    is the library's (times sorted, ties in file order), whole and filtered by topic and
    time. A file-order reader, or an unstable sort, would differ."""
    f = _write(tmp_path / 'a.mcap', [
        [('/a', 10), ('/b', 10), ('/a', 20)],
        [('/b', 40), ('/a', 25), ('/b', 20 + 10), ('/a', 30), ('/b', 20)],
        [('/a', 40), ('/b', 50)]], compression)
    with open(f, 'rb') as fh:
        assert storages._chunks_in_time_order(make_reader(fh).get_summary().chunk_indexes)
    got = list(McapStorage().messages(f, None, None, None))
    assert [t for _, t, _ in got] == [10, 10, 20, 20, 25, 30, 30, 40, 40, 50]
    assert got == _library(f)
    assert list(McapStorage().messages(f, {'/b'}, 20, 40)) == _library(f, {'/b'}, 20, 40)


def test_overlapping_chunks_go_through_the_merge(tmp_path, monkeypatch):
    """Chunks whose times overlap are not read chunk by chunk (that order would be wrong):
    the library's merge gives them in log-time order."""
    f = _write(tmp_path / 'b.mcap', [[('/a', 0), ('/a', 50)], [('/a', 10), ('/a', 60)]])
    with open(f, 'rb') as fh:
        assert not storages._chunks_in_time_order(make_reader(fh).get_summary().chunk_indexes)
    got = list(McapStorage().messages(f, None, None, None))
    assert [t for _, t, _ in got] == [0, 10, 50, 60] and got == _library(f)


def test_a_message_outside_its_chunks_stated_time_is_corrupt(tmp_path, monkeypatch):
    """A chunk index that claims a later start than its chunk's first message (a damaged
    summary) would put that message out of order: refused as corrupt, not read."""
    f = _write(tmp_path / 'c.mcap', [[('/a', 0), ('/a', 5)], [('/a', 10), ('/a', 20)]])
    real = storages._in_chunk_order

    def lying(fh, summary, *args):
        first = min(summary.chunk_indexes, key=lambda c: c.chunk_start_offset)
        summary.chunk_indexes[summary.chunk_indexes.index(first)] = dataclasses.replace(
            first, message_start_time=3)
        return real(fh, summary, *args)
    monkeypatch.setattr(storages, '_in_chunk_order', lying)
    with pytest.raises(BagError, match='corrupt'):
        list(McapStorage().messages(f, None, None, None))


@pytest.mark.parametrize('record', [0, -1])
def test_a_summary_record_with_a_damaged_length(tmp_path, record):
    """A summary record's length field flipped to 2**40 (the first record, a schema; the last,
    before the footer): the reader refuses it as corrupt, or reads the intact data section,
    in bounded memory (a reader that allocated the length it read would take 1 TB)."""
    import struct
    import tracemalloc
    f = _write(tmp_path / 'b.mcap', [[('/a', 1), ('/b', 2)], [('/a', 3)]])
    data = bytearray(f.read_bytes())
    start = struct.unpack_from('<Q', data, len(data) - 8 - 20)[0]
    heads, pos = [], start
    while data[pos] != 0x02:                        # the summary's records up to the footer
        heads.append(pos)
        pos += 9 + struct.unpack_from('<Q', data, pos + 1)[0]
    struct.pack_into('<Q', data, heads[record] + 1, 1 << 40)
    f.write_bytes(bytes(data))
    tracemalloc.start()
    try:
        got = list(McapStorage().messages(f, None, None, None))
    except BagError as exc:
        got = str(exc)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert peak < 16 << 20, peak
    if isinstance(got, str):
        assert 'corrupt' in got, got
    else:                                           # read from the intact data section
        assert [(t, ns) for t, ns, _ in got] == [('/a', 1), ('/b', 2), ('/a', 3)]


def test_a_files_crcs_are_read_once_per_state_of_the_file(tmp_path, monkeypatch):
    """Opening a bag again does not read it again for its CRCs; a byte changed in place (same
    size) is refused at the next open all the same."""
    import numpy as np
    from servovalve_twin.bag.anybag import open_any_bag
    from servovalve_twin.bag.writer import BagWriter
    w = BagWriter(tmp_path / 'b')
    w.add_topic('/value', 'std_msgs/msg/Float64')
    w.write_float64('/value', np.arange(100, dtype=np.int64) * 1_000_000, np.arange(100.0))
    w.add_metadata('note', {'k': 'a value outside the chunks'})
    w.close()
    reads = []
    crc_of = storages.crc_of
    monkeypatch.setattr(storages, 'crc_of', lambda *a: reads.append(a[1:]) or crc_of(*a))
    for _ in range(3):
        open_any_bag(tmp_path / 'b').provenance
    assert len(reads) == 2, reads                   # the summary's and the data section's
    f = tmp_path / 'b' / 'b_0.mcap'
    data = f.read_bytes()
    at = data.index(b'a value outside the chunks')
    with open(f, 'r+b') as fh:                      # in place: same size, same inode
        fh.seek(at)
        fh.write(b'A')
    with pytest.raises(BagError, match='CRC of its data section does not match'):
        open_any_bag(tmp_path / 'b')
