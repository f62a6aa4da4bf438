"""The one bag reader's contract: every command that takes a bag reads every storage and
layout the reader registers. The fixtures are one twin run (the packaged HD reference bag, cut
to 0.4 s) rewritten by ``bagmaker`` in each layout rosbag2 writes; adding a storage or layout
adds a fixture here, not a test. The expected values come from the original MCAP file read with
the ``mcap`` library's own reader, not through this package's storages."""

from __future__ import annotations

import json
import re
import shutil
import struct

import numpy as np
import pytest

from bagmaker import reference_messages, write_bag
from servovalve_twin.bag.reader import read_bag
from servovalve_twin.bag.storages import get_registered_readers
from servovalve_twin.cli import main
from servovalve_twin.config import reference_dir
from servovalve_twin.errors import BagError

END_NS = 400_000_000
REF = reference_dir() / 'paper_HD'

#: layout name -> bagmaker arguments; 'provenance' False: a foreign bag without one
LAYOUTS = {
    'mcap': dict(storage='mcap'),
    'mcap-zstd': dict(storage='mcap', compression='zstd'),
    'mcap-lz4': dict(storage='mcap', compression='lz4'),
    'mcap-split': dict(storage='mcap', split=3),
    'mcap-v4': dict(storage='mcap', version=4),
    'sqlite3': dict(storage='sqlite3'),
    'sqlite3-split': dict(storage='sqlite3', split=2),
    'sqlite3-v4': dict(storage='sqlite3', version=4, provenance=False),
    'foreign-mcap': dict(storage='mcap', provenance=False),
    # one actuator of several in a graph: its topics under /left (run --namespace left)
    'mcap-namespaced': dict(storage='mcap', namespace='/left'),
}


def _reference():
    """(messages as bagmaker takes them, provenance record, /xj values) from the packaged
    bag, read with the mcap library alone."""
    msgs, record = reference_messages(END_NS)
    xj = [struct.unpack('<d', d[4:12])[0] for t, _, _, d in msgs if t == '/xj']
    return msgs, record, np.array(xj)


@pytest.fixture(scope='module')
def layouts(tmp_path_factory):
    msgs, record, xj = _reference()
    root = tmp_path_factory.mktemp('layouts')
    out = {}
    for name, kw in LAYOUTS.items():
        kw = dict(kw)
        with_prov = kw.pop('provenance', True)
        ns = kw.pop('namespace', '')
        rec = dict(record, namespace=ns) if ns else record
        mine = [(t if t == '/clock' else ns + t, *rest) for t, *rest in msgs]
        write_bag(root / name, msgs=mine, provenance=rec if with_prov else None, **kw)
        out[name] = (root / name, with_prov)
    return out, msgs, xj


def test_every_registered_storage_has_a_fixture():
    assert get_registered_readers() == sorted({kw['storage'] for kw in LAYOUTS.values()})


@pytest.mark.parametrize('name', LAYOUTS)
def test_read_bag_reads_every_layout(layouts, name):
    bags, msgs, xj = layouts
    path, with_prov = bags[name]
    run = read_bag(path)
    np.testing.assert_array_equal(run.signals['xj'], xj)
    assert sum(run.topics.values()) == len(msgs)
    assert bool(run.provenance) == with_prov
    if with_prov:
        assert run.valve_model == 'HD' and run.control_period == 1e-3


@pytest.mark.parametrize('name', LAYOUTS)
def test_the_signal_blocks_are_read_bags_rows(layouts, name, monkeypatch):
    """Read in blocks of a few hundred messages (block ends at arbitrary messages, ticks and
    file seams), the rows put together are read_bag's, column for column, bit for bit."""
    from servovalve_twin.bag.reader import iter_signal_blocks
    bags, _, _ = layouts
    whole = read_bag(bags[name][0]).signals
    for size in (97, 500):
        blocks = [rows for _, rows in iter_signal_blocks(bags[name][0], block_messages=size)]
        assert len(blocks) > 3
        assert set(blocks[0]) == set(whole)
        for col, v in whole.items():
            np.testing.assert_array_equal(np.concatenate([b[col] for b in blocks]), v, col)


