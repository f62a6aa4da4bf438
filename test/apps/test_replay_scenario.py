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
