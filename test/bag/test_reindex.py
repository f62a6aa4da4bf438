"""reindex: a damaged chunk costs that chunk only, messages come back in log-time order, the
damaged original is kept, and memory does not grow with the bag. The bags are written here
with known messages, so what must survive is counted against what was written."""

from __future__ import annotations

import struct
import subprocess
import sys
import textwrap

import numpy as np
import pytest
from mcap.reader import make_reader

from servovalve_twin.bag.anybag import open_any_bag
from servovalve_twin.bag.reindex import reindex
from servovalve_twin.bag.writer import BagWriter
from servovalve_twin.cli import main

F64 = 'std_msgs/msg/Float64'


def _f64(v: float) -> bytes:
    return b'\x00\x01\x00\x00' + struct.pack('<d', v)


def _bag(path, times_ns, flush_ns=50_000_000):
    """One /value topic, message i = float(i) at times_ns[i]; chunks closed every flush_ns
    of log time."""
    w = BagWriter(path, flush_every_ns=flush_ns)
    w.add_topic('/value', F64)
    for i, t in enumerate(times_ns):
        w.write('/value', _f64(float(i)), int(t))
    w.close()
    return path / f'{path.name}_0.mcap'


def _chunks(file):
    with open(file, 'rb') as fh:
        return sorted(make_reader(fh).get_summary().chunk_indexes,
                      key=lambda c: c.chunk_start_offset)


def _values(path):
    return [(t, struct.unpack('<d', d[4:])[0]) for _, t, d in open_any_bag(path).messages()]


@pytest.mark.parametrize('where', ['data', 'length'])
def test_a_damaged_middle_chunk_costs_only_itself(tmp_path, where, capsys):
    times = np.arange(1000) * 1_000_000
    file = _bag(tmp_path / 'b', times)
    chunks = _chunks(file)
    assert len(chunks) >= 10
    victim = chunks[len(chunks) // 2]
    data = bytearray(file.read_bytes())
    # 'data': a byte inside the compressed records (the chunk CRC fails); 'length': the
    # record's own length field (the scan must find the next chunk by itself)
    pos = (victim.chunk_start_offset + victim.chunk_length - 20 if where == 'data'
           else victim.chunk_start_offset + 3)
    data[pos] ^= 0xFF
    file.write_bytes(bytes(data))
    lost = {i for i, t in enumerate(times)
            if victim.message_start_time <= t <= victim.message_end_time}
    assert 0 < len(lost) < 100
    assert main(['reindex', str(tmp_path / 'b')]) == 0
    err = capsys.readouterr().err
    assert 'skipped' in err and 'kept as b_0.mcap.damaged' in err, err
    # the file's own summary (intact at its end) indexed them: the report counts the lost
    assert f'its own index counts 1000 messages; {len(lost)} of them were not found' in err
    got = _values(tmp_path / 'b')
    assert got == [(int(t), float(i)) for i, t in enumerate(times) if i not in lost]
    # the damaged original is kept byte for byte
    assert (tmp_path / 'b' / 'b_0.mcap.damaged').read_bytes() == bytes(data)


def test_messages_come_back_in_log_time_order(tmp_path):
    # chunks written out of time order, and overlapping ones: the rebuilt file is sorted
    rng = np.random.default_rng(3)
    times = np.concatenate([np.arange(500, 1000), np.arange(0, 500),
                            rng.integers(0, 1000, 300)]) * 1_000_000
    file = _bag(tmp_path / 'b', times, flush_ns=1)     # a chunk whenever time advances
    (tmp_path / 'b' / 'metadata.yaml').unlink()
    meta = reindex(tmp_path / 'b')
    assert meta['message_count'] == times.size
    order = sorted(range(times.size), key=lambda i: (times[i], i))
    in_file = []
    with open(file, 'rb') as fh:
        for _, _, m in make_reader(fh).iter_messages(log_time_order=False):
            in_file.append((m.log_time, struct.unpack('<d', m.data[4:])[0]))
    assert [t for t, _ in in_file] == sorted(times.tolist())
    assert sorted(v for _, v in in_file) == sorted(float(i) for i in order)
    # equal log times keep the order they were written in (file order)
    same = [v for t, v in in_file if t == in_file[0][0]]
    assert same == sorted(same)


def test_a_bag_with_nothing_damaged_is_rebuilt_without_a_copy(tmp_path):
    times = np.arange(300) * 1_000_000
    _bag(tmp_path / 'b', times)
    (tmp_path / 'b' / 'metadata.yaml').unlink()
    meta = reindex(tmp_path / 'b')
    assert meta['report']['files'][0]['damaged'] == []
    assert sorted(p.name for p in (tmp_path / 'b').iterdir()) == ['b_0.mcap', 'metadata.yaml']
    assert _values(tmp_path / 'b') == [(int(t), float(i)) for i, t in enumerate(times)]


@pytest.mark.slow
def test_reindex_memory_does_not_grow_with_the_bag(tmp_path):
    """2 M messages: the earlier reindex held every message (0.86 kB each, 1.7 GB here)."""
    code = textwrap.dedent(f'''
        import resource, sys
        import numpy as np
        from servovalve_twin.bag.writer import BagWriter
        from servovalve_twin.bag.reindex import reindex
        n = 2_000_000
        w = BagWriter({str(tmp_path / 'big')!r})
        w.add_topic('/value', 'std_msgs/msg/Float64')
        t = np.arange(n, dtype=np.int64) * 1_000_000
        for k in range(0, n, 1000):                  # a chunk per simulated second
            w.write_float64('/value', t[k:k + 1000], np.arange(k, k + 1000, dtype=float))
            w.flush()
        w.close()
        before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
        meta = reindex({str(tmp_path / 'big')!r})
        after = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
        print(meta['message_count'], before // 1024, after // 1024)
    ''')
    r = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                       timeout=1800)
    assert r.returncode == 0, r.stderr[-2000:]
    count, before_mb, after_mb = (int(x) for x in r.stdout.split())
    print(f'2 M messages: peak RSS {before_mb} MiB after writing, {after_mb} MiB after reindex')
    assert count == 2_000_000
    assert after_mb - before_mb < 150


def test_a_metadata_yaml_of_another_bag_is_never_replaced(tmp_path, capsys):
    """`reindex dir/other.mcap` in a directory whose metadata.yaml describes another bag
    replaced it with one listing other.mcap alone: the other bag lost its description. Now
    one line, exit 2, the metadata.yaml as it was; the file's own bag (its metadata listing it
    alone) is rebuilt as before."""
    times = np.arange(200) * 1_000_000
    _bag(tmp_path / 'b', times)
    other = tmp_path / 'b' / 'other.mcap'
    other.write_bytes((tmp_path / 'b' / 'b_0.mcap').read_bytes())
    before = (tmp_path / 'b' / 'metadata.yaml').read_bytes()
    assert main(['reindex', str(other)]) == 2
    err = capsys.readouterr().err
    assert "describes a bag of ['b_0.mcap'], not of other.mcap alone" in err
    assert err.count('\n') == 1
    assert (tmp_path / 'b' / 'metadata.yaml').read_bytes() == before
    assert main(['reindex', str(tmp_path / 'b' / 'b_0.mcap')]) == 0
