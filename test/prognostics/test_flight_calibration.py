"""servovalve_twin.prognostics.flight_calibration: diagnosis calibrated on the flight and the
design at hand -- the cache key, the units' seeds, the verdict floor from healthy units, resuming
an interrupted calibration, and refusing a cache entry it cannot trust."""

from __future__ import annotations

import json
import math

import pytest

from servovalve_twin.config import load_scenario
from servovalve_twin.errors import TwinError
from servovalve_twin.physics.faults import FAULTS
from servovalve_twin.physics.params import DEFAULTS
from servovalve_twin.prognostics import flight_calibration as fc
from servovalve_twin.prognostics import rules
from servovalve_twin.prognostics.calibration import calibration_for
from servovalve_twin.prognostics.calibration_set import to_g

FLIGHT = {'duration': 0.3, 'com': [[0.0, 0.0], [0.05, 0.02]], 'fr': [[0.0, 0.0], [0.1, 3000.0]],
          'psr': [[0.0, 2.0e7]]}


def test_the_key_follows_what_the_flight_and_design_are():
    """Another input, design parameter (HD's or not), model, free nuisance, control period or
    alpha is another calibration; the scenario's name or windows are not."""
    base = fc.flight_key(FLIGHT, DEFAULTS, 'SQ', ['M', 'CJ'], 1e-3)
    assert base == fc.flight_key(dict(FLIGHT, name='x', windows={'a': [0, 0.1]}), DEFAULTS,
                                 'SQ', ['CJ', 'M'], 1e-3)
    others = [fc.flight_key(dict(FLIGHT, duration=0.4), DEFAULTS, 'SQ', ['M', 'CJ'], 1e-3),
              fc.flight_key(dict(FLIGHT, fr=[[0.0, 0.0], [0.1, 3001.0]]), DEFAULTS, 'SQ',
                            ['M', 'CJ'], 1e-3),
              fc.flight_key(FLIGHT, DEFAULTS.replace(M=900.0), 'SQ', ['M', 'CJ'], 1e-3),
              fc.flight_key(FLIGHT, DEFAULTS.replace(c=1e-5), 'SQ', ['M', 'CJ'], 1e-3),
              fc.flight_key(FLIGHT, DEFAULTS, 'C2', ['M', 'CJ'], 1e-3),
              fc.flight_key(FLIGHT, DEFAULTS, 'SQ', ['M'], 1e-3),
              fc.flight_key(FLIGHT, DEFAULTS, 'SQ', ['M', 'CJ'], 2e-3),
              fc.flight_key(FLIGHT, DEFAULTS, 'SQ', ['M', 'CJ'], 1e-3, alpha=0.05)]
    assert len({base, *others}) == len(others) + 1


def test_a_unit_s_seed_is_its_own():
    """Seeds from (seed, fault, level, replicate) alone: adding a fault or units re-seeds no
    unit (today's every unit's seed was seed*1_000_003 + its index)."""
    few = fc.jobs(['leakage_growth'], 2, 7)
    more = fc.jobs(['supply_loss', 'leakage_growth'], 3, 7)
    assert set(few) <= set(more)
    assert len({j[3] for j in more}) == len(more)
    assert fc.unit_seed(7, 'leakage_growth', 0.3, 0) != fc.unit_seed(8, 'leakage_growth', 0.3, 0)
    # healthy units: twice the units per level
    assert sum(1 for j in more if j[0] is None) == 2 * 3 * 3


def _healthy(best):
    return dict(fault=None, truth=None, named=None, rms=1.0, scenario='own', best=best)


