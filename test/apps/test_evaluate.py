"""``evaluate`` block by block (apps/evaluate.py): an algorithm's run on a bag fed in blocks
gives what a hand computation over the bag (read with the mcap library alone) gives, its
health messages once per change across block seams; the CLI's JSON, written from columns
streamed to temporary files, is byte for byte ``json.dumps`` of the whole payload; and its
memory does not grow with the bag."""

import json
import math
import struct

import numpy as np
import pytest

from bagmaker import f64, write_bag, write_long_bag
from cases import HOSTILE_ALGORITHMS
from servovalve_twin.outputs import write_json
from servovalve_twin.apps.evaluate import evaluate, run_to_json
from servovalve_twin.bag import reader
from servovalve_twin.cli import main
from servovalve_twin.prognostics import ERROR, OK, WARN, Algorithm, Health


class Swing(Algorithm):
    """Stateful (a running sum of XJ), with levels that go WARN, ERROR, OK and WARN again on
    the tick count, and outputs that collide with the JSON's own keys and are not finite."""

    inputs = ('xj', 'com')
    outputs = ('t', 'level', 'odd')

    def reset(self):
        self.k, self.total = 0, 0.0

    def step(self, t, u):
        self.total += u['xj']
        self.k += 1
        odd = math.nan if self.k % 97 == 0 else (math.inf if self.k % 89 == 0 else 1.0 / self.k)
        return {'t': self.total, 'level': u['com'] - u['xj'], 'odd': odd}

    def health(self):
        return Health(_level(self.k), f'tick {self.k}')


class Wide(Algorithm):
    """32 outputs a tick: what a run's held columns would cost shows in memory."""

    inputs = ('xj',)
    outputs = tuple(f'y{i}' for i in range(32))

    def step(self, t, u):
        return {k: u['xj'] * i for i, k in enumerate(self.outputs)}


def _level(k):
    return WARN if 300 <= k < 700 or k >= 1500 else ERROR if 700 <= k < 1000 else OK


def _recorded(bag):
    """(log time, value) of /xj and /com, read with the mcap library alone."""
    from mcap.reader import make_reader
    got = {'/xj': {}, '/com': {}}
    with open(next(bag.glob('*.mcap')), 'rb') as fh:
        for _, ch, m in make_reader(fh).iter_messages(topics=list(got), log_time_order=True):
            got[ch.topic].setdefault(m.log_time, struct.unpack('<d', m.data[4:])[0])
    ticks = sorted(set(got['/xj']) & set(got['/com']))
    return ticks, [got['/xj'][t] for t in ticks], [got['/com'][t] for t in ticks]


@pytest.fixture(scope='module')
def bag(tmp_path_factory):
    return write_long_bag(tmp_path_factory.mktemp('ev') / 'b', 2)


def test_blocks_give_the_hand_computed_run(bag):
    ticks, xj, com = _recorded(bag)
    # blocks of 37 messages: every block seam falls somewhere in the run, mid-level too
    run = evaluate(bag, Swing, block_messages=37)
    assert np.rint(run.t * 1e9).astype(np.int64).tolist() == ticks
    np.testing.assert_array_equal(run.outputs['t'], np.cumsum(xj))
    np.testing.assert_array_equal(run.outputs['level'], np.array(com) - np.array(xj))
    k = np.arange(1, len(ticks) + 1)
    assert run.level.tolist() == [_level(i) for i in k]
    # one message at each change to WARN or ERROR, none repeated at a seam
    assert run.messages == ['tick 300', 'tick 700', 'tick 1500']


def test_a_foreign_bag_gives_the_first_value_of_a_tick_that_has_two(tmp_path):
    """A bag from another tool (no provenance, no tick grid): /xj logged twice at some ticks,
    /com missing at others -- the ticks are those where both were logged, each input's value
    its first there, whatever the blocks."""
    F64 = 'std_msgs/msg/Float64'
    msgs = []
    for k in range(200):
        t = 1_000_000 * (k + 1)
        msgs.append(('/xj', F64, t, f64(float(k))))
        if k % 3 == 0:
            msgs.append(('/xj', F64, t, f64(-1.0)))         # a second value at that tick
        if k % 5:
            msgs.append(('/com', F64, t, f64(2.0 * k)))
    write_bag(tmp_path / 'b', msgs=msgs)
    run = evaluate(tmp_path / 'b', Swing, block_messages=7)
    ks = [k for k in range(200) if k % 5]
    assert np.rint(run.t * 1e9).astype(np.int64).tolist() == [1_000_000 * (k + 1) for k in ks]
    np.testing.assert_array_equal(run.outputs['level'], [2.0 * k - k for k in ks])


