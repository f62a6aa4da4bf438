"""The least-squares fit of the diagnosis (:mod:`servovalve_twin.prognostics.fitting`), against
a brute-force profile of its own cost."""

from __future__ import annotations

import numpy as np

from servovalve_twin.physics.params import DEFAULTS
from servovalve_twin.prognostics import calibration_set
from servovalve_twin.prognostics.fitting import Problem, fit, start_grid


def test_a_fit_on_a_flat_stretch_finds_the_valley_between_the_start_grid_points():
    """Static friction 6 x on the built-in test: its cost under SQ is flat from about 5.6 x up
    (the jack never breaks away there) and has a valley about 10 % wide near 4.7 x, between
    the start grid's points 3.68 and 7.07. The finite differences see nothing at a grid point
    on the flat stretch; the fit must still end in the valley: no worse than the best of 161
    severities tried one by one (the nuisance at the fit's), far better than any grid point."""
    sig, truth, _ = calibration_set.unit_signals('static_friction', 0.6, 'bit', 8101, spread=1.5)
    problem = Problem(sig, DEFAULTS, 'SQ', 1e-3, None)
    x, res, _ = fit(problem, ['static_friction'], ['M', 'CJ'])
    rss = float(res @ res)

    def cost(s: float) -> float:
        r = problem.residuals(problem.run(problem.params(
            ['static_friction'], [float(s)], {'M': x[1], 'CJ': x[2]})))
        return float(r @ r)

    profile = [cost(s) for s in np.geomspace(2.0, 20.0, 161)]
    on_grid = [cost(s) for s in start_grid('static_friction')]
    assert rss <= 1.01 * min(profile)
    assert rss < 0.8 * min(on_grid)
    assert 4.0 < x[0] < 5.5 < truth


def test_a_whole_run_is_modelled_from_rest_not_from_its_first_noisy_sample():
    """A run diagnosed from t = 0 starts at rest: its first recorded XJ and DXJ are the rest
    state plus the sensors' noise, and a model started there made a transient the actuator
    never had (on a flight that excites nothing, a healthy unit was called a 100 x leak). A
    fit from a later instant, or of rows that begin mid-run, starts at the recorded state."""
    sig, _, _ = calibration_set.unit_signals(None, 0.0, 'defaults', 4242, spread=1.5)
    assert sig['xj'][0] != 0.0 and sig['dxj'][0] != 0.0          # noise at the first row
    problem = Problem(sig, DEFAULTS, 'SQ', 1e-3, None)
    run = problem.run(problem.params((), [], {}))
    for s in ('xj', 'dxj', 'p12'):
        assert np.all(run[s] == 0.0), s                 # at rest, as the actuator stayed
    later = Problem(sig, DEFAULTS, 'SQ', 1e-3, (0.5, 1.0), start=0.4)
    assert later.initial == {'xj': float(sig['xj'][400]), 'dxj': float(sig['dxj'][400])}
    # rows that begin mid-run (the live estimator's kept ones, their time shifted to 0)
    mid = Problem(sig, DEFAULTS, 'SQ', 1e-3, None, from_rest=False)
    assert mid.initial == {'xj': float(sig['xj'][0]), 'dxj': float(sig['dxj'][0])}


def test_a_fit_that_stalls_on_a_rough_cost_is_solved_again_to_its_valley():
    """Dynamic friction 1.86 x on the paper flight, M and CJ free: dynamic friction trades
    against CJ, and with the finite difference's step of 1e-3 the cost is rough enough (the
    friction's switching) that the solver's trust region shrank to nothing after two
    Jacobians, at 1.78 x with CJ still at its start, RSS 2660. The fit must reach the valley:
    no worse than the best of a brute-force grid over the severity and CJ (M at the fit's)."""
    sig, truth, _ = calibration_set.unit_signals('dynamic_friction', 0.22, 'paper', 4444477,
                                             spread=1.5)
    problem = Problem(sig, DEFAULTS, 'SQ', 1e-3, None)
    x, res, _ = fit(problem, ['dynamic_friction'], ['CJ', 'M'])
    rss = float(res @ res)

    def cost(s: float, cj: float) -> float:
        r = problem.residuals(problem.run(problem.params(
            ['dynamic_friction'], [float(s)], {'CJ': float(cj), 'M': x[2]})))
        return float(r @ r)

    grid = min(cost(s, cj) for s in np.linspace(1.6, 2.6, 11) for cj in np.linspace(0.6, 1.0, 9))
    assert rss <= 1.005 * grid and rss < 2500
    assert x[0] > 2.0 and x[1] < 0.9


def test_a_known_xj_offset_runs_as_the_twin_s_biased_sensor_in_the_loop():
    """The XJ sensor reading 80 um high inside the loop (the twin's own sensor model, no
    noise) against the fit's run of the command less 80 um, read 80 um high: the same
    readings. A P12 offset adds to the reading only."""
    from servovalve_twin.config import load_scenario
    from servovalve_twin.physics.params import DEFAULTS
    from servovalve_twin.prognostics.fitting import Problem
    from servovalve_twin.runs import simulate
    scn = load_scenario('paper').to_dict()
    sensed = simulate('SQ', dict(scn, sensors={'xj': {'bias': 8e-5}, 'p12': {'bias': 2e5}}),
                      ecu_period=1e-3).signals
    ideal = simulate('SQ', scn, ecu_period=1e-3).signals
    # the jack settles 80 um short of the command: the loop is fed the reading
    assert abs(float(sensed['xj'][-1] - ideal['xj'][-1])) < 1e-6
    problem = Problem(ideal, DEFAULTS, 'SQ', 1e-3, None,
                      sensor_bias={'xj': 8e-5, 'p12': 2e5})
    run = problem.run(problem.params((), [], {}))
    for s in ('xj', 'dxj', 'p12'):
        np.testing.assert_allclose(run[s], sensed[s][problem.rows], rtol=1e-9,
                                   atol=1e-12 * float(np.max(np.abs(sensed[s]))))
    free = problem.run(problem.params((), [], {'p12_bias': 1e5}))
    np.testing.assert_allclose(free['p12'] - run['p12'], 1e5)
    np.testing.assert_array_equal(free['xj'], run['xj'])