def test_a_tick_missing_at_a_block_seam_is_corruption(layouts, tmp_path):
    """One /xj message left out: read in blocks whose seams fall on every position around it,
    the gap is found every time (the tick check carries each topic's last tick across the
    seam), never a table short of a row."""
    from servovalve_twin.bag.reader import iter_signal_blocks
    _, msgs, _ = layouts
    _, record, _ = _reference()
    drop = [i for i, m in enumerate(msgs) if m[0] == '/xj'][40]
    kept = msgs[:drop] + msgs[drop + 1:]
    write_bag(tmp_path / 'gap', msgs=kept, provenance=record)
    # the first block ends at the log time of its last message: sizes whose first seam lies
    # between the ticks either side of the gap
    t_gap = msgs[drop][2]
    f64_times = [ns for _, typ, ns, _ in kept if typ == 'std_msgs/msg/Float64']
    sizes = [i + 1 for i, ns in enumerate(f64_times) if t_gap - 1_000_000 < ns <= t_gap + 1_000_000]
    assert len(sizes) > 10
    for size in sizes:
        with pytest.raises(BagError, match='not one message per control period'):
            for _ in iter_signal_blocks(tmp_path / 'gap', block_messages=size):
                pass


@pytest.mark.parametrize('name', ['mcap-split', 'sqlite3-split'])
def test_a_split_bag_is_merged_as_it_is_read(layouts, name, monkeypatch):
    """The files of a split bag are merged lazily: the first messages come out having pulled
    a few from each file, not every file whole (a bag's memory would grow with it); and in
    log-time order, ties in file order."""
    from servovalve_twin.bag.anybag import open_any_bag
    bags, msgs, _ = layouts
    bag = open_any_bag(bags[name][0])
    pulled = []
    real = bag.reader.messages

    def counting(f, *a, **k):
        for m in real(f, *a, **k):
            pulled.append(f)
            yield m
    monkeypatch.setattr(bag.reader, 'messages', counting)
    it = bag.messages()
    first = [next(it) for _ in range(5)]
    assert len(bag.files) > 1 and len(pulled) <= 5 + len(bag.files)
    rest = list(it)
    times = [t for _, t, _ in first + rest]
    assert times == sorted(times) and len(times) == len(msgs)


@pytest.mark.parametrize('name', LAYOUTS)
def test_compare_evaluate_diagnose_prognose_reindex(layouts, name, tmp_path, capsys):
    bags, msgs, xj = layouts
    path, with_prov = bags[name]
    # compare against the packaged original: the same rows, so every error is 0
    assert main(['compare', '@paper_HD', str(path), '--json', str(tmp_path / 'c.json')]) == 0
    errors = json.loads((tmp_path / 'c.json').read_text())['metrics']['all']
    assert errors['xj']['n'] == xj.size
    assert all(e['rms'] == 0 and e['max'] == 0 for e in errors.values()), errors
    # evaluate: one tick per recorded 1 ms row
    assert main(['evaluate', str(path), '--algorithm',
                 'servovalve_twin.prognostics.monitor:MonitorAlgorithm',
                 '--json', str(tmp_path / 'e.json')]) == 0
    assert json.loads((tmp_path / 'e.json').read_text())['ticks'] == xj.size
    # diagnose: a healthy unit; a bag without provenance does not say what the design was,
    # so it is unexplained -- until the user states it
    capsys.readouterr()
    assert main(['diagnose', str(path), '--faults', 'leakage_growth',
                 '--json', str(tmp_path / 'd.json')]) == 0
    err = capsys.readouterr().err
    assert ('no provenance record' in err) == (not with_prov), err
    verdict = json.loads((tmp_path / 'd.json').read_text())['fault']
    assert verdict == ('healthy' if with_prov else 'unexplained')
    if not with_prov:
        assert main(['diagnose', str(path), '--faults', 'leakage_growth', '--param', 'M=500',
                     '--json', str(tmp_path / 'd.json')]) == 0
        assert 'assumed the parameters given with --param' in capsys.readouterr().err
        assert json.loads((tmp_path / 'd.json').read_text())['fault'] == 'healthy'
    # prognose over three flights of it
    assert main(['prognose', str(path), str(path), str(path), '--threshold', 'leakage_growth',
                 '--json', str(tmp_path / 'p.json')]) == 0
    # reindex a copy: the same messages afterwards, nothing else left behind
    copy = tmp_path / 'copy'
    shutil.copytree(path, copy)
    (copy / 'metadata.yaml').unlink()
    assert main(['reindex', str(copy)]) == 0
    again = read_bag(copy)
    np.testing.assert_array_equal(again.signals['xj'], xj)
    assert sum(again.topics.values()) == len(msgs)
    assert bool(again.provenance) == (with_prov and 'sqlite3' not in name)