def test_the_json_is_byte_for_byte_the_whole_payloads(bag, tmp_path, monkeypatch, capsys):
    whole = evaluate(bag, Swing)
    write_json(tmp_path / 'whole.json', run_to_json(whole, bag))
    from servovalve_twin.apps import evaluate as module
    monkeypatch.setattr(reader, 'BLOCK_MESSAGES', 51)
    monkeypatch.setattr(module, 'COLUMN_VALUES', 100)     # columns written in 21 pieces
    assert main(['evaluate', str(bag), '--algorithm', 'test_evaluate:Swing',
                 '--json', str(tmp_path / 'streamed.json')]) == 0
    assert (tmp_path / 'streamed.json').read_bytes() == (tmp_path / 'whole.json').read_bytes()
    assert sorted(p.name for p in tmp_path.iterdir()) == ['streamed.json', 'whole.json']
    line = capsys.readouterr().out
    n_nan = sum(1 for i in range(1, len(whole.t) + 1) if i % 97 == 0 or i % 89 == 0)
    assert f'first WARN at {whole.t[299]:.3f} s, first ERROR at {whole.t[699]:.3f} s' in line
    assert f'peak odd 1 ({n_nan} ticks NaN or infinite, the first at {whole.t[88]:.3f} s)' \
        in line
    assert f'peak t {whole.outputs["t"].max():.6g}' in line


def test_a_run_without_ticks_or_outputs(bag, tmp_path, monkeypatch):
    """Empty columns are written as json writes them ([]) -- an algorithm whose input the
    bag never pairs with another refuses instead."""
    from servovalve_twin.apps.evaluate import Evaluation
    alg = Swing()
    ev = Evaluation(alg, 'x', tmp_path / 'e.json')
    ev.write_json()
    ev.close()
    head = dict(ev.payload_head(), t=[], outputs={k: [] for k in Swing.outputs}, level=[])
    assert (tmp_path / 'e.json').read_text() == json.dumps(head, indent=2) + '\n'


@pytest.mark.slow
def test_memory_does_not_grow_with_the_bag(tmp_path, monkeypatch):
    """``evaluate --json`` of bags of 4 and 16 s (4 004 and 16 016 ticks) with 32 outputs, read
    and written 1 000 values at a time: the peak of Python allocations the same within 0.5 MiB
    -- holding the run's blocks grows it by 3.7 MiB, the whole payload's lists by tens."""
    import tracemalloc
    from servovalve_twin.apps import evaluate as module
    monkeypatch.setattr(reader, 'BLOCK_MESSAGES', 1000)
    monkeypatch.setattr(module, 'COLUMN_VALUES', 1000)
    bags = {s: write_long_bag(tmp_path / f'b{s}', s) for s in (4, 16)}
    args = ['--algorithm', 'test_evaluate:Wide']
    assert main(['evaluate', str(bags[4]), *args, '--json', str(tmp_path / 'warm.json')]) == 0
    peaks = []
    for s, b in bags.items():
        tracemalloc.start()
        assert main(['evaluate', str(b), *args, '--json', str(tmp_path / f'{s}.json')]) == 0
        peaks.append(tracemalloc.get_traced_memory()[1])
        tracemalloc.stop()
    assert json.loads((tmp_path / '16.json').read_text())['ticks'] == 16 * 1001
    assert peaks[1] - peaks[0] < 0.5 * (1 << 20), peaks


def test_an_algorithm_that_blocks_is_stopped_by_the_watchdog(tmp_path, monkeypatch, capsys):
    """A step that blocks (a sleep of 10^6 s at t = 5 ms) held evaluate for ever; a module that
    blocks at import too. With the watchdog's limit at 0.5 s each ends in one line, exit 2."""
    from servovalve_twin.cli import main
    from servovalve_twin.prognostics import watchdog
    monkeypatch.setattr(watchdog, 'STEP_LIMIT_S', 0.5)
    (tmp_path / 'stuck_alg.py').write_text(HOSTILE_ALGORITHMS)
    (tmp_path / 'stuck_import.py').write_text('import time\ntime.sleep(1e6)\n')
    monkeypatch.syspath_prepend(str(tmp_path))
    assert main(['evaluate', '@paper_HD', '--algorithm', 'stuck_alg:Stuck']) == 2
    err = capsys.readouterr().err
    assert 'algorithm Stuck made no progress for 0.5 s' in err and err.count('\n') == 1, err
    assert main(['evaluate', '@paper_HD', '--algorithm', 'stuck_import:X']) == 2
    err = capsys.readouterr().err
    assert "'stuck_import:X': its import made no progress for 0.5 s" in err, err
    assert main(['evaluate', '@paper_HD', '--algorithm', 'stuck_alg:Exiting']) == 2
    err = capsys.readouterr().err
    assert 'called os._exit(0)' in err and err.count('\n') == 1, err
