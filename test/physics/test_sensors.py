"""physics/sensors.py and simulate() with sensors: the noise generator against its Python-integer
reference and against the normal distribution; every reading against Q(truth + bias + drift*t +
noise*n) computed here from the run's truth; the ECU closing its loop on the measured XJ; seeds;
the scenario schema."""

import numpy as np
import pytest
from scipy import stats

from servovalve_twin.config import load_scenario
from servovalve_twin.errors import ParameterError, ScenarioError
from servovalve_twin.physics.scenario import scenario_from_dict
from servovalve_twin.physics.sensors import (SENSED, normal_draws, sensors_from_dict, signal_key,
                                             std_normal, std_normal_py)
from servovalve_twin.runs import simulate

from cases import short

SENSORS = {'seed': 7,
           'xj': {'noise': 2.0e-5, 'quantisation': 1.0e-6},
           'dxj': {'bias': 1.0e-3, 'drift': 2.0e-2},
           'p12': {'noise': 1.0e5, 'period': 0.003},
           'p1': {'noise': 5.0e4, 'quantisation': 1.0e4, 'period': 0.002}}


def _with(scenario, sensors=SENSORS):
    return dict(scenario, sensors=sensors)


def test_the_compiled_draws_are_the_python_integer_reference_bit_for_bit():
    """SplitMix64 on numba's uint64 (wrapping multiplies, shifts) against Python's integers
    masked to 64 bits: a shift by the wrong amount, a signed shift, or an int64/uint64 mix
    (numba turns it into float64) would differ."""
    for seed in (0, 1, 7, 2 ** 63 - 1):
        for j in range(len(SENSED)):
            key = signal_key(seed, j)
            for k in (0, 1, 2, 1000, 3_599_999, 2 ** 40 + 3):
                assert std_normal(np.uint64(key), k) == std_normal_py(key, k), (seed, j, k)


def test_the_draws_are_independent_standard_normal():
    """200 000 draws of one stream: mean, variance, the upper 5 % and a KS test against
    N(0, 1); no lag-1 correlation; another signal's and another seed's streams uncorrelated
    with it. A Box-Muller with the wrong radius (sqrt(-log u)) or a counter that repeats would
    fail."""
    n = 200_000
    k = np.arange(n)
    x = normal_draws(7, 'xj', k)
    assert abs(x.mean()) < 4 / np.sqrt(n)
    assert abs(x.std() - 1.0) < 0.01
    assert abs((x > 1.6449).mean() - 0.05) < 0.003
    assert stats.kstest(x, 'norm').pvalue > 1e-3
    assert abs(np.corrcoef(x[1:], x[:-1])[0, 1]) < 4 / np.sqrt(n)
    for other in (normal_draws(7, 'p12', k), normal_draws(8, 'xj', k)):
        assert abs(np.corrcoef(x, other)[0, 1]) < 4 / np.sqrt(n)


def _expected(truth, spec, seed, name, dt_row=1e-3):
    """A sensor's readings at the 1 ms rows, from the truth, by the documented formula: a
    sample every period (held between), y = Q(x + bias + drift*t_k + noise*n_k)."""
    every = int(round(spec.get('period', dt_row) / dt_row))
    rows = np.arange(len(truth))
    k = rows // every
    x = truth[k * every]
    y = x + spec.get('bias', 0.0) + spec.get('drift', 0.0) * (k * (every * dt_row))
    if spec.get('noise'):
        y = y + spec['noise'] * normal_draws(seed, name, k)
    q = spec.get('quantisation', 0.0)
    if q:
        y = q * np.floor(y / q + 0.5)
    return y


@pytest.mark.parametrize('model', ['C2', 'HD'])
def test_every_reading_is_the_formula_on_the_truth(model):
    """Each sensed signal's column equals the formula applied here to the run's truth (the
    sample instants, the hold, bias, drift over the sample's time, noise, quantisation);
    the signals without a sensor equal their truth. HD: P1 too."""
    r = simulate(model, _with(short()), ecu_period=1e-3)
    names = [n for n in SENSORS if n != 'seed' and (n != 'p1' or model == 'HD')]
    assert sorted(r.truth) == sorted(names)
    for name in names:
        want = _expected(r.truth[name], SENSORS[name], 7, name)
        np.testing.assert_allclose(r[name], want, rtol=1e-15, atol=0, err_msg=name)
        assert not np.array_equal(r[name], r.truth[name])
    # the hold: P12 (3 ms) changes only at sample rows
    changes = np.flatnonzero(np.diff(r['p12'])) + 1
    assert len(changes) > 50 and np.all(changes % 3 == 0)


def test_the_ecu_closes_its_loop_on_the_measured_position():
    """With an XJ sensor reading 1 mm high, the loop settles the *reading* where an ideal
    sensor's loop settles the jack (12 um short of the command: the valve's own offset): the
    true jack stops 1 mm lower. An ECU fed the truth would put it where the ideal run does."""
    scn = {'duration': 0.5, 'com': [[0.0, 0.02]], 'sensors': {'xj': {'bias': 1.0e-3}}}
    r = simulate('C2', scn, ecu_period=1e-3)
    ideal = simulate('C2', dict(scn, sensors=None), ecu_period=1e-3)
    assert abs(ideal['xj'][-1] - 0.02) < 2e-5
    assert abs(r['xj'][-1] - ideal['xj'][-1]) < 1e-8
    assert abs(r.truth['xj'][-1] - (ideal['xj'][-1] - 1.0e-3)) < 1e-8