@pytest.mark.ros
@pytest.mark.parametrize('name', LAYOUTS)
def test_replay_play_and_replay_into(layouts, name, tmp_path, capsys, ros_context):
    from std_msgs.msg import Float64
    from servovalve_twin.testing import replay_into
    bags, msgs, xj = layouts
    path, with_prov = bags[name]
    assert main(['replay', str(path), '--out', str(tmp_path / 'r')]) == 0
    assert read_bag(tmp_path / 'r').valve_model == ('HD' if with_prov else 'C2')
    capsys.readouterr()
    assert main(['play', str(path), '--rate', '1000']) == 0
    assert f'play: done: {len(msgs)} messages' in capsys.readouterr().out
    # the user's node in the actuator's namespace (relative topic names, as the twin's nodes)
    node = ros_context and __import__('rclpy.node', fromlist=['Node']).Node(
        'probe', context=ros_context, namespace=LAYOUTS[name].get('namespace', '/'))
    seen = []
    node.create_subscription(Float64, 'xj', lambda m: seen.append(m.data), 10)
    try:
        replay_into(node, path)
    finally:
        node.destroy_node()
    np.testing.assert_array_equal(seen, xj)


def _crafted(tmp_path, name, edit_meta=None, record=None):
    """A copy of the twin's bag (MCAP) with its metadata.yaml or provenance edited."""
    import yaml as _yaml
    msgs, good, _ = _reference()
    d = tmp_path / name
    write_bag(d, msgs=msgs[:400], provenance=record if record is not None else good)
    if edit_meta is not None:
        meta = _yaml.safe_load((d / 'metadata.yaml').read_text())
        edit_meta(meta['rosbag2_bagfile_information'], d)
        (d / 'metadata.yaml').write_text(_yaml.safe_dump(meta))
    return d


def _bad_records():
    _, good, _ = _reference()
    yield 'cp', dict(good, control_period='fast')
    yield 'cp-tiny', dict(good, control_period='1e-300')
    yield 'cp-long', dict(good, control_period='5')
    yield 'params-list', dict(good, params='- 1\n- 2\n')
    yield 'params-text', dict(good, params='M: heavy\n')
    yield 'bad-yaml', dict(good, scenario='{unclosed: [')
    yield 'fault-no-at', dict(good, scenario=good['scenario'] + 'faults:\n- fault: leakage_growth\n'
                              '  severity: 2.0\n')
    yield 'windows-list', dict(good, scenario=good['scenario'].replace('windows:', 'windows: []\n'
                                                                       'old_windows:'))


def _bad_metadata():
    outside = lambda m, d: m.update(relative_file_paths=['../elsewhere.mcap'])   # noqa: E731
    twice = lambda m, d: m.update(relative_file_paths=m['relative_file_paths'] * 2)  # noqa
    absolute = lambda m, d: m.update(relative_file_paths=[str(REF / 'paper_HD_0.mcap')])  # noqa
    ints = lambda m, d: m.update(relative_file_paths=[1, 2])                   # noqa: E731
    files_int = lambda m, d: m.update(relative_file_paths=7)                    # noqa: E731
    topics_junk = lambda m, d: m.update(topics_with_message_count={'a': 1})     # noqa: E731
    yield from (('outside', outside), ('twice', twice), ('absolute', absolute), ('ints', ints),
                ('files-int', files_int))
    yield 'topics-junk', topics_junk           # not needed to read the data: read as if absent


