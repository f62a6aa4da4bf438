"""The one conformal rule of diagnosis (servovalve_twin.prognostics.conformal) and the group
fallback of its calibration, against hand values, the definition of each score, and the
closed-form coverage of an order statistic."""

from __future__ import annotations

import math

import numpy as np
import pytest

from servovalve_twin.prognostics import conformal
from servovalve_twin.prognostics.calibration import (POOLED, calibration_for, groups_of,
                                                     resolve_entry)
from servovalve_twin.prognostics.rules import DIAGNOSABLE


def test_the_level_and_the_rank_against_hand_values():
    assert conformal.ALPHA == 0.1
    assert conformal.z_of(0.1) == pytest.approx(1.6449, abs=1e-4)      # tables
    assert conformal.z_of(0.05) == pytest.approx(1.9600, abs=1e-4)
    # ceil(0.9 * 10) = 9 exactly (0.9 * 10 is 9.000000000000002 in binary: not 10)
    assert [conformal.rank(n) for n in (8, 9, 10, 19, 99)] == [9, 9, 10, 18, 90]
    assert conformal.rank(18, 0.05) == 19 and conformal.rank(19, 0.05) == 19
    assert conformal.units_needed(0.1) == 9 and conformal.units_needed(0.05) == 19
    assert not conformal.enough(8) and conformal.enough(9)


def test_the_quantile_is_the_order_statistic():
    assert conformal.quantile(range(10, 0, -1)) == 10          # rank 10 of 10
    assert conformal.quantile(list(range(1, 20))) == 18        # rank 18 of 19
    assert conformal.quantile([3.0, 1.0, 2.0]) == 3.0          # too few: the largest
    # a false-alarm bound of 1/(n + 1): the largest of n
    assert conformal.quantile([0.1, 0.5, 0.2], 1 / 4) == 0.5
    with pytest.raises(ValueError):
        conformal.quantile([])


def test_the_p_value_counts_the_reference():
    ref = [1.0, 2.0, 3.0, 4.0]
    assert conformal.p_value(ref, 0.5) == 1.0
    assert conformal.p_value(ref, 3.0) == pytest.approx(3 / 5)     # ties count as worse
    assert conformal.p_value(ref, 9.0) == pytest.approx(1 / 5)


@pytest.mark.parametrize('n,alpha', [(9, 0.1), (12, 0.1), (19, 0.1), (40, 0.2), (19, 0.05)])
def test_the_quantile_covers_a_new_unit_at_the_order_statistic_s_rate(n, alpha):
    """Exchangeable continuous scores: a new one is at most the k-th smallest of n with
    probability exactly k/(n + 1) -- the closed form the rule rests on (k = rank)."""
    rng = np.random.default_rng(n)
    trials = 40000
    cal = rng.standard_normal((trials, n)) ** 2
    new = rng.standard_normal(trials) ** 2
    q = np.array([conformal.quantile(row, alpha) for row in cal])
    k = conformal.rank(n, alpha)
    assert np.mean(new <= q) == pytest.approx(k / (n + 1), abs=4 * math.sqrt(0.25 / trials))
    assert k / (n + 1) >= 1 - alpha


def _smallest(covered, hi=10.0):
    """The smallest parameter in [0, hi] at which ``covered`` holds, by a fine bisection."""
    lo = 0.0
    if covered(lo):
        return lo
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        lo, hi = (lo, mid) if covered(mid) else (mid, hi)
    return hi


def test_each_score_is_the_smallest_parameter_that_covers_its_unit():
    rng = np.random.default_rng(3)
    z = conformal.z_of()
    for _ in range(200):
        dev, se, sigma, x = rng.normal(0, 0.3), rng.uniform(0.001, 0.2), rng.uniform(0, 0.1), \
            rng.uniform(0.1, 2.0)
        assert conformal.spread_score(dev, se, z) == pytest.approx(_smallest(
            lambda v: abs(dev) <= z * math.hypot(se, v)), abs=1e-9)
        assert conformal.factor_score(dev, se, sigma, z) == pytest.approx(_smallest(
            lambda v: abs(dev) <= z * math.hypot(v * se, sigma), hi=1e4), abs=1e-7)
        assert conformal.rate_score(dev, sigma + 0.01, x, z) == pytest.approx(_smallest(
            lambda v: abs(dev) <= z * math.hypot(sigma + 0.01, v * x)), abs=1e-9)


def test_the_groups_fall_back_in_one_declared_order():
    assert groups_of('paper') == ['paper', POOLED]
    assert groups_of('onset:bit') == ['onset:bit', 'onset', POOLED]
    assert groups_of('onset') == ['onset', POOLED]
    assert groups_of(None) == [POOLED]
    cal = {POOLED: {'a': dict(sigma=0.3, units=60, pinned=50)},
           'by_scenario': {'onset': {'b': dict(sigma=0.1, units=30, pinned=30)},
                           'onset:bit': {'b': dict(sigma=0.05, units=12, pinned=12)}}}
    # an onset answer of a fault no onset unit calibrated: the from-start pool, not nothing
    assert resolve_entry(cal, 'a', 'onset:bit') == (dict(cal[POOLED]['a'], scored=50), POOLED)
    # a flight's own group on fewer than OWN_UNITS units: the larger spread of it and the next
    own, group = resolve_entry(cal, 'b', 'onset:bit')
    assert (own['sigma'], own['scored'], group) == (0.1, 30, 'onset:bit')
    # a pooled group stands alone
    assert resolve_entry(cal, 'b', 'onset')[0]['sigma'] == 0.1
    assert resolve_entry(cal, 'c', 'paper') == (None, None)


@pytest.mark.parametrize('free', [(), ('CJ', 'M')])
def test_every_packaged_group_resolves_every_fault(free):
    """No (group, fault) of the packaged calibration is left to a noise-only interval."""
    cal = calibration_for('SQ', free)
    groups = list(cal['by_scenario']) + [None, 'own', 'onset:another']
    holes = [(g, f) for g in groups for f in DIAGNOSABLE if resolve_entry(cal, f, g)[0] is None]
    assert not holes
