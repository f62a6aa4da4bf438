"""The least-squares fit of the diagnosis (:mod:`servovalve_twin.prognostics.fitting`), against
a brute-force profile of its own cost."""

from __future__ import annotations

import numpy as np

from servovalve_twin.physics.params import DEFAULTS
from servovalve_twin.prognostics import calibration
from servovalve_twin.prognostics.fitting import Problem, fit, start_grid


def test_a_fit_on_a_flat_stretch_finds_the_valley_between_the_start_grid_points():
    """Static friction 6 x on the built-in test: its cost under SQ is flat from about 5.6 x up
    (the jack never breaks away there) and has a valley about 10 % wide near 4.7 x, between
    the start grid's points 3.68 and 7.07. The finite differences see nothing at a grid point
    on the flat stretch; the fit must still end in the valley: no worse than the best of 161
    severities tried one by one (the nuisance at the fit's), far better than any grid point."""
    sig, truth, _ = calibration.unit_signals('static_friction', 0.6, 'bit', 8101, spread=1.5)
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