@pytest.mark.parametrize('name,record', list(_bad_records()), ids=[n for n, _ in _bad_records()])
def test_a_malformed_provenance_record_is_one_line_for_every_command(tmp_path, capsys, name,
                                                                     record):
    d = _crafted(tmp_path, name, record=record)
    for args in (['compare', '@paper_HD', str(d)], ['evaluate', str(d), '--algorithm',
                 'servovalve_twin.prognostics.monitor:MonitorAlgorithm'],
                 ['diagnose', str(d), '--json', str(tmp_path / 'd.json')], ['replay', str(d)]):
        assert main(args) == 2, args
        err = capsys.readouterr().err
        assert err.count('\n') == 1, err
        assert 'provenance record' in err or 'its recorded' in err, err
        assert 'Traceback' not in err


@pytest.mark.parametrize('name,edit', list(_bad_metadata()), ids=[n for n, _ in _bad_metadata()])
def test_metadata_written_by_someone_else_cannot_point_outside_the_bag(tmp_path, capsys, name,
                                                                      edit):
    (tmp_path / 'elsewhere.mcap').write_bytes((next(REF.glob('*.mcap'))).read_bytes())
    d = _crafted(tmp_path, name, edit_meta=edit)
    code = main(['evaluate', str(d), '--algorithm',
                 'servovalve_twin.prognostics.monitor:MonitorAlgorithm',
                 '--json', str(tmp_path / 'e.json')])
    err = capsys.readouterr().err
    if name == 'topics-junk':
        assert code == 0 and json.loads((tmp_path / 'e.json').read_text())['ticks'] > 0
        return
    assert code == 2 and err.count('\n') == 1 and 'metadata.yaml' in err, err


def test_a_huge_or_deep_metadata_file_is_refused(tmp_path, capsys):
    d = _crafted(tmp_path, 'deep')
    (d / 'metadata.yaml').write_text('[' * 10000 + ']' * 10000)
    assert main(['compare', '@paper_HD', str(d)]) == 2
    assert 'not readable YAML' in capsys.readouterr().err
    with open(d / 'metadata.yaml', 'w') as fh:
        fh.truncate(17 * 2 ** 20)
    assert main(['compare', '@paper_HD', str(d)]) == 2
    assert 'MiB' in capsys.readouterr().err


@pytest.mark.parametrize('name', ['x_0.mcap', 'x_0.db3'])
def test_a_storage_file_that_is_a_fifo_is_refused_not_read(tmp_path, capsys, name):
    """A bag directory holding a FIFO named like a storage file: compare and evaluate blocked
    on it for ever (play for 18 min); now one line naming it, exit 2 -- and the FIFO is never
    opened (opening a FIFO for reading blocks until a writer comes)."""
    import os
    d = tmp_path / 'd'
    d.mkdir()
    os.mkfifo(d / name)
    for argv in (['compare', '@paper_HD', str(d)],
                 ['evaluate', str(d), '--algorithm',
                  'servovalve_twin.prognostics.monitor:MonitorAlgorithm']):
        assert main(argv) == 2
        err = capsys.readouterr().err
        assert f'{name} is not a regular file' in err and err.count('\n') == 1, err