def test_the_verdict_floor_is_the_largest_size_a_healthy_unit_would_be_named_with():
    """Three healthy units: named (without a floor) a leak 0.1 of the way, a gain loss 0.25,
    nothing: the floor is 0.25 of the way, for every fault, in its coordinate; a run beyond it
    is named, one at it is not."""
    recs = [_healthy(['leakage_growth', 0.1]), _healthy(['torque_motor_gain_loss', 0.25]),
            _healthy(None)]
    assert fc.verdict_fraction(recs) == 0.25
    assert fc.verdict_fraction([_healthy(None)]) == 0.0
    with pytest.raises(TwinError, match='needs healthy units'):
        fc.verdict_fraction([dict(fault='leakage_growth')])
    cal = {'verdict_fraction': 0.25}
    leak_at = 10 ** 0.25                          # a leak multiplier: g = log10
    assert rules.fraction('leakage_growth', leak_at) == pytest.approx(0.25)
    assert rules.above_floor(cal, 'leakage_growth', leak_at * 1.001) is True
    assert rules.above_floor(cal, 'leakage_growth', leak_at / 1.001) is False
    assert rules.above_floor(None, 'leakage_growth', 5.0) is None
    g = to_g('supply_loss', 0.3 * 0.25)
    assert abs(g) == pytest.approx(0.25 * abs(to_g('supply_loss', FAULTS['supply_loss'].demo)))


def _leak(level, best):
    return dict(fault='leakage_growth', level=level, truth=1.0, named=None, rms=1.0,
                scenario='own', best=best)


def test_a_fault_is_revealed_from_the_lowest_level_all_its_units_above_were_named_at():
    """The detection limit: walked down from the alarm value, a level counts only if every
    unit of it was named the fault beyond the floor; one miss ends the walk (a level named
    below a miss is not a limit); a unit named another fault, or the fault at or under the
    floor, is a miss; none at the alarm value: not revealed (None)."""
    ok, floor = ['leakage_growth', 0.5], 0.2
    recs = [_leak(q, ok) for q in (0.3, 0.6, 1.0) for _ in range(3)]
    assert fc.revealed_from(recs, 'leakage_growth', floor) == 0.3
    assert fc.revealed_from(recs + [_leak(0.3, None)], 'leakage_growth', floor) == 0.6
    assert fc.revealed_from(recs + [_leak(0.6, ['supply_loss', 0.9])], 'leakage_growth',
                            floor) == 1.0
    assert fc.revealed_from(recs + [_leak(0.6, ['leakage_growth', 0.2])], 'leakage_growth',
                            floor) == 1.0
    assert fc.revealed_from(recs + [_leak(1.0, None)], 'leakage_growth', floor) is None
    assert fc.revealed_from(recs, 'supply_loss', floor) is None
    # in the entry (from the records' fitted severities: a leak of 10^x is x of the way; no
    # unit has an estimate, so no bias is taken off): as a severity, None where not revealed
    healthy = [_healthy(['leakage_growth', 10 ** floor])]
    fitted = [_leak(q, ['leakage_growth', 10 ** 0.5]) for q in (0.3, 0.6, 1.0) for _ in range(3)]
    cal = fc.fit(healthy + fitted + [_leak(0.3, None)], ['leakage_growth', 'supply_loss'])
    assert cal['verdict_fraction'] == pytest.approx(floor)
    assert cal['revealed_from'] == {'leakage_growth': pytest.approx(10 ** 0.6),
                                    'supply_loss': None}


def test_the_verdict_uses_the_flight_s_floor():
    """diagnose's verdict rule with a flight calibration: the best-scoring fault is named only
    beyond the flight's floor (a leak of 0.3 of the way under a floor of 0.35: healthy; under
    0.25: named) -- not at the fixed 20 % of the way."""
    from types import SimpleNamespace
    from servovalve_twin.prognostics.diagnosis import _verdict_candidate
    healthy = SimpleNamespace(fault='healthy', faults=(), severities=(), score=0.0)
    leak = SimpleNamespace(fault='leakage_growth', faults=('leakage_growth',),
                           severities=(10 ** 0.3,), score=-50.0)
    ranked = [leak, healthy]
    by_name = {c.fault: c for c in ranked}
    assert _verdict_candidate(ranked, by_name, {'verdict_fraction': 0.35}, 'own') is healthy
    assert _verdict_candidate(ranked, by_name, {'verdict_fraction': 0.25}, 'own') is leak
    leak.severities = (10 ** 0.15,)               # below the fixed floor (0.2), above 0.1
    assert _verdict_candidate(ranked, by_name, None, None) is healthy
    assert _verdict_candidate(ranked, by_name, {'verdict_fraction': 0.1}, 'own') is leak


