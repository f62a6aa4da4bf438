"""The scenario a replay drives the twin with (apps/replay.py), read block by block: a
breakpoint at the first value and at every change of Com, FR and PSR, as a hand computation
over the mcap library's reading of the bag gives them, whatever the block seams."""

import struct

import pytest

from servovalve_twin.apps.replay import scenario_from_bag
from servovalve_twin.bag import reader
from servovalve_twin.bag.anybag import open_any_bag
from servovalve_twin.errors import BagError
from conftest import ROOT

HD_BAG = ROOT / 'servovalve_twin' / 'data' / 'paper_HD'


def _changes(topic):
    from mcap.reader import make_reader
    out, last = [], None
    with open(next(HD_BAG.glob('*.mcap')), 'rb') as fh:
        for _, _, m in make_reader(fh).iter_messages(topics=[topic], log_time_order=True):
            v = struct.unpack('<d', m.data[4:])[0]
            if v != last:
                out.append([m.log_time * 1e-9, v])
            last = v
    return out


@pytest.mark.parametrize('block', [None, 97])
def test_the_breakpoints_are_the_recorded_changes(monkeypatch, block):
    if block:
        monkeypatch.setattr(reader, 'BLOCK_MESSAGES', block)     # seams all through the run
    got = scenario_from_bag(open_any_bag(HD_BAG)).to_dict()
    for sig in ('com', 'fr', 'psr'):
        want = _changes(f'/{sig}')
        assert len(want) >= 2 and got[sig] == want, sig
    assert got['duration'] == 1.0


def test_a_bag_without_an_input_is_refused(tmp_path):
    from bagmaker import f64, write_bag
    F64 = 'std_msgs/msg/Float64'
    write_bag(tmp_path / 'b', msgs=[(f'/{s}', F64, 0, f64(1.0)) for s in ('com', 'fr')])
    with pytest.raises(BagError, match='has no /psr topic to replay'):
        scenario_from_bag(open_any_bag(tmp_path / 'b'))
    write_bag(tmp_path / 'c', msgs=[(f'/{s}', F64, 1000, f64(1.0)) for s in ('com', 'fr', 'psr')])
    with pytest.raises(BagError, match='/com does not start at t = 0'):
        scenario_from_bag(open_any_bag(tmp_path / 'c'))


def _values(bag, topic):
    from mcap.reader import make_reader
    with open(next(bag.glob('*.mcap')), 'rb') as fh:
        got = [(m.log_time, struct.unpack('<d', m.data[4:])[0])
               for _, _, m in make_reader(fh).iter_messages(topics=[topic], log_time_order=True)]
    return [t for t, _ in got], [v for _, v in got]


def test_a_twin_bag_replays_its_recorded_scenario(tmp_path):
    """@paper_HD replays the paper scenario as recorded; cut at 0.4 s (a stopped run) it
    replays the scenario up to there; one /com value edited, the recorded values instead."""
    import numpy as np
    from bagmaker import f64, reference_messages, write_bag
    from servovalve_twin.apps.replay import replay_scenario
    bag = open_any_bag(HD_BAG)
    scn = replay_scenario(bag)
    recorded = bag.provenance.scenario
    assert scn.to_dict()['com'] == recorded['com'] and scn.duration == 1.0
    assert scn.name == 'replay of paper_HD'
    for i, sig in enumerate(('com', 'fr', 'psr')):
        t, v = _values(HD_BAG, f'/{sig}')
        assert scn.inputs(np.array(t, dtype=np.int64))[i].tolist() == v
    msgs, record = reference_messages(400_000_000)
    write_bag(tmp_path / 'cut', msgs=msgs, provenance=record)
    cut = replay_scenario(open_any_bag(tmp_path / 'cut')).to_dict()
    assert cut['duration'] == 0.4
    assert cut['com'] == [p for p in recorded['com'] if p[0] <= 0.4]
    edited = [(tp, ty, t, f64(0.005) if tp == '/com' and t == 250_000_000 else d)
              for tp, ty, t, d in msgs]
    write_bag(tmp_path / 'edited', msgs=edited, provenance=record)
    got = replay_scenario(open_any_bag(tmp_path / 'edited')).to_dict()
    assert [0.25, 0.005] in got['com'] and got['com'] == _steps(tmp_path / 'edited', '/com')


def _steps(bag, topic):
    out, last = [], None
    for t, v in zip(*_values(bag, topic)):
        if v != last:
            out.append([t * 1e-9, v])
        last = v
    return out


def test_an_input_with_too_many_steps_is_refused(tmp_path, monkeypatch):
    from bagmaker import f64, write_bag
    from servovalve_twin.apps import replay
    monkeypatch.setattr(replay, 'MAX_BREAKPOINTS', 50)
    F64 = 'std_msgs/msg/Float64'
    msgs = [(f'/{s}', F64, k * 1_000_000, f64(float(k) if s == 'com' else 1.0))
            for k in range(100) for s in ('com', 'fr', 'psr')]
    write_bag(tmp_path / 'b', msgs=msgs)
    with pytest.raises(BagError, match='/com changes at more than 50 ticks'):
        scenario_from_bag(open_any_bag(tmp_path / 'b'))
