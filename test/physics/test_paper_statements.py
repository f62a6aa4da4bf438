"""The paper's statements (MODELS.md section 7), checked on the paper scenario against HD.
Each test prints what it measured; partial agreements are reported as such."""

import numpy as np
import pytest

from servovalve_twin.apps.compare import error_metrics
from servovalve_twin.physics.params import DEFAULTS
from servovalve_twin.apps.report import back_movement
from conftest import cached_run

C_MODELS = ('C1', 'C2', 'C3', 'C4')
HIGH_CLK = 2e-12                  # ten times the paper's leakage


def err(model, window, signal='xj', stat='rms', clk=None):
    ref, run = cached_run('HD', clk), cached_run(model, clk)
    w = ref.scenario.windows
    return error_metrics(ref.signals, run.signals, {window: w[window]})[window][signal][stat]


def test_1_unloaded_and_aiding_runs_close_to_hd():
    for m in C_MODELS:
        e1, e3 = err(m, 'run1', stat='max'), err(m, 'run3', stat='max')
        print(f'{m}: max |XJ - XJ_HD| run 1 = {e1 * 1e3:.3f} mm, run 3 = {e3 * 1e3:.3f} mm')
        assert e1 < 1e-3
    # run 3 holds only loosely for C1 (its over-stall excursion is still being recovered)
    for m in ('C2', 'C3', 'C4'):
        assert err(m, 'run3', stat='max') < 2e-3
    hd, c2 = cached_run('HD'), cached_run('C2')
    w = hd.window(0.75, 0.85)
    v_hd, v_c2 = hd['dxj'][w].min(), c2['dxj'][w].min()
    print(f'run 3 peak speed: HD {v_hd * 1e3:.1f} mm/s, C2 {v_c2 * 1e3:.1f} mm/s '
          f'({(abs(v_c2) / abs(v_hd) - 1) * 100:+.1f} %)')


def test_2_opposing_load_run_too_fast():
    hd = cached_run('HD')
    w = hd.window(0.30, 0.35)
    v_hd = hd['dxj'][w].mean()
    for m in C_MODELS:
        v = cached_run(m)['dxj'][w].mean()
        print(f'run 2 mean speed {m}: {v * 1e3:.1f} mm/s vs HD {v_hd * 1e3:.1f} mm/s')
        if m != 'C1':
            assert v > 1.3 * v_hd
    # C1 is the exception: its clamp PSR* = PSR/(1 + k) leaves it little force beyond the load,
    # so it runs slower than HD here (reported above, not asserted)


def test_3_overstall_back_movement_overestimated_with_constant_acceleration():
    hd = cached_run('HD')
    b_hd = back_movement(hd)
    for m in C_MODELS:
        r = cached_run(m)
        b = back_movement(r)
        # back acceleration: slope of DXJ over the drop once the spool is at its stop
        w = r.window(0.37, 0.44)
        t, v = r['t'][w], r['dxj'][w]
        fit = np.polyfit(t, v, 1)
        resid = np.max(np.abs(np.polyval(fit, t) - v)) / np.ptp(v)
        print(f'{m}: back movement {b * 1e3:.2f} mm (HD {b_hd * 1e3:.2f} mm); drop DXJ linear '
              f'fit: acceleration {fit[0]:.3f} m/s^2, worst residual {resid:.3%} of its span')
        assert b > 1.5 * b_hd
        if m != 'C3':          # C3's divisor changes with |XS| as the spool moves: near-constant
            assert resid < 0.05
    w = hd.window(0.37, 0.44)
    fit = np.polyfit(hd['t'][w], hd['dxj'][w], 1)
    resid_hd = np.max(np.abs(np.polyval(fit, hd['t'][w]) - hd['dxj'][w])) / np.ptp(hd['dxj'][w])
    print(f'HD: back movement {b_hd * 1e3:.2f} mm, linear-fit residual {resid_hd:.1%} '
          '(flow-damped, not constant acceleration)')
    assert resid_hd > 0.1


def test_4_clamped_pressure_versus_asymptotic_approach():
    hd, c2 = cached_run('HD'), cached_run('C2')
    w = hd.window(0.30, 0.35)
    psr = c2['psr'][w]
    clamped = np.mean(np.abs(c2['p12'][w]) >= psr * (1 - 1e-12))
    clamped_hd = np.mean(np.abs(hd['p12'][w] - psr) < 1e3)
    print(f'run 2 (0.30-0.35 s): C2 holds P12 at the PSR clamp for {clamped:.0%} of the rows, '
          f'HD for {clamped_hd:.0%}')
    assert clamped > 0.3 and clamped_hd < 0.05


@pytest.mark.parametrize('clk', [None, HIGH_CLK])
def test_5_error_ranking_under_opposing_load_and_overstall(clk):
    e = {m: err(m, 'overstall', clk=clk) for m in ('C1', 'C2', 'C3')}
    print(f'CLk = {clk or DEFAULTS.CLk:g}: XJ rms error over 0.35-0.50 s '
          + ', '.join(f'{m} {v * 1e3:.2f} mm' for m, v in e.items()))
    assert e['C2'] < e['C3'] < e['C1']


def test_5_errors_of_c1_c3_grow_with_leakage_c2_does_not():
    growth = {m: err(m, 'overstall', clk=HIGH_CLK) / err(m, 'overstall') for m in
              ('C1', 'C2', 'C3')}
    print('XJ rms error growth over 0.35-0.50 s when CLk x 10: '
          + ', '.join(f'{m} x{g:.2f}' for m, g in growth.items()))
    assert growth['C1'] > 1.2 and growth['C3'] > 1.2
    assert growth['C2'] < min(growth['C1'], growth['C3'])