def test_a_sqlite3_bag_is_read_without_writing_beside_it(layouts, tmp_path):
    """A rosbag2 sqlite3 bag in WAL journal mode, in a directory whose name needs quoting in
    a URI: read by the one reader, nothing appears beside it (mode=ro alone left -shm and
    -wal files in the user's bag), and what it holds is read."""
    import shutil
    import sqlite3
    bags, msgs, xj = layouts
    bag = tmp_path / 'my bag #1?'
    shutil.copytree(bags['sqlite3'][0], bag)
    for f in bag.glob('*.db3'):
        con = sqlite3.connect(f)
        assert con.execute('PRAGMA journal_mode=WAL').fetchone()[0] == 'wal'
        con.close()
    before = sorted(p.name for p in bag.iterdir())
    run = read_bag(bag)
    np.testing.assert_array_equal(run.signals['xj'], xj)
    assert sorted(p.name for p in bag.iterdir()) == before


_XJ = "(SELECT id FROM topics WHERE name = '/xj')"
SQLITE_DAMAGE = {
    # what was edited -> the SQL, and a fragment of the refusal
    'a timestamp off the tick grid': (
        f'UPDATE messages SET timestamp = timestamp + 1 WHERE id = (SELECT id FROM messages '
        f'WHERE topic_id = {_XJ} ORDER BY timestamp LIMIT 1 OFFSET 300)',
        '/xj is not one message per control period (1 ms) at 0.300000 s'),
    'a timestamp moved onto the next tick': (
        f'UPDATE messages SET timestamp = timestamp + 1000000 WHERE id = (SELECT id FROM '
        f'messages WHERE topic_id = {_XJ} ORDER BY timestamp LIMIT 1 OFFSET 300)',
        'is not one message per control period'),
    'a message cut short': (
        f'UPDATE messages SET data = substr(data, 1, 7) WHERE id = (SELECT id FROM messages '
        f'WHERE topic_id = {_XJ} ORDER BY timestamp LIMIT 1 OFFSET 300)',
        'its message on /xj at 0.300000 s: not a little-endian CDR'),
    'a negative timestamp': (
        f'UPDATE messages SET timestamp = -1000000 WHERE id = (SELECT id FROM messages '
        f'WHERE topic_id = {_XJ} ORDER BY timestamp LIMIT 1)',
        'timestamp -1000000, data of type bytes (expected a topic of the file, an integer '
        'time >= 0 and bytes)'),
    'a message deleted': (
        f'DELETE FROM messages WHERE id = (SELECT id FROM messages WHERE topic_id = {_XJ} '
        f'ORDER BY timestamp LIMIT 1 OFFSET 300)',
        'metadata.yaml counts'),
}


@pytest.mark.parametrize('sql, fragment', [
    ('UPDATE messages SET timestamp = (SELECT MAX(timestamp) FROM messages) - timestamp',
     'the message times run backwards against the order the messages were recorded in'),
    ("UPDATE topics SET type = 'this/msg/Foo' WHERE name = '/xj'", "this/msg/Foo"),
], ids=['every timestamp reversed', "/xj's type changed"])
def test_an_altered_sqlite3_bag_is_refused_by_every_command(layouts, tmp_path, capsys, sql,
                                                            fragment):
    """Every timestamp reversed was accepted by evaluate; /xj's type changed to an unknown one
    made compare drop XJ and compare the rest, rc 0. Both are one line, exit 2, now."""
    import shutil
    import sqlite3
    bags, _, _ = layouts
    bag = tmp_path / 'b'
    shutil.copytree(bags['sqlite3'][0], bag)
    (f,) = bag.glob('*.db3')
    con = sqlite3.connect(f)
    con.execute(sql)
    con.commit()
    con.close()
    with pytest.raises(BagError, match=re.escape(fragment)):
        read_bag(bag)
    for args in (['evaluate', str(bag), '--algorithm',
                  'servovalve_twin.prognostics.monitor:MonitorAlgorithm'],
                 ['compare', '@paper_HD', str(bag)]):
        assert main(args) == 2
        err = capsys.readouterr().err
        assert fragment in err and err.count('\n') == 1, err


