"""The registry's contract: every registered model, tested the moment it is registered."""

import math

import numpy as np
import pytest

from servovalve_twin.errors import ModelError
from servovalve_twin.physics.params import DEFAULTS
from servovalve_twin.runs import simulate
from servovalve_twin.physics.valves import VALVE_MODEL_NAMES, VALVE_MODELS, get_valve_model

PAPER_NAMES = ('linear', 'saturated', 'saturated_downstream', 'linear_leakage', 'A', 'B', 'C1',
               'C2', 'C3', 'C4', 'HD')


def test_registry_holds_every_model_of_the_paper():
    assert set(PAPER_NAMES) <= set(VALVE_MODEL_NAMES)


def test_unknown_name_lists_the_valid_ones():
    with pytest.raises(ModelError) as err:
        get_valve_model('C9')
    msg = str(err.value)
    assert "unknown valve model 'C9'" in msg
    assert all(repr(n) in msg for n in VALVE_MODEL_NAMES)


@pytest.fixture(params=VALVE_MODEL_NAMES)
def model(request):
    return VALVE_MODELS[request.param]


def random_points(n=300, seed=1):
    rng = np.random.default_rng(seed)
    xs = rng.uniform(-DEFAULTS.XSM, DEFAULTS.XSM, n)
    qj = rng.uniform(-1.5e-4, 1.5e-4, n)
    psr = rng.uniform(2e6, 30e6, n)
    return xs, qj, psr


def test_shared_signature_and_finite_output(model):
    state = None
    for xs, qj, psr in zip(*random_points()):
        p12, state, info = model(xs, qj, psr, DEFAULTS, state)
        assert math.isfinite(p12)
        assert isinstance(info, dict)
    if model.iterative:
        assert info['iterations'] >= 1
    if model.has_ports:
        assert {'p1', 'p2', 'cavitation'} <= set(info)


def test_python_call_does_not_modify_given_state(model):
    state = model.initial_state(DEFAULTS)
    before = state.copy()
    model(1e-5, 1e-5, 20e6, DEFAULTS, state)
    np.testing.assert_array_equal(state, before)


def test_odd_symmetry_with_symmetric_valve(model):
    # with zero laps the valve is symmetric: P12(-XS, -QJ) = -P12(XS, QJ)
    for xs, qj, psr in zip(*random_points(50, seed=2)):
        a = model(xs, qj, psr, DEFAULTS)[0]
        b = model(-xs, -qj, psr, DEFAULTS)[0]
        assert a == pytest.approx(-b, rel=1e-6, abs=1.0)


def test_pressure_falls_as_the_flow_grows(model):
    # the pressure-output models all feed the working flow back negatively
    for xs in (-1e-4, 0.0, 2e-5, 1.5e-4):
        p = [model(xs, q, 20e6, DEFAULTS)[0] for q in np.linspace(-1e-4, 1e-4, 21)]
        assert np.all(np.diff(p) <= 1e-6), (model.name, xs)


def test_nonfinite_input_is_an_error(model):
    with pytest.raises(ModelError, match='XS must be finite'):
        model(math.nan, 0.0, 20e6, DEFAULTS)


def test_whole_paper_scenario_runs(model):
    r = simulate(model.name, 'paper')
    assert len(r['t']) == 1001
    for c in ('xs', 'xj', 'dxj', 'p12', 'qj'):
        assert np.all(np.isfinite(r[c])), c
    assert np.all(np.abs(r['xj']) <= DEFAULTS.XJM)
    print(model.name, 'XJ(1 s) =', r['xj'][-1], 'm', r.info)
