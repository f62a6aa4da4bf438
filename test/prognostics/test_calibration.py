"""The diagnosis' model-form calibration: its coordinates, the fit of bias and spread to a known
error distribution, the goodness-of-fit test and the verdicts it gives on HD units the
calibration never saw (seeds of their own)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from servovalve_twin.physics.faults import FAULTS
from servovalve_twin.prognostics import calibration, calibration_set
from servovalve_twin.physics.params import DEFAULTS
from servovalve_twin.prognostics.calibration import calibration_for, fit_calibration, gof_p_value
from servovalve_twin.prognostics.calibration_set import (LEVELS, from_g, severity_at, to_g,
                                                         unit_signals)
from servovalve_twin.prognostics.diagnosis import DIAGNOSABLE, UNEXPLAINED, diagnose

#: the two-sided 90 % normal quantile, by hand (tables): not the code's own
Z90 = 1.6449


def test_levels_and_coordinates_against_hand_values():
    # geometric for a multiplier: 0.3 of the way from 1 to 10 is 10^0.3
    assert severity_at('leakage_growth', 0.3) == pytest.approx(10 ** 0.3)
    # even for a fraction: 0.6 of the way from 0 to 0.7
    assert severity_at('torque_motor_gain_loss', 0.6) == pytest.approx(0.42)
    assert to_g('leakage_growth', math.e) == pytest.approx(1.0)
    assert to_g('supply_loss', 0.15) == pytest.approx(0.5)          # span 0.3
    for f in FAULTS:
        for q in LEVELS:
            s = severity_at(f, q)
            assert from_g(f, to_g(f, s)) == pytest.approx(s)


def test_fit_calibration_recovers_a_known_bias_and_spread():
    """Errors in g drawn N(-0.05, 0.04) with a fit standard error of 0.01: the bias comes back
    as the median, and the spread makes the 90 % interval hold 90 % of the units."""
    rng = np.random.default_rng(2)
    rec = []
    for _ in range(2000):
        truth = float(np.exp(rng.uniform(0.5, 2.0)))
        est = truth * math.exp(rng.normal(-0.05, 0.04) + rng.normal(0.0, 0.01))
        rec.append(dict(fault='leakage_growth', truth=truth, named='leakage_growth',
                        estimate=est, se=0.01, rms=1.0))
    c = fit_calibration(rec)['faults']['leakage_growth']
    assert c['bias'] == pytest.approx(-0.05, abs=0.004)
    # sqrt(0.04^2 + 0.01^2) in all; less the stated 0.01: 0.04
    assert c['sigma'] == pytest.approx(0.04, rel=0.1)


def test_few_units_are_held_at_the_conformal_rank():
    """Ten units: a new unit is held with probability >= 90 % only if the interval holds
    ceil(0.9*11) = 10 of them -- all ten, the largest error included (a plain 90 % of ten
    would leave it out)."""
    errs = [-0.3, -0.1, -0.05, -0.02, 0.0, 0.0, 0.01, 0.04, 0.08, 0.6]
    rec = [dict(fault='leakage_growth', truth=2.0, named='leakage_growth',
                estimate=2.0 * math.exp(e), se=0.0, rms=1.0) for e in errs]
    c = fit_calibration(rec)['faults']['leakage_growth']
    assert c['bias'] == pytest.approx(0.0)
    assert c['sigma'] * 1.6449 == pytest.approx(0.6, rel=1e-3)


def test_the_spread_is_the_conformal_quantile_at_the_stated_alpha():
    """19 units erring 0.01 ... 0.19 in g, se 0: the 90 % spread holds the 18th (ceil(0.9 *
    20)), the 80 % one the 16th (ceil(0.8 * 20)), at z 1.6449 and 1.2816 (tables)."""
    rec = [dict(fault='leakage_growth', truth=2.0, named='leakage_growth',
                estimate=2.0 * math.exp(0.01 * i * (-1) ** i), se=0.0, rms=1.0)
           for i in range(1, 20)]
    c90 = fit_calibration(rec)
    c80 = fit_calibration(rec, alpha=0.2)
    assert (c90['alpha'], c80['alpha']) == (0.1, 0.2)
    # (the bias is the median error, +0.01 or -0.01 here: the deviations shift by it)
    dev = sorted(abs(0.01 * i * (-1) ** i - c90['faults']['leakage_growth']['bias'])
                 for i in range(1, 20))
    assert c90['faults']['leakage_growth']['sigma'] * Z90 == pytest.approx(dev[17], rel=1e-3)
    assert c80['faults']['leakage_growth']['sigma'] * 1.2816 == pytest.approx(dev[15],
                                                                             rel=1e-3)


def test_the_goodness_of_fit_p_value_counts_the_reference():
    cal = {'rms': [1.0, 2.0, 3.0, 4.0]}
    assert gof_p_value(cal, 0.5) == 1.0
    assert gof_p_value(cal, 3.5) == pytest.approx(2 / 5)
    assert gof_p_value(cal, 9.0) == pytest.approx(1 / 5)


def test_the_packaged_calibration_covers_every_hypothesis():
    from servovalve_twin.prognostics.diagnosis import DIAGNOSABLE
    for free in (('CJ', 'M'), ()):
        cal = calibration_for('SQ', free)
        assert cal is not None and len(cal['rms']) > 100
        missing = [f for f in DIAGNOSABLE if f not in cal['faults']]
        assert not missing, missing
        # past the alarm value: every fault whose catalog goes past it
        assert sorted(cal['past']) == sorted(
            f for f in DIAGNOSABLE if calibration_set.end_level(f) > 1.0)
        assert len(cal['past_rms']) > len(cal['rms'])


@pytest.mark.slow
def test_an_actuator_unlike_its_design_is_unexplained():
    """An HD unit whose piston area is 30 % larger than its design says -- no catalog fault, no
    nuisance the diagnosis frees -- is not given a confident name."""
    sig, _, _ = unit_signals(None, 0.0, 'paper', 424242, spread=0.0, noise_gain=1.0,
                             design=DEFAULTS.replace(AJ=1.3 * DEFAULTS.AJ))
    d = diagnose(sig, DEFAULTS, control_period=1e-3, model='SQ', free=('M', 'CJ'))
    assert d.verdict == UNEXPLAINED and d.p_value < 0.01
    assert d.to_json()['fault'] == UNEXPLAINED and d.to_json()['severity'] is None


def test_a_right_hypothesis_is_not_unexplained():
    sig, truth, _ = unit_signals('leakage_growth', 1.0, 'paper', 515151, noise_gain=1.0)
    d = diagnose(sig, DEFAULTS, control_period=1e-3, model='SQ', free=('M', 'CJ'))
    assert d.verdict == '' and d.best.fault == 'leakage_growth' and d.p_value > 0.01
    assert d.confidence == 0.9
    # every other hypothesis fits far worse: no rival, only the fault SQ cannot hypothesise
    assert d.rivals == [] and d.also_consistent_with == ['clearance_growth'] and all(
        c.score - d.best.score >= 10 for c in d.candidates[1:])


@pytest.mark.slow
def test_the_model_form_term_makes_the_interval_hold_the_truth():
    """SQ reads HD's leakage low (the model's bias): the noise-only interval misses the truth
    on these units, the calibrated one holds it, and is wider."""
    held = {True: 0, False: 0}
    for seed in (901, 902, 903, 904):
        sig, truth, _ = unit_signals('leakage_growth', 0.6, 'paper', seed, noise_gain=0.5)
        for mf in (True, False):
            d = diagnose(sig, DEFAULTS, control_period=1e-3, model='SQ', free=('M', 'CJ'),
                         faults=['leakage_growth'], model_form=mf)
            lo, hi = d.best.interval
            held[mf] += lo <= truth <= hi
    print(held)
    assert held[True] >= 3 and held[False] <= 1



def test_a_linear_bias_per_scenario_is_recovered():
    """Errors in g that grow with the estimate, 0.1 + 0.2 (g - g0), on one scenario, and a
    constant -0.05 on another: each scenario's own entry has its line, the pooled entry a
    constant, and a flight of neither falls back to the pooled one."""
    rng = np.random.default_rng(4)
    rec = []
    for scen in ('steps', 'paper'):
        for _ in range(200):
            truth = float(np.exp(rng.uniform(0.5, 3.0)))
            g = math.log(truth)
            e = (0.1 + 0.2 * (g - 1.75)) if scen == 'steps' else -0.05
            e += rng.normal(0.0, 0.01)
            rec.append(dict(fault='leakage_growth', truth=truth, named='leakage_growth',
                            estimate=truth * math.exp(e), se=0.0, rms=1.0, scenario=scen))
    cal = fit_calibration(rec)
    own = cal['by_scenario']['steps']['leakage_growth']
    assert own['slope'] == pytest.approx(0.2 / 1.2, abs=0.01)      # per g(estimate)
    g_est = 3.0 + 0.1 + 0.2 * (3.0 - 1.75)
    assert calibration.bias_at(own, g_est) == pytest.approx(g_est - 3.0, abs=0.01)
    assert cal['by_scenario']['paper']['leakage_growth']['slope'] == pytest.approx(0, abs=0.01)
    assert calibration.fault_calibration(cal, 'leakage_growth', 'paper')['bias'] == \
        pytest.approx(-0.05, abs=0.005)
    assert calibration.resolve_entry(cal, 'leakage_growth', 'eval') == (
        dict(cal['faults']['leakage_growth'], scored=cal['faults']['leakage_growth']['pinned']),
        calibration.POOLED)
    # a scenario's own spread stands alone on 200 units; on nine it is never narrower than
    # the pooled one (nine units do not pin it)
    pooled = cal['faults']['leakage_growth']['sigma']
    own_sigma = cal['by_scenario']['steps']['leakage_growth']['sigma']
    assert own_sigma < pooled
    assert calibration.fault_calibration(cal, 'leakage_growth', 'steps')['sigma'] == own_sigma
    few = fit_calibration([r for r in rec if r['scenario'] == 'paper']
                          + [r for r in rec if r['scenario'] == 'steps'][:9])
    assert few['by_scenario']['steps']['leakage_growth']['units'] == 9
    assert calibration.fault_calibration(few, 'leakage_growth', 'steps')['sigma'] == \
        few['faults']['leakage_growth']['sigma']


def test_a_bias_that_changes_sign_with_the_severity_follows_it_on_the_built_in_test():
    """Static friction on the built-in test as SQ reads it: 20 % low up to 4.5 x, 15 % high at
    20 x (in g: -0.22 and +0.14). The built-in test's own entry (units spread between the
    levels) follows it; a line through both would miss each end by ~0.1."""
    rng = np.random.default_rng(5)
    rec = []
    for _ in range(30):
        for g_true, e in ((rng.uniform(0.8, 1.6), -0.22), (rng.uniform(2.9, 3.1), 0.14)):
            truth = float(np.exp(g_true))
            rec.append(dict(fault='static_friction', truth=truth, named='static_friction',
                            estimate=truth * math.exp(e + rng.normal(0, 0.01)), se=0.01,
                            rms=1.0, scenario='bit'))
    own = fit_calibration(rec)['by_scenario']['bit']['static_friction']
    assert calibration.bias_at(own, 1.0) == pytest.approx(-0.22, abs=0.01)
    assert calibration.bias_at(own, 3.14) == pytest.approx(0.14, abs=0.01)
    assert own['sigma'] < 0.03


def test_the_bias_near_the_verdict_floor_counts_the_units_called_healthy():
    """A leak read more low the milder it is (error -0.2 + 0.1*g in g = ln s) on a flight with
    units spread across the floor; a unit is named only where it reads at least g = 0.5. The
    bias at the floor is that of every unit's fit, -0.1364 there (hand: g_est = 1.1 g - 0.2 =
    0.5 at g = 0.6364); over the named units alone the kernel sees only those above and
    reads about -0.115 -- the truncation that called leaks beyond the stated limit healthy.
    The spread is scored on the named units only (the answers an interval is stated for)."""
    rng = np.random.default_rng(9)
    rec = []
    for _ in range(400):
        g = rng.uniform(0.2, 1.5)
        e = -0.2 + 0.1 * g + rng.normal(0.0, 0.002)
        rec.append(dict(fault='leakage_growth', truth=float(np.exp(g)),
                        named='leakage_growth' if g + e >= 0.5 else None,
                        estimate=float(np.exp(g + e)), se=0.0, rms=1.0, scenario='paper'))
    own = fit_calibration(rec)['by_scenario']['paper']['leakage_growth']
    assert calibration.bias_at(own, 0.5) == pytest.approx(-0.1364, abs=0.004)
    assert own['units'] == sum(r['named'] is not None for r in rec) < own['fitted'] == 400
    # left out: a unit whose fit is not recorded (an older record), and one whose right
    # hypothesis stayed at healthy while another fault took the run (it found no leak)
    rec.append(dict(fault='leakage_growth', truth=2.0, named=None, rms=1.0, scenario='paper'))
    rec.append(dict(fault='leakage_growth', truth=2.0, named='supply_loss', estimate=1.0,
                    se=0.01, rms=1.0, scenario='paper'))
    assert fit_calibration(rec)['by_scenario']['paper']['leakage_growth']['fitted'] == 400


def test_a_kernel_bias_is_scored_on_units_it_was_not_fitted_to():
    """Eight units 0.6 apart in g (twice the bandwidth), errors alternating +-0.1: a kernel
    through them nearly interpolates each one, so its spread must come from each unit left
    out (then the neighbours say -0.1 where it is +0.1: ~0.2), not from its own fit."""
    rec = [dict(fault='static_friction', truth=float(np.exp(0.5 + 0.6 * i)),
                named='static_friction', estimate=float(np.exp(0.5 + 0.6 * i + e)), se=0.0,
                rms=1.0, scenario='bit') for i, e in enumerate([0.1, -0.1] * 4)]
    own = fit_calibration(rec)['by_scenario']['bit']['static_friction']
    assert Z90 * own['sigma'] > 0.15


def test_a_fit_that_does_not_pin_its_severity_widens_its_own_interval_not_every_one():
    """Forty units pinned to +-0.01 and twenty on a flat likelihood (their own se 0.3, their
    errors twice that): the model-form spread stays that of the pinned ones, and the others'
    own standard error is scaled by ~2 to hold them at the conformal rank."""
    rng = np.random.default_rng(6)
    rec = []
    for i in range(60):
        flat = i % 3 == 0
        se = 0.3 if flat else 0.005
        e = rng.normal(0.0, 2 * se if flat else 0.01)
        truth = float(np.exp(rng.uniform(0.5, 3.0)))
        rec.append(dict(fault='static_friction', truth=truth, named='static_friction',
                        estimate=truth * math.exp(e), se=se, rms=1.0))
    c = fit_calibration(rec)['faults']['static_friction']
    assert c['pinned'] == 40 and c['sigma'] < 0.025
    assert 1.5 < c['k'] < 3.0
    held = [abs(math.log(r['estimate'] / r['truth']) - c['bias'])
            <= Z90 * calibration.spread_of(c, r['se']) for r in rec]
    assert sum(held) >= 54


def test_the_extra_units_leave_the_first_ones_and_spread_between_the_levels():
    jobs = calibration_set.calibration_jobs(2, 7)
    per_round = 1 + len(DIAGNOSABLE) * len(LEVELS)
    first = 2 * len(calibration_set.CAL_SCENARIOS) * per_round
    extra_end = first + sum(calibration_set.EXTRA_UNITS.values()) * per_round
    assert all(j[1] <= 1.0 for j in jobs[:extra_end]) and jobs[extra_end][1] > 1.0
    # the first units: the levels, seeds in sequence, whatever the extra ones are
    assert [j[3] for j in jobs] == [7 * 1_000_003 + k for k in range(len(jobs))]
    assert {j[1] for j in jobs[:first] if j[0]} == set(LEVELS)
    extra = [j for j in jobs[first:extra_end] if j[0]]
    assert all(calibration_set.EXTRA_RANGE[j[2]][0] <= j[1] <= calibration_set.EXTRA_RANGE[j[2]][1]
               for j in extra)
    assert len({j[1] for j in extra}) > len(extra) // 2
    # the paper flight's extra units reach below the verdict floor
    assert min(j[1] for j in extra if j[2] == 'paper') < 0.2


def test_units_past_the_alarm_value_come_last_and_reach_the_catalogs_end():
    """The catalog's end in fractions of the way to the alarm value (hand values: a leak's
    100 x against 10 x is ln 100 / ln 10 = 2; a supply loss's 0.9 against 0.3 is 3; a null
    bias ends at its alarm value); the units past it are appended to both sets (the units
    before keep their seeds), each fault whose catalog goes past its alarm value on every
    calibration flight (on every onset flight), between the alarm value and the end."""
    assert calibration_set.end_level('leakage_growth') == pytest.approx(2.0)
    assert calibration_set.end_level('supply_loss') == pytest.approx(3.0)
    assert calibration_set.end_level('null_bias') == pytest.approx(1.0)
    assert calibration_set.end_level('static_friction') == pytest.approx(
        math.log(50) / math.log(20))
    beyond = [f for f in DIAGNOSABLE if calibration_set.end_level(f) > 1.0]
    assert 'null_bias' not in beyond and len(beyond) == len(DIAGNOSABLE) - 1
    for jobs, flights, units in (
            (calibration_set.calibration_jobs(2, 7), calibration_set.CAL_SCENARIOS,
             calibration_set.PAST_UNITS),
            (calibration_set.onset_jobs(2, 7), calibration_set.ONSET_SCENARIOS,
             calibration_set.PAST_ONSET_UNITS)):
        n = units * len(flights) * len(beyond)
        past, before = jobs[-n:], jobs[:-n]
        assert all(j[1] <= 1.0 for j in before)
        assert sorted({j[2] for j in past}) == sorted(flights)
        for f in beyond:
            qs = [j[1] for j in past if j[0] == f]
            assert len(qs) == units * len(flights)
            assert all(1.0 <= q < calibration_set.end_level(f) for q in qs)
            assert all(FAULTS[f].lo <= severity_at(f, q) <= FAULTS[f].hi for q in qs)


def _leak(rng, g_truth: float, err: float, **kw) -> dict:
    return dict(fault='leakage_growth', truth=math.exp(g_truth), named='leakage_growth',
                estimate=math.exp(g_truth + err + rng.normal(0.0, 0.003)), se=0.0, rms=1.0,
                **kw)


def test_the_error_past_the_alarm_value_is_a_line_from_it_and_moves_nothing_else():
    """Units up to a leak's alarm value (10 x) read -0.05 in g; those past it a further
    -0.2 per unit of g their estimate lies past it. The entry ``past`` has that slope, from
    the correction the entries up to the alarm value make, through 0 at the alarm value, and
    a spread that barely grows past it (the deviations are the noise's); the other entries are
    those of the units up to the alarm value alone. An estimate short of the alarm value is
    not corrected further; past it by 0.5 in g it is, by -0.1, its spread grown by the rate
    times 0.5; either side of the alarm value the answer is continuous."""
    from servovalve_twin.prognostics.modelform import model_form_estimate
    rng = np.random.default_rng(11)
    ga = math.log(10.0)
    rec = [_leak(rng, rng.uniform(0.5, ga), -0.05, level=0.5) for _ in range(60)]
    past = []
    for _ in range(30):
        gt = rng.uniform(ga, 2 * ga)
        # g_est - g_truth = -0.05 - 0.2 (g_est - ga), solved for g_est
        ge = (gt - 0.05 + 0.2 * ga) / 1.2
        past.append(_leak(rng, gt, ge - gt, level=1.5))
    cal = fit_calibration(rec + past)
    p = cal['past']['leakage_growth']
    assert p['slope'] == pytest.approx(-0.2, abs=0.01)
    assert p['rate'] < 0.02 and p['units'] == 30
    plain = fit_calibration(rec)
    assert cal['faults'] == plain['faults'] and 'past' not in plain
    c = cal['faults']['leakage_growth']
    assert calibration.past_correction(cal, 'leakage_growth', ga - 0.1, c) == (0.0, c)
    further, wide = calibration.past_correction(cal, 'leakage_growth', ga + 0.5, c)
    assert further == pytest.approx(-0.1, abs=0.005)
    assert wide['sigma'] == pytest.approx(math.hypot(c['sigma'], 0.5 * p['rate']))
    below, above = (model_form_estimate(cal, 'leakage_growth', s, (s - 0.01, s + 0.01))[:2]
                    for s in (10.0 - 1e-6, 10.0 + 1e-6))
    assert above[0] == pytest.approx(below[0], rel=1e-5)
    assert above[1] == pytest.approx(below[1], rel=1e-5)
    far = model_form_estimate(cal, 'leakage_growth', 10.0 * math.exp(0.5), (16.0, 17.0))[0]
    assert math.log(far) == pytest.approx(ga + 0.5 + 0.05 + 0.1, abs=0.01)


def test_an_onset_answer_past_the_alarm_value_has_its_own_entry():
    """Onset units past a leak's alarm value, refitted at their onset, read -0.4 per unit of
    g past it (from the start: -0.2): the entry ``past_onset`` has their slope, ``past`` the
    from-start units' alone; an onset answer takes ``past_onset`` where the calibration has
    one for its fault, else ``past``; onset units whose answer kept the fit from the start
    are left out."""
    rng = np.random.default_rng(12)
    ga = math.log(10.0)

    def past_unit(slope, **kw):
        gt = rng.uniform(ga, 2 * ga)
        ge = (gt - 0.05 + slope * ga) / (1 + slope)
        return _leak(rng, gt, ge - gt, level=1.5, **kw)
    rec = [_leak(rng, rng.uniform(0.5, ga), -0.05, level=0.5, scenario='paper')
           for _ in range(60)]
    rec += [past_unit(0.2, scenario='paper') for _ in range(20)]
    onset = [_leak(rng, rng.uniform(0.5, ga), -0.05, level=0.5, scenario='paper',
                   refitted=True, widen=1.0) for _ in range(20)]
    onset += [past_unit(0.4, scenario='paper', refitted=True, widen=1.0) for _ in range(8)]
    onset += [past_unit(3.0, scenario='paper', refitted=False, widen=None) for _ in range(8)]
    cal = fit_calibration(rec, onset)
    assert cal['past']['leakage_growth']['slope'] == pytest.approx(-0.2, abs=0.01)
    assert cal['past_onset']['leakage_growth']['slope'] == pytest.approx(-0.4, abs=0.01)
    assert cal['past_onset']['leakage_growth']['units'] == 8
    c = cal['faults']['leakage_growth']
    assert calibration.past_correction(cal, 'leakage_growth', ga + 0.5, c, onset=True)[0] == \
        pytest.approx(-0.2, abs=0.01)
    assert calibration.past_correction(cal, 'leakage_growth', ga + 0.5, c)[0] == \
        pytest.approx(-0.1, abs=0.005)
    del cal['past_onset']['leakage_growth']
    assert calibration.past_correction(cal, 'leakage_growth', ga + 0.5, c, onset=True)[0] == \
        pytest.approx(-0.1, abs=0.005)


def test_an_answer_past_the_alarm_value_is_tested_against_every_right_fit():
    """The goodness-of-fit reference of an answer past its alarm value holds the right fits
    past it with those up to it; up to it, those alone (hand count: 2.5 has 2 of 4 fits as
    bad or worse, p = 3/5; 0 of 2, p = 1/3)."""
    cal = {'rms': [1.0, 2.0], 'past_rms': [1.0, 2.0, 3.0, 4.0]}
    assert gof_p_value(cal, 2.5, past=True) == pytest.approx(3 / 5)
    assert gof_p_value(cal, 2.5) == pytest.approx(1 / 3)
    assert gof_p_value({'rms': [1.0, 2.0]}, 2.5, past=True) == pytest.approx(1 / 3)


def test_the_onset_entries_come_from_refitted_onset_units_and_nothing_else():
    """Onset units whose answer was refitted at an onset give the entries ``onset:paper``
    (error -0.2 in g) and ``onset:bit`` (+0.1) and, pooled, ``onset``; those that kept the
    from-start fit (error +0.5) are left out, and no onset unit moves the pooled or a
    scenario's entry. The interval factor is each entry's split-conformal rank of the named
    units' needed factors (hand-counted: rank ceil(0.9 * 21) = 19 of 20)."""
    rng = np.random.default_rng(8)

    def unit(e, **kw):
        truth = float(np.exp(rng.uniform(0.5, 2.0)))
        return dict(fault='leakage_growth', truth=truth, named='leakage_growth',
                    estimate=truth * math.exp(e + rng.normal(0.0, 0.01)), se=0.0, rms=1.0,
                    **kw)
    rec = [unit(0.0, scenario='paper') for _ in range(50)]
    onset = ([unit(-0.2, scenario='paper', refitted=True, widen=1.0 + k) for k in range(20)]
             + [unit(0.1, scenario='bit', refitted=True, widen=10.0 + k) for k in range(20)]
             + [unit(0.5, scenario='paper', refitted=False, widen=None) for _ in range(30)])
    # a wrongly named unit's onset says nothing of the named fault's interval
    onset.append(dict(onset[0], named='supply_loss', widen=1e6))
    cal = fit_calibration(rec, onset)
    by = cal['by_scenario']
    assert by['onset:paper']['leakage_growth']['units'] == 20
    assert by['onset:paper']['leakage_growth']['bias'] == pytest.approx(-0.2, abs=0.01)
    assert by['onset:bit']['leakage_growth']['bias'] == pytest.approx(0.1, abs=0.01)
    assert by['onset:paper']['leakage_growth']['sigma'] < 0.05
    # pooled: both flights' units, a spread covering both biases
    assert by['onset']['leakage_growth']['units'] == 40
    assert by['onset']['leakage_growth']['sigma'] > 0.1
    assert cal['onset_widen'] == {'onset:paper': 19.0, 'onset:bit': 28.0,
                                  'onset': sorted([1.0 + k for k in range(20)]
                                                  + [10.0 + k for k in range(20)])[36]}
    plain = fit_calibration(rec)
    assert cal['faults'] == plain['faults']
    assert cal['by_scenario']['paper'] == plain['by_scenario']['paper']
    assert not any(k.startswith('onset') for k in plain['by_scenario'])
    assert plain['onset_widen'] == {}


def test_an_onset_flight_without_enough_units_falls_back_to_the_onset_entry():
    """An onset flight's own entry, on fewer than OWN_UNITS units, takes the larger spread of
    its own and the pooled onset entry's -- not the from-start pooled one's -- and a flight
    without onset units takes the pooled onset entry and its factor."""
    from servovalve_twin.prognostics.rules import onset_entry
    line = dict(bias=0.0, slope=0.0, g0=0.0, k=1.0)
    cal = dict(faults={'leakage_growth': dict(line, sigma=0.5, units=99)},
               by_scenario={'onset': {'leakage_growth': dict(line, sigma=0.2, units=40)},
                            'onset:bit': {'leakage_growth': dict(line, sigma=0.1,
                                                                 units=12)}},
               onset_widen={'onset': 3.0, 'onset:bit': 2.0})
    assert calibration.fault_calibration(cal, 'leakage_growth', 'onset:bit')['sigma'] == 0.2
    assert calibration.fault_calibration(cal, 'leakage_growth', 'onset')['sigma'] == 0.2
    assert onset_entry(cal, 'bit') == 'onset:bit'
    assert onset_entry(cal, 'sine_opposing') == 'onset' == onset_entry(cal, None)
    assert calibration.onset_widen(cal, 'onset:bit') == 2.0
    assert calibration.onset_widen(cal, onset_entry(cal, 'my_flight')) == 3.0
    assert calibration.onset_widen(None, 'onset') == 1.0


def test_the_factor_an_onset_interval_needs_against_a_hand_count():
    """A cost of 100 at 0.3 s, 105 at 0.2, 115 at 0.4, 200 at 0.1, 300 at 0.5, a width of 0.1:
    the instants bracketing the lowest cost, [0.2, 0.4], hold 0.35 at any factor (0); 0.15
    needs 0.2 inside, 105 <= 100 (1 + 0.1 f): f = 0.5 exactly -- below 1, the factor is not
    floored at the noise's width; 0.45 needs 0.4 inside: f = 1.5; 0.05 needs 0.1 inside (f =
    10)."""
    profile = dict(costs={'0.1': 200.0, '0.2': 105.0, '0.3': 100.0, '0.4': 115.0,
                          '0.5': 300.0}, rss=100.0, width=0.1)
    assert calibration_set.widen_needed(profile, (0.0, 1.0), 0.35) == 0.0
    assert calibration_set.widen_needed(profile, (0.0, 1.0), 0.15) == pytest.approx(0.5, abs=1e-9)
    assert calibration_set.widen_needed(profile, (0.0, 1.0), 0.45) == pytest.approx(1.5, abs=1e-9)
    assert calibration_set.widen_needed(profile, (0.0, 1.0), 0.05) == pytest.approx(10.0, abs=1e-8)


def test_onset_units_draw_severities_and_onsets_of_their_own():
    """The onset units: every diagnosable fault per round and flight (more on the built-in
    test), severities between the levels, onsets inside the window of each flight (the
    built-in test is 2 s), seeds apart from the calibration set's; then those past the alarm
    value (their own test)."""
    everyone = calibration_set.onset_jobs(3, 7)
    jobs = [j for j in everyone if j[1] <= 1.0]
    assert everyone[:len(jobs)] == jobs
    assert len(jobs) == sum(3 + calibration_set.ONSET_EXTRA.get(scen, 0)
                            for scen in calibration_set.ONSET_SCENARIOS) * len(DIAGNOSABLE)
    assert [j[0] for j in jobs[:len(DIAGNOSABLE)]] == list(DIAGNOSABLE)
    lo, hi = calibration_set.ONSET_WINDOW
    for scen in calibration_set.ONSET_SCENARIOS:
        some = [j for j in jobs if j[2] == scen]
        duration = 2.0 if scen == 'bit' else 1.0
        assert len(some) == (3 + calibration_set.ONSET_EXTRA.get(scen, 0)) * len(DIAGNOSABLE)
        assert all(LEVELS[0] <= j[1] <= 1.0 and lo * duration <= j[4] <= hi * duration
                   for j in some)
    # the extra units come after the first ones, whose seeds do not depend on them
    assert [j[3] for j in everyone] == [7 * 1_000_003 + 500_000 + k
                                        for k in range(len(everyone))]
    assert [j[2] for j in jobs] == sorted((j[2] for j in jobs),
                                          key=calibration_set.ONSET_SCENARIOS.index)
    assert max(j[4] for j in jobs) > 1.0                   # the built-in test's own window
    assert len({j[4] for j in jobs}) == len(jobs)
    seeds = {j[3] for j in calibration_set.calibration_jobs(4, 7)}
    assert not seeds & {j[3] for j in everyone}
    assert len({j[3] for j in everyone}) == len(everyone)


def test_a_bag_is_matched_to_its_calibration_scenario_by_its_inputs():
    from servovalve_twin.apps.diagnose import calibration_scenario
    from servovalve_twin.bag.provenance import Provenance
    from servovalve_twin.config import load_scenario
    from servovalve_twin.physics.params import DEFAULTS
    from servovalve_twin.physics.scenario import scenario_from_dict
    bit = load_scenario('bit')
    assert calibration_scenario(Provenance.build('HD', bit, DEFAULTS, 1e-3)) == 'bit'
    # renamed, with a fault scheduled: the same flight
    raw = dict(bit.to_dict(), name='my_test', faults=[dict(at=0.0, fault='null_bias',
                                                           severity=-1e-3)])
    assert calibration_scenario(Provenance.build('HD', scenario_from_dict(raw), DEFAULTS,
                                                 1e-3)) == 'bit'
    # another flight: none
    raw = dict(bit.to_dict(), fr=[[0.0, 0.0]])
    assert calibration_scenario(Provenance.build('HD', scenario_from_dict(raw), DEFAULTS,
                                                 1e-3)) is None


def test_sensors_outside_the_calibrated_domain_are_named():
    """Each departure named once, on the compared signals only: XJ noise 5 x the documented
    10 um (the domain is 0.5-2 x), a DXJ bias, a P12 quantised in 0.2 MPa steps (coarser than
    its 50 kPa noise) sampled every 2 ms; XS (not compared), in-domain noise and a bias (which
    the fit applies) say nothing."""
    from servovalve_twin.physics.sensors import sensors_from_dict
    sensors = sensors_from_dict({'xj': {'noise': 5.0e-5, 'bias': 1e-5}, 'dxj': {'drift': 1e-3},
                                 'p12': {'noise': 5.0e4, 'quantisation': 2.0e5,
                                         'period': 0.002},
                                 'xs': {'noise': 1.0, 'bias': 1.0}})
    got = calibration.sensor_warnings(sensors, 1e-3)
    assert len(got) == 4, got
    assert 'the xj sensor\'s noise is 5 x the documented level' in got[0]
    assert got[1].startswith('the dxj sensor drifts')
    assert 'quantised in steps of 200000' in got[2]
    assert 'samples every 0.002 s' in got[3]
    ideal = sensors_from_dict({'xj': {'noise': 2.0e-5}, 'p12': {'noise': 2.5e4}})
    assert calibration.sensor_warnings(ideal, 1e-3) == []
    assert calibration.sensor_warnings(None, 1e-3) == []