def test_6_hd_brakes_above_psr_c_models_capped_and_brake_softer():
    """Partial agreement: HD brakes above PSR and the C-models are capped at PSR and brake
    more softly (lower peak deceleration), but with these parameters they do not stop *later*
    than HD -- HD's run-3 speed is higher (statement 1), so it has more to shed. Measured and
    printed, the stop times are not asserted."""
    hd = cached_run('HD')
    w = hd.window(0.75, 0.85)

    def braking(r):
        t, v = r['t'][w], r['dxj'][w]
        i_peak = np.argmax(np.abs(v))
        after = np.nonzero(np.abs(v[i_peak:]) < 0.01)[0]
        t_stop = t[i_peak + after[0]] if after.size else np.inf     # not stopped by 0.85 s
        return r['p12'][w].max(), np.max(np.diff(v)) / 1e-3, t_stop
    peak_hd, decel_hd, t_hd = braking(hd)
    print(f'HD: peak P12 after 0.75 s {peak_hd / 1e6:.2f} MPa (PSR 20 MPa), peak braking '
          f'deceleration {decel_hd:.2f} m/s^2, |DXJ| < 10 mm/s at {t_hd:.3f} s')
    assert peak_hd > 20e6 * 1.05
    for m in C_MODELS:
        peak, decel, ts = braking(cached_run(m))
        print(f'{m}: peak P12 {peak / 1e6:.2f} MPa, peak deceleration {decel:.2f} m/s^2, '
              f'stops at {ts:.3f} s')
        assert peak <= 20e6 + 1.0
        assert decel < 0.8 * decel_hd


@pytest.mark.parametrize('clk', [None, HIGH_CLK])
def test_7_bounds_along_the_run(clk):
    p = DEFAULTS.replace(CLk=clk or DEFAULTS.CLk)
    c1, c2, c3 = (cached_run(m, clk) for m in ('C1', 'C2', 'C3'))
    assert np.all(np.abs(c2['p12']) <= c2['psr'])
    assert np.all(np.abs(c1['p12']) <= c1['psr'] / (1 + p.k) * (1 + 1e-12))
    assert np.all(np.abs(c3['p12']) <= c3['psr'] * (1 + 1e-12))
    print(f'k = {p.k:.3f}: max |P12|/PSR  C1 {np.max(np.abs(c1["p12"]) / c1["psr"]):.3f} '
          f'(PSR* = {1 / (1 + p.k):.3f}), C2 {np.max(np.abs(c2["p12"]) / c2["psr"]):.3f}, '
          f'C3 {np.max(np.abs(c3["p12"]) / c3["psr"]):.3f}')


def test_8_c4_gives_c2_at_a_higher_cost():
    c2, c4 = cached_run('C2'), cached_run('C4')
    d = np.max(np.abs(c4['xj'] - c2['xj']))
    calls = c4.info['valve_calls']
    print(f'max |XJ(C4) - XJ(C2)| = {d:.2e} m; C4 needs up to {c4.info["max_iterations"]} '
          f'iterations per step over {calls} steps (C2: one closed-form evaluation)')
    assert d <= 1e-9 and c4.info['max_iterations'] > 1


def test_9_saturated_b_linear_models():
    hd = cached_run('HD')
    w = hd.window(0.0, 0.2)
    v_hd = hd['dxj'][w].max()
    gq_xss = DEFAULTS.gpn / DEFAULTS.gpq * DEFAULTS.xss / DEFAULTS.AJ    # GQ*XSS/AJ [m/s]
    for m in ('saturated', 'B'):
        v = cached_run(m)['dxj'][w].max()
        print(f'{m}: no-load peak speed {v * 1e3:.1f} mm/s <= GQ*XSS/AJ = {gq_xss * 1e3:.1f} mm/s'
              f' (HD {v_hd * 1e3:.1f} mm/s)')
        assert v <= gq_xss * 1.001 and v < 0.25 * v_hd
    sd = cached_run('saturated_downstream')
    v = sd['dxj'][w].max()
    print(f'saturated_downstream: no-load peak {v * 1e3:.1f} mm/s; max |P12|/PSR '
          f'{np.max(np.abs(sd["p12"]) / sd["psr"]):.3f}')
    assert v == pytest.approx(v_hd, rel=0.05)
    assert np.all(np.abs(sd['p12']) <= sd['psr'])
    for m in ('linear', 'linear_leakage', 'A'):
        r = cached_run(m)
        b = back_movement(r)
        p_drop = r['p12'][r.window(0.35, 0.45)].max()
        print(f'{m}: back movement {b * 1e3:.2f} mm, max P12 in the drop {p_drop / 1e6:.1f} MPa '
              '(PSR 12 MPa)')
        assert b < 1e-4 and p_drop > 12e6


def test_10_c2_most_accurate_of_the_papers_simplified_models():
    simplified = ('linear', 'saturated', 'saturated_downstream', 'linear_leakage', 'A', 'B',
                  'C1', 'C2', 'C3')
    for window in ('all', 'overstall'):
        e = {m: (err(m, window) if window != 'all' else _err_all(m)) for m in simplified}
        best = min(e, key=e.get)
        print(f'XJ rms error, {window}: ' + ', '.join(f'{m} {v * 1e3:.2f}' for m, v in
                                                      sorted(e.items(), key=lambda x: x[1])))
        assert best == 'C2'


def _err_all(m):
    ref, run = cached_run('HD'), cached_run(m)
    return error_metrics(ref.signals, run.signals, {})['all']['xj']['rms']
