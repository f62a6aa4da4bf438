"""servovalve_twin.apps.diagnose: a bag diagnosed over a window holds only the rows up to its
end -- the same diagnosis as from the whole table, in memory that does not grow with the bag."""

from __future__ import annotations

import json

import pytest

from bagmaker import write_long_bag
from servovalve_twin.apps.diagnose import calibration_scenario, diagnose_bag
from servovalve_twin.apps.replay import bag_params
from servovalve_twin.bag import reader
from servovalve_twin.bag.reader import read_bag, read_bag_until
from servovalve_twin.prognostics.diagnosis import diagnose

WINDOW = (0.2, 0.6)


def test_a_window_is_diagnosed_from_the_rows_up_to_its_end(tmp_path):
    """Rows kept up to 0.6 s of a 3 s bag: exactly the whole table's first rows, and the
    diagnosis over 0.2-0.6 s the whole table's, JSON for JSON."""
    bag = write_long_bag(tmp_path / 'b', 3)
    whole = read_bag(bag)
    part = read_bag_until(bag, WINDOW[1])
    assert part.signals['t'][-1] == pytest.approx(WINDOW[1])
    n = len(part.signals['t'])
    for col, v in whole.signals.items():
        assert part.signals[col].tobytes() == v[:n].tobytes(), col
    d = diagnose_bag(bag, faults=['leakage_growth', 'supply_loss'], window=WINDOW)
    want = diagnose(whole.signals, bag_params(whole), control_period=1e-3, model='SQ',
                    faults=['leakage_growth', 'supply_loss'], window=WINDOW,
                    model_form=True, scenario=calibration_scenario(whole.provenance))
    assert json.dumps(d.to_json(), sort_keys=True) == json.dumps(want.to_json(), sort_keys=True)


@pytest.mark.slow
def test_the_memory_of_a_windowed_read_does_not_grow_with_the_bag(tmp_path, monkeypatch):
    """The rows up to 1 s of a 4 s and of a 16 s bag, read in blocks of 5 000 messages: the
    peak of Python allocations the same within 1.5 MiB (read_bag holds 16 bytes per message
    and the whole table: megabytes more)."""
    import tracemalloc
    monkeypatch.setattr(reader, 'BLOCK_MESSAGES', 5000)
    bags = {s: write_long_bag(tmp_path / f'b{s}', s) for s in (4, 16)}
    read_bag_until(bags[4], 1.0)
    peaks = []
    for s, bag in bags.items():
        tracemalloc.start()
        got = read_bag_until(bag, 1.0)
        peaks.append(tracemalloc.get_traced_memory()[1])
        tracemalloc.stop()
        assert len(got.signals['t']) == 1001
    assert peaks[1] - peaks[0] < 1.5 * (1 << 20), peaks


def test_a_fit_ending_past_the_limit_is_refused_before_anything_is_read(tmp_path, monkeypatch,
                                                                         capsys):
    """The model runs from t = 0 to the window's end: a bag (or a window) ending later than
    MAX_FIT_END_S is one line and exit 2 -- without reading the messages (a 4 GB bag must not
    be read for minutes to be refused) -- and a window ending within it still diagnoses."""
    from servovalve_twin.apps import diagnose as module
    from servovalve_twin.cli import main
    bag = write_long_bag(tmp_path / 'b', 4)                  # rows up to 4.003 s
    monkeypatch.setattr(module, 'MAX_FIT_END_S', 3.0)
    monkeypatch.setattr(reader, 'iter_float64_blocks', None)   # any read of messages fails
    out = tmp_path / 'd.json'
    for extra in ([], ['--window', '2.5:3.5']):
        assert main(['diagnose', str(bag), '--json', str(out), *extra]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and 'at most 3 s' in err[0] and '--window T0:T1' in err[0], err
        assert not out.exists()
    monkeypatch.undo()
    monkeypatch.setattr(module, 'MAX_FIT_END_S', 3.0)
    assert main(['diagnose', str(bag), '--json', str(out), '--window', '0.2:0.8',
                 '--faults', 'leakage_growth']) == 0
    assert json.loads(out.read_text())['window'] == [0.2, 0.8]


def test_a_bags_stale_gains_give_way_to_its_designs_calibration():
    """A bag of another design (more clearance) that recorded the default design's XSS and
    GPQ: the design's own calibration is used and one line says so; constants the user gives
    are kept; constants that agree say nothing."""
    from servovalve_twin.apps.diagnose import _calibrated_constants
    from servovalve_twin.physics.params import DEFAULTS
    from servovalve_twin.physics.valves.calibration import calibrate
    other = DEFAULTS.replace(c=1.0e-5)
    cal = calibrate(other)
    recorded = other.replace(XSS=DEFAULTS.xss, GPQ=DEFAULTS.gpq)
    design, line = _calibrated_constants(recorded, {})
    assert (design.xss, design.gpq) == (cal['XSS'], cal['GPQ'])
    assert line.startswith('the bag records XSS = 1.73945e-05 m') and '2.5927' in line
    design, line = _calibrated_constants(recorded, {'XSS': DEFAULTS.xss})
    assert design is recorded and line is None
    design, line = _calibrated_constants(other.replace(XSS=cal['XSS'], GPQ=cal['GPQ']), {})
    assert line is None and design.xss == cal['XSS']


def _fleet(tmp_path, *extra):
    """diagnose of two bags and one that is no bag, as a fleet, and of one bag alone."""
    from servovalve_twin.cli import main
    assert main(['diagnose', '@paper_HD', '--faults', 'leakage_growth,supply_loss',
                 '--json', str(tmp_path / 'one.json')]) == 0
    code = main(['diagnose', '@paper_HD', str(tmp_path / 'nosuch'), '@paper_HD', '--faults',
                 'leakage_growth,supply_loss', '--json', str(tmp_path / 'fleet'), *extra])
    return code, json.loads((tmp_path / 'one.json').read_text())


def _check_fleet(tmp_path, code, one):
    out = tmp_path / 'fleet'
    assert code == 2                                   # one bag's error is the fleet's code
    summary = json.loads((out / 'summary.json').read_text())
    assert summary['bags'] == 3 and [r.get('json') for r in summary['diagnosed']] == [
        '000_paper_HD.json', None, '002_paper_HD.json']
    assert 'no bag at' in summary['diagnosed'][1]['error']
    for name in ('000_paper_HD.json', '002_paper_HD.json'):
        assert json.loads((out / name).read_text()) == one     # as diagnosed alone


def test_a_fleet_of_bags_is_diagnosed_each_as_alone(tmp_path, capsys):
    """diagnose BAG1 BAG2 ... --json DIR on two processes: one JSON per bag, each the one
    diagnose gives that bag alone; a bag that is none is its own error line, the others go
    on; summary.json in the bags' order."""
    code, one = _fleet(tmp_path, '--workers', '2')
    _check_fleet(tmp_path, code, one)
    err = capsys.readouterr().err
    assert 'nosuch: error: no bag at' in err


@pytest.mark.slow
def test_a_fleet_of_bags_on_a_dask_cluster(tmp_path):
    import distributed
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                  dashboard_address=None) as cluster:
        code, one = _fleet(tmp_path, '--scheduler', cluster.scheduler_address)
    _check_fleet(tmp_path, code, one)