@pytest.mark.parametrize('damage', SQLITE_DAMAGE)
def test_a_damaged_sqlite3_bag_is_refused_never_read_silently(layouts, tmp_path, capsys,
                                                               damage):
    """sqlite3 keeps no checksum: what can be checked is -- counts against metadata.yaml,
    one message per control period from 0 on each of the plant's signals, CDR that decodes.
    Each damage used to give a quietly different table (a tick dropped from every signal)."""
    import shutil
    import sqlite3
    bags, _, xj = layouts
    bag = tmp_path / 'b'
    shutil.copytree(bags['sqlite3'][0], bag)
    np.testing.assert_array_equal(read_bag(bag).signals['xj'], xj)     # intact: read
    sql, fragment = SQLITE_DAMAGE[damage]
    (f,) = bag.glob('*.db3')
    con = sqlite3.connect(f)
    assert con.execute(sql).rowcount == 1
    con.commit()
    con.close()
    with pytest.raises(BagError, match='corrupt') as info:
        read_bag(bag)
    assert fragment in str(info.value)
    for args in (['evaluate', str(bag), '--algorithm',
                  'servovalve_twin.prognostics.monitor:MonitorAlgorithm'],
                 ['compare', str(bag), str(bag)]):
        assert main(args) == 2
        err = capsys.readouterr().err
        assert fragment in err and err.count('\n') == 1, err


def test_an_mcap_bag_off_its_recorded_period_blames_the_record_not_sqlite3(tmp_path, capsys):
    """An MCAP bag whose provenance states a period its messages do not keep: its checksums
    hold, so the line names an edited record (it named sqlite3's missing checksums)."""
    _, good, _ = _reference()
    d = _crafted(tmp_path, 'cp-edited', record=dict(good, control_period='0.0007'))
    assert main(['compare', '@paper_HD', str(d)]) == 2
    err = capsys.readouterr().err
    assert 'not one message per control period (0.7 ms)' in err and \
        'an edited provenance record' in err and 'sqlite3' not in err, err


def test_every_command_on_a_sqlite3_bag_says_it_cannot_be_verified(layouts, tmp_path, capsys):
    """sqlite3 keeps no checksums: a command that read one says so in one note after its
    report; on MCAP (checksums verified) it says nothing."""
    bags, _, _ = layouts
    for storage, said in (('sqlite3', True), ('mcap', False)):
        bag = str(bags[storage][0])
        for argv in (['compare', '@paper_HD', bag],
                     ['evaluate', bag, '--algorithm',
                      'servovalve_twin.prognostics.monitor:MonitorAlgorithm'],
                     ['diagnose', bag, '--faults', 'leakage_growth', '--json',
                      str(tmp_path / 'd.json')]):
            assert main(argv) == 0, argv
            err = capsys.readouterr().err
            note = f'note: {bag} is a sqlite3 bag, which keeps no checksums: what was read ' \
                   'from it cannot be verified'
            assert (note in err) == said and err.count(note) <= 1, (argv, err)


def test_sqlite3_messages_come_in_time_order_not_insertion_order(layouts, tmp_path):
    """A recorder inserts each topic's messages as they arrive; here the rows were inserted
    topic by topic (each topic's times still rising with its rows, as a real bag's do). The
    reader gives them in log-time order, as from the bag it was made from."""
    import shutil
    import sqlite3
    from servovalve_twin.bag.anybag import open_any_bag
    bags, _, _ = layouts
    bag = tmp_path / 'b'
    shutil.copytree(bags['sqlite3'][0], bag)
    want = list(open_any_bag(bag).messages())
    (f,) = bag.glob('*.db3')
    con = sqlite3.connect(f)
    rows = con.execute('SELECT topic_id, timestamp, data FROM messages '
                       'ORDER BY topic_id DESC, timestamp').fetchall()
    con.execute('DELETE FROM messages')
    con.executemany('INSERT INTO messages (topic_id, timestamp, data) VALUES (?, ?, ?)', rows)
    con.commit()
    con.close()
    got = list(open_any_bag(bag).messages())
    assert [t for _, t, _ in got] == sorted(t for _, t, _ in got)
    assert sorted(got) == sorted(want) and len(got) == len(want)