def test_noise_on_the_measured_position_moves_the_true_jack():
    """The noisy reading feeds back: the true XJ differs from the ideal-sensor run (it would
    not if the ECU read the truth), by far less than the noise itself."""
    scn = _with(short(), {'seed': 1, 'xj': {'noise': 1.0e-5}})
    r = simulate('SQ', scn, ecu_period=1e-3)
    ideal = simulate('SQ', dict(scn, sensors=None), ecu_period=1e-3)
    moved = np.abs(r.truth['xj'] - ideal['xj']).max()
    assert 0 < moved < 1.0e-5


def test_the_seed_decides_the_noise_and_nothing_else_does():
    """The same seed gives the same bytes; another seed (in the scenario or sensor_seed)
    other readings of the same sensors; sensor_seed equals writing the seed in the
    scenario."""
    a = simulate('C2', _with(short()), ecu_period=1e-3)
    b = simulate('C2', _with(short()), ecu_period=1e-3)
    c = simulate('C2', _with(short()), ecu_period=1e-3, sensor_seed=8)
    d = simulate('C2', _with(short(), dict(SENSORS, seed=8)), ecu_period=1e-3)
    assert np.array_equal(a['xj'], b['xj'])
    assert not np.array_equal(a['xj'], c['xj'])
    for name in ('xj', 'p12', 'cor'):
        assert np.array_equal(c[name], d[name])


def test_a_continuous_ecu_reads_sensors_sampled_every_output_row():
    """Without an ECU period the sensors sample every 1 ms (the output rows) and the ECU
    holds their reading in between: the rows equal the formula on the truth."""
    r = simulate('C2', _with(short(), {'seed': 2, 'xj': {'noise': 1.0e-5}}))
    np.testing.assert_allclose(r['xj'], _expected(r.truth['xj'], {'noise': 1.0e-5}, 2, 'xj'),
                               rtol=1e-15, atol=0)


def test_the_scenario_carries_its_sensors_through_yaml():
    scn = scenario_from_dict(_with(short()))
    again = scenario_from_dict(scn.to_dict())
    assert again.sensors == scn.sensors and again.sensors.seed == 7
    assert scn.without_sensors().sensors is None
    assert load_scenario('paper').sensors is None


@pytest.mark.parametrize('sensors, fragment', [
    ({'cor': {'noise': 1.0}}, "unknown key 'cor'"),
    ({'xj': {'noise': -1.0}}, 'noise must be >= 0'),
    ({'xj': {'nois': 1.0}}, "unknown key 'nois'"),
    ({'xj': {'period': 1.0}}, 'period must be in (0, 0.1] s'),
    ({'xj': {'bias': float('nan')}}, 'expected a finite number'),
    ({'xj': 3}, 'expected a mapping'),
    ({'seed': -1, 'xj': {}}, 'outside [0, 2**63 - 1]'),
    ({'seed': 1.5, 'xj': {}}, 'expected an integer'),
])
def test_bad_sensors_are_named(sensors, fragment):
    with pytest.raises(ScenarioError, match='scenario.sensors') as err:
        scenario_from_dict(_with(short(), sensors))
    assert fragment in str(err.value)


def test_a_seed_without_sensors_is_refused():
    """A sensor seed for a scenario without sensors is a mistake (a realisation of nothing),
    not a run silently like the ideal one."""
    with pytest.raises(ParameterError, match='declares no sensors'):
        simulate('C2', short(), sensor_seed=3)


def test_a_sensor_period_must_be_whole_control_periods():
    scn = _with(short(), {'xj': {'period': 0.0025}})
    with pytest.raises(ScenarioError, match='whole number of control periods'):
        simulate('C2', scn, ecu_period=1e-3)
    with pytest.raises(ScenarioError, match='whole number of control periods'):
        simulate('C2', _with(short(), {'xj': {'period': 0.002}}), ecu_period=3e-3)
    assert sensors_from_dict({'xj': {}}) is not None and sensors_from_dict({'seed': 1}) is None


def test_the_result_says_what_measured_it():
    """A seed given to simulate() is the one the result's scenario carries (what a bag's
    provenance would record)."""
    r = simulate('C2', _with(short()), ecu_period=1e-3, sensor_seed=9)
    assert r.sensors.seed == 9
    assert r.scenario.to_dict()['sensors']['seed'] == 9
    assert simulate('C2', short()).scenario.sensors is None


@pytest.mark.parametrize('ecu_period', [None, 2e-3])
def test_a_pressure_sensor_alone_leaves_the_loop_as_it_was(ecu_period):
    """Only P12 sensed: the ECU reads the true XJ (continuously, or every 2 ms) and every
    other column -- the state, Cor, and the unsensed signals at every 1 ms row, between the
    sensors' samples included -- equals the ideal-sensor run bit for bit."""
    scn = _with(short(), {'seed': 1, 'p12': {'noise': 1.0e5}})
    r = simulate('HD', scn, ecu_period=ecu_period)
    ideal = simulate('HD', dict(scn, sensors=None), ecu_period=ecu_period)
    for name in ideal.columns:
        if name != 'p12':
            assert np.array_equal(r[name], ideal[name]), name
    assert np.array_equal(r.truth['p12'], ideal['p12'])
    assert not np.array_equal(r['p12'], ideal['p12'])
