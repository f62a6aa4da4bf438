"""physics/fleet.py: simulate_many runs N units in one compiled call, each unit's rows those
simulate() gives it alone -- every column, bit for bit -- whatever its neighbours are: other
parameters, a fault scheduled mid-run, a unit whose valve model fails."""

import numpy as np
import pytest

from servovalve_twin.config import load_scenario
from servovalve_twin.errors import ModelError, ParameterError
from servovalve_twin.physics.fleet import simulate_many
from servovalve_twin.physics.params import DEFAULTS
from servovalve_twin.physics.simulate import simulate

from cases import short, with_fault

LEAK = {'at': 0.05, 'fault': 'leakage_growth', 'severity': 4.0}
GAIN = {'at': 0.12, 'fault': 'torque_motor_gain_loss', 'severity': 0.3}


@pytest.mark.parametrize('model', ['C2', 'SQ', 'HD'])
def test_each_unit_of_a_fleet_is_its_own_simulate(model):
    """Three units unlike each other (a heavier jack, a leak from 0.05 s, a gain loss from
    0.12 s on a different CJ), from an offset jack position, a 1 ms ECU: each equals its own
    simulate() in every column. A unit that read its neighbour's state, parameters or fault
    segment, or a fleet that shared one valve state, would differ."""
    scn = short()
    units = [DEFAULTS.replace(M=550.0), DEFAULTS, DEFAULTS.replace(CJ=DEFAULTS.CJ * 1.3)]
    faults = [(), (LEAK,), (GAIN,)]
    runs = simulate_many(model, scn, units, ecu_period=1e-3, faults=faults,
                         initial={'xj': 0.002})
    for u, (p, f) in enumerate(zip(units, faults)):
        ref = simulate(model, dict(scn, faults=list(f)), params=p, ecu_period=1e-3,
                       initial={'xj': 0.002})
        assert runs[u].columns == ref.columns
        for c in ref.columns:
            assert np.array_equal(runs[u][c], ref[c], equal_nan=True), (model, u, c)
    assert not np.array_equal(runs[0]['xj'], runs[1]['xj'])


def test_the_scenario_s_own_faults_and_a_continuous_ecu():
    """Without ``faults`` every unit flies the scenario's own (here a leak) and, without an
    ECU period, a continuous ECU, as simulate() does."""
    scn = with_fault(short(), 'leakage_growth', 3.0, at=0.1)
    units = [DEFAULTS, DEFAULTS.replace(M=450.0)]
    runs = simulate_many('C2', scn, units)
    for u, p in enumerate(units):
        assert np.array_equal(runs[u]['p12'], simulate('C2', scn, params=p)['p12'])


def test_a_failing_unit_stops_alone():
    """A unit whose HD solve cannot converge (its leakage coefficient NaN: a corrupted
    parameter set, which validation would refuse, forced in) fails as it does alone; its
    neighbours still equal their own runs, to the end of a flight longer than one chunk of
    steps (a failure that stopped every unit at the chunk's end passed a shorter flight).
    'raise' names the unit; 'none' gives None."""
    from servovalve_twin.physics.simulate import CHUNK_STEPS
    scn = load_scenario('paper')
    assert scn.duration_ns > 1.5 * CHUNK_STEPS * DEFAULTS.DT * 1e9
    bad = DEFAULTS.replace(M=510.0)
    object.__setattr__(bad, 'CLk', float('nan'))
    with pytest.raises(ModelError, match='failed to converge'):
        simulate('HD', scn, params=bad, ecu_period=1e-3)
    units = [DEFAULTS, bad, DEFAULTS.replace(M=520.0)]
    runs = simulate_many('HD', scn, units, ecu_period=1e-3, failed='none')
    assert runs[1] is None
    for u in (0, 2):
        assert np.array_equal(runs[u]['xj'],
                              simulate('HD', scn, params=units[u], ecu_period=1e-3)['xj'])
    with pytest.raises(ModelError, match='unit 1: valve model HD failed'):
        simulate_many('HD', scn, units, ecu_period=1e-3)


@pytest.mark.parametrize('kwargs, fragment', [
    (dict(params=[]), 'runs 1 to 1024 units'),
    (dict(params=[DEFAULTS], faults=[(), ()]), '2 fault schedules for 1 units'),
    (dict(params=[DEFAULTS], failed='ignore'), "failed must be 'raise' or 'none'"),
    (dict(params=[DEFAULTS], initial={'q': 1.0}), "unknown plant state 'q'"),
])
def test_bad_fleets_are_named(kwargs, fragment):
    with pytest.raises(ParameterError) as err:
        simulate_many('C2', short(), **kwargs)
    assert fragment in str(err.value)


def test_a_fleet_runs_ideal_sensors_only():
    with pytest.raises(ParameterError, match='ideal sensors only'):
        simulate_many('C2', dict(short(), sensors={'xj': {'noise': 1e-6}}), [DEFAULTS])
