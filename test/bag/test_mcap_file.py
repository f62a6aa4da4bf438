"""The MCAP writer (bag/mcap_file.py): a file of thousands of chunks whose chunk indexes went
through a temporary file reads back with the mcap library -- every chunk indexed where it
lies, the summary's CRC as the spec computes it -- and writing it holds memory that does not
grow with the number of chunks."""

import struct
import zlib

import numpy as np
import pytest

from servovalve_twin.bag import mcap_file
from servovalve_twin.bag.writer import BagWriter


def _write(path, chunks, per_chunk=5):
    w = BagWriter(path)
    w.add_topic('/value', 'std_msgs/msg/Float64')
    for k in range(chunks):
        t = (np.arange(per_chunk, dtype=np.int64) + k * per_chunk) * 1_000_000
        w.write_float64('/value', t, t * 1e-9)
        w.flush()                                   # one chunk each
    w.close()
    return path / f'{path.name}_0.mcap'


@pytest.fixture
def spill(monkeypatch):
    monkeypatch.setattr(mcap_file, 'SPOOL_BYTES', 4096)     # ~15 chunk indexes in memory


def test_thousands_of_chunks_read_back(tmp_path, spill):
    from mcap.reader import make_reader
    from mcap.records import Chunk
    from mcap.stream_reader import StreamReader
    f = _write(tmp_path / 'b', 3000)
    with open(f, 'rb') as fh:
        reader = make_reader(fh, validate_crcs=True)
        summary = reader.get_summary()
        assert summary.statistics.chunk_count == len(summary.chunk_indexes) == 3000
        times = [m.log_time for _, _, m in reader.iter_messages()]
        assert times == list(range(0, 15000 * 1_000_000, 1_000_000))
        for ci in summary.chunk_indexes[::499]:     # each index points at its chunk
            fh.seek(ci.chunk_start_offset)
            chunk = next(StreamReader(fh, skip_magic=True, emit_chunks=True).records)
            assert isinstance(chunk, Chunk) and chunk.message_start_time == \
                ci.message_start_time and ci.chunk_length == 9 + len(chunk.data) + 8 * 4 + 4 + 4
    data = f.read_bytes()
    # the footer: opcode, length, summary start, summary offset start, summary CRC, magic
    start, _, crc = struct.unpack('<QQI', data[-8 - 20:-8])
    assert crc == zlib.crc32(data[start:-8 - 4])


def test_memory_does_not_grow_with_the_chunks(tmp_path, spill):
    import tracemalloc
    _write(tmp_path / 'warm', 100)
    peaks = []
    for n in (1000, 4000):
        tracemalloc.start()
        _write(tmp_path / f'b{n}', n)
        peaks.append(tracemalloc.get_traced_memory()[1])
        tracemalloc.stop()
    # chunk indexes held as objects: ~1 kB each, 3 MB more for 3 000 more chunks
    assert peaks[1] - peaks[0] < 256 * 1024, peaks