def test_the_floor_and_the_verdict_test_the_size_the_verdict_states():
    """A flight whose own units read a gain loss 0.1 high in ``g`` (of 0.7): a healthy unit
    fitted at 0.14 (g 0.2) is sized 0.1 of the way for the floor, and a run fitted at 0.05
    (stated 0.0, the bias taking it past healthy) is never named, even over a floor of 0; one
    fitted at 0.14 is named over a floor of 0.05 and not over 0.12 (its fitted 0.2 would be)."""
    from types import SimpleNamespace
    from servovalve_twin.prognostics.diagnosis import _verdict_candidate
    own = {'torque_motor_gain_loss': dict(bias=0.1, sigma=0.01, units=30)}
    cal = {'faults': {}, 'by_scenario': {'own': own}}
    sized = fc.stated_sizes([_healthy(['torque_motor_gain_loss', 0.14]), _healthy(None)], cal)
    assert sized[0]['best'] == ['torque_motor_gain_loss', pytest.approx(0.1)]
    assert sized[1]['best'] is None
    assert fc.verdict_fraction(sized) == pytest.approx(0.1)
    healthy = SimpleNamespace(fault='healthy', faults=(), severities=(), score=0.0)
    loss = SimpleNamespace(fault='torque_motor_gain_loss', faults=('torque_motor_gain_loss',),
                           severities=(0.05,), score=-50.0)
    ranked = [loss, healthy]
    by_name = {c.fault: c for c in ranked}
    assert _verdict_candidate(ranked, by_name, dict(cal, verdict_fraction=0.0), 'own') is healthy
    loss.severities = (0.14,)
    assert _verdict_candidate(ranked, by_name, dict(cal, verdict_fraction=0.05), 'own') is loss
    assert _verdict_candidate(ranked, by_name, dict(cal, verdict_fraction=0.12), 'own') is healthy


def _fake_unit(calls):
    def run_unit(job, scenario, design, model, free, control_period, faults):
        calls.append(job)
        fault, q, r, seed = job
        if fault is None:
            return dict(id=fc._job_id(job), fault=None, level=0.0, truth=None, scenario='own',
                        named=None, rms=1.0, best=['null_bias', -0.005 * 0.01 * (r + 1)])
        truth = 1.0 + q if fault == 'leakage_growth' else q * 0.1
        return dict(id=fc._job_id(job), fault=fault, level=q, truth=truth, scenario='own',
                    named=fault, rms=1.0, best=None, estimate=truth * 1.01, se=0.01)
    return run_unit


def test_an_interrupted_calibration_resumes_and_is_cached(tmp_path, monkeypatch):
    """Ctrl-C after 5 units: they are kept (a partial file); the rerun runs only the others,
    then the entry is cached and a third call runs nothing. The entry states the floor (the
    fake healthy units' largest null bias, 0.06 of the way to -5 mA, less the packaged pooled
    bias the verdict would take off: no unit of its own) and its own key."""
    monkeypatch.setenv(fc.CACHE_ENV, str(tmp_path))
    calls = []
    fake = _fake_unit(calls)

    def stopping(*a):
        if len(calls) == 5:
            raise KeyboardInterrupt
        return fake(*a)
    monkeypatch.setattr(fc, 'run_unit', stopping)
    kw = dict(faults=['leakage_growth'], units=1, workers=1)
    with pytest.raises(KeyboardInterrupt):
        fc.calibrate_flight(FLIGHT, DEFAULTS, **kw)
    assert len(calls) == 5
    partial = list((tmp_path / 'diagnosis').glob('*.partial.jsonl'))
    assert len(partial) == 1 and len(partial[0].read_text().splitlines()) == 5
    monkeypatch.setattr(fc, 'run_unit', fake)
    cal, path = fc.calibrate_flight(FLIGHT, DEFAULTS, **kw)
    total = len(fc.jobs(['leakage_growth'], 1, 0))
    assert len(calls) == total                  # 5 before, the rest now: none twice
    pooled = calibration_for('SQ', [])['faults']['null_bias']['bias']
    assert cal['verdict_fraction'] == pytest.approx(abs(-0.06 - pooled))
    assert cal['healthy_units'] == 6
    assert json.loads(path.read_text())['about']['key'] == path.stem
    assert not partial[0].exists()
    fc.calibrate_flight(FLIGHT, DEFAULTS, **kw)
    assert len(calls) == total


