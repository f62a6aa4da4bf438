"""The registry's contract: every registered model, tested the moment it is registered."""

import math

import numpy as np
import pytest

from servovalve_twin.errors import ModelError
from servovalve_twin.physics.params import DEFAULTS
from servovalve_twin.runs import simulate
from servovalve_twin.physics.valves import VALVE_MODEL_NAMES, VALVE_MODELS, get_valve_model
from cases import short

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


SHORT = short(0.06, load=8000.0, psr_after=1.2e7)


def test_stateful_plant_equals_simulate(model):
    """The ROS plant's physics (EhaPlant, one control period per call, the ECU from Python)
    gives simulate's sampled-ECU run bit for bit, for every registered model."""
    from servovalve_twin.physics.simulate import EhaPlant
    ref = simulate(model.name, SHORT, ecu_period=1e-3)
    plant = EhaPlant(model.name, DEFAULTS)
    xj = []
    for i, (com, fr, psr) in enumerate(zip(ref['com'], ref['fr'], ref['psr'])):
        xj.append(plant.xj)
        cor = plant.control(com, plant.xj)
        plant.tick(cor, fr, psr, 100 if i < len(ref['t']) - 1 else 0)
    np.testing.assert_array_equal(xj, ref['xj'])


def test_mid_run_switch_to_and_from_the_model(model):
    """Switched to mid-run, a model keeps the mechanical state and answers from it: its first
    P12 is what the model computes at that state from Python; switched away, the other model
    continues from the same state too."""
    from servovalve_twin.physics.servovalve import S_DXJ, S_XS
    from servovalve_twin.physics.simulate import EhaPlant
    other = 'HD' if model.name != 'HD' else 'C2'
    plant = EhaPlant(other, DEFAULTS)
    for _ in range(30):
        plant.tick(plant.control(0.02, plant.xj), 8000.0, 2e7, 100)
    for target in (model.name, other):
        before = plant.s.copy()
        plant.set_valve_model(target)
        np.testing.assert_array_equal(plant.s, before)
        vs = plant.vs.copy()
        p12 = plant.tick(plant.control(0.02, plant.xj), 8000.0, 2e7, 100)[0]
        expected = VALVE_MODELS[target](before[S_XS], DEFAULTS.AJ * before[S_DXJ], 2e7,
                                        DEFAULTS, vs)[0]
        assert p12 == pytest.approx(expected, rel=1e-9, abs=1e-3)
        assert np.isfinite(plant.xj)


def test_short_twin_run_and_its_bag(model, ros_context, tmp_path):
    """One short ROS twin run per model: it equals simulate, its bag reads back the same
    table, P1/P2 are there exactly when the model has port pressures, the provenance names
    the model."""
    from servovalve_twin.bag.reader import read_bag
    from servovalve_twin.twin import TwinConfig, run_twin
    result = run_twin(TwinConfig(model.name, SHORT, bag=tmp_path / model.name),
                      context=ros_context, handle_signals=False)
    ref = simulate(model.name, SHORT, ecu_period=1e-3)
    bag = read_bag(tmp_path / model.name)
    assert set(bag.signals) == set(ref.columns) == set(result.signals)
    assert ({'p1', 'p2'} <= set(bag.signals)) == model.has_ports
    for col in ref.columns:
        np.testing.assert_array_equal(result.signals[col], ref[col], err_msg=col)
        np.testing.assert_array_equal(bag.signals[col], ref[col], err_msg=col)
    assert bag.valve_model == model.name


def test_entry_is_consistent(model):
    """What an entry declares holds: a monitor model has ordered default thresholds, a model
    with port pressures fills them, constants fit the kernel."""
    from servovalve_twin.physics.params import N_VALVE_CONSTANTS
    from servovalve_twin.prognostics.monitor import HealthConfig
    assert len(model.constants(DEFAULTS)) <= N_VALVE_CONSTANTS
    if model.monitor:
        HealthConfig.for_model(model.name)          # validates the thresholds' order
    else:
        with pytest.raises(ModelError):
            HealthConfig.for_model(model.name)
    _, vs, info = model(2e-5, 1e-5, 2e7, DEFAULTS)
    if model.has_ports:
        assert np.isfinite(info['p1']) and np.isfinite(info['p2'])
        assert info['p1'] - info['p2'] == pytest.approx(model(2e-5, 1e-5, 2e7, DEFAULTS)[0])


def test_compiled_loops_select_this_model_by_its_id(model):
    """The step loops call the model through ``valve_p12(model.id, ...)``: its branch must be
    this model's function, bit for bit with the same state in and out (a branch pointing at a
    neighbour, or a new model without a branch, fails here); ids are the registry positions."""
    from servovalve_twin.physics.valves import valve_p12
    assert model.id == VALVE_MODEL_NAMES.index(model.name)
    kernel = model.kernel(DEFAULTS)
    vs_a = model.initial_state(DEFAULTS)
    vs_b = vs_a.copy()
    for xs, qj, psr in zip(*random_points(100, seed=7)):
        a = model.fn(xs, qj, psr, kernel, vs_a)
        b = valve_p12(model.id, xs, qj, psr, kernel, vs_b)
        assert a == b or (math.isnan(a) and math.isnan(b))
        np.testing.assert_array_equal(vs_a, vs_b)