def test_a_cache_entry_it_cannot_trust_is_named(tmp_path, monkeypatch):
    monkeypatch.setenv(fc.CACHE_ENV, str(tmp_path))
    key = fc.flight_key(FLIGHT, DEFAULTS, 'SQ', [], 1e-3)
    path = fc.entry_path(key)
    path.parent.mkdir(parents=True)
    path.write_text('{"about": {"version": 0}}')
    with pytest.raises(TwinError, match='another version'):
        fc.cached(key)
    path.write_text('{"about": ')
    with pytest.raises(TwinError, match='not a flight calibration'):
        fc.cached(key)
    path.unlink()
    assert fc.cached(key) is None


@pytest.mark.parametrize('args, fragment', [
    (['nope.yaml'], 'cannot read scenario file'),
    (['paper', '--units', '0'], 'units must be 1 to 100'),
    (['paper', '--workers', '0'], '--workers must be >= 1'),
    (['paper', '--seed', '-1'], '--seed must be an integer'),
    (['paper', '--param', 'c=-1'], 'c = -1.0'),
])
def test_bad_input_is_one_line(tmp_path, monkeypatch, capsys, args, fragment):
    from servovalve_twin.cli import main
    monkeypatch.setenv(fc.CACHE_ENV, str(tmp_path / 'cache'))
    monkeypatch.chdir(tmp_path)
    assert main(['calibrate-diagnosis', *args]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert fragment in err[-1] and 'Traceback' not in '\n'.join(err), err
    assert not (tmp_path / 'cache').exists() or not list((tmp_path / 'cache').rglob('*.json'))


@pytest.mark.slow
def test_a_flight_calibration_is_found_by_diagnose(tmp_path, monkeypatch):
    """A 0.3 s flight of its own calibrated on demand (1 unit per fault and level, 6 healthy):
    diagnose of a healthy HD unit's bag of that flight applies it -- the JSON says so, with
    the floor it stands on -- and without it says that none exists."""
    from servovalve_twin.apps.diagnose import flight_calibration_of
    monkeypatch.setenv(fc.CACHE_ENV, str(tmp_path))
    scn = load_scenario(FLIGHT)
    cal, path = fc.calibrate_flight(scn.to_dict(), DEFAULTS, free=('M', 'CJ'), units=1,
                                    workers=2)
    assert cal['healthy_units'] == 6 and 0 <= cal['verdict_fraction'] < 1
    assert set(cal['healthy_floor']) >= {'leakage_growth', 'supply_loss'}
    assert math.isfinite(cal['healthy_floor']['leakage_growth'])
    from types import SimpleNamespace
    prov = SimpleNamespace(scenario=scn.to_dict(), scenario_object=lambda: scn)
    run = SimpleNamespace(provenance=prov)
    assert flight_calibration_of(run, DEFAULTS, 'SQ', ('M', 'CJ'), 1e-3) == cal
    assert flight_calibration_of(run, DEFAULTS, 'SQ', (), 1e-3) is None


@pytest.mark.slow
def test_a_calibration_on_a_dask_cluster_is_the_local_one(tmp_path, monkeypatch):
    """The units on a cluster of two worker processes: the same entry, to the bit, as on
    local processes (whatever order they finish in)."""
    import distributed
    kw = dict(faults=['leakage_growth'], units=1)
    monkeypatch.setenv(fc.CACHE_ENV, str(tmp_path / 'local'))
    local, _ = fc.calibrate_flight(FLIGHT, DEFAULTS, workers=2, **kw)
    monkeypatch.setenv(fc.CACHE_ENV, str(tmp_path / 'cluster'))
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                  dashboard_address=None) as cluster:
        remote, _ = fc.calibrate_flight(FLIGHT, DEFAULTS, scheduler=cluster.scheduler_address,
                                        **kw)
    assert json.dumps(remote, sort_keys=True) == json.dumps(local, sort_keys=True)
    assert remote['healthy_units'] == 6
