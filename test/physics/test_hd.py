"""The HD reference against theory: Merritt's critical-centre valve, the null pressure gain,
calibration, over-pressure, cavitation, the compressible variant."""

import math

import numpy as np
import pytest

from servovalve_twin.physics.valves.calibration import calibrate
from servovalve_twin.physics.valves.hd import hd_ports
from servovalve_twin.physics.params import DEFAULTS
from servovalve_twin.runs import simulate
from servovalve_twin.physics.valves import VALVE_MODELS


@pytest.mark.parametrize('c', [1e-6, 1e-7, 1e-8])
def test_approaches_merritt_critical_centre_as_clearance_vanishes(c):
    p = DEFAULTS.replace(CLk=0.0, c=c)
    psr = 20e6
    worst = 0.0
    for xs in (2e-5, 6e-5, 1.5e-4):
        for frac in (0.0, 0.3, 0.6, 0.9):
            qj = frac * p.Cd * p.w * xs * math.sqrt(psr / p.rho)
            p12 = hd_ports(xs, qj, psr, p)[0]
            merritt = psr - p.rho * qj ** 2 / (p.Cd * p.w * xs) ** 2
            worst = max(worst, abs(p12 - merritt) / psr)
    print(f'c = {c:g} m: worst |P12 - Merritt|/PSR = {worst:.2e}')
    assert worst < 3 * c / 2e-5      # the clearance adds (c/x)^2-order corrections


def test_null_pressure_gain_matches_the_laminar_formula():
    p = DEFAULTS.replace(CLk=0.0)
    psr = 20e6
    h = 1e-10
    gp0 = (hd_ports(h, 0.0, psr, p)[0] - hd_ports(-h, 0.0, psr, p)[0]) / (2 * h)
    expected = 12 * p.mu * p.Cd * math.sqrt(psr / p.rho) / p.c ** 2
    print(f'HD null pressure gain {gp0:.4e} Pa/m; 12*mu*Cd*sqrt(PSR/rho)/c^2 = {expected:.4e}')
    assert gp0 == pytest.approx(expected, rel=0.01)
    assert expected == pytest.approx(2.73e11, rel=0.01)


def test_calibration_reproduces_the_defaults_file():
    cal = calibrate(DEFAULTS)
    print(cal)
    assert cal['XSS'] == pytest.approx(DEFAULTS.xss, rel=1e-9)
    assert cal['GPQ'] == pytest.approx(DEFAULTS.gpq, rel=1e-9)
    assert cal['XSS'] == pytest.approx(1.74e-5, rel=0.01)
    assert cal['GPN'] == pytest.approx(1.15e12, rel=0.01)
    assert cal['GQN'] == pytest.approx(1.112, rel=0.01)
    assert cal['k'] == pytest.approx(0.207, rel=0.01)


def test_derived_constants_follow_the_design_never_stale():
    """XSS and GPQ not given are HD's calibration of the design at hand: more clearance, a
    softer null (XSS 1.49 x); a larger valve at 28 MPa its own -- each what calibrate()
    gives; a design that differs in anything HD does not see (mass, friction, the
    compressible option) keeps the default's; given values are kept. Stale constants made
    a healthy unit of a larger actuator read as a 0.147 gain loss."""
    wider = DEFAULTS.replace(c=1.0e-5)
    assert wider.xss > DEFAULTS.xss * 1.2                      # more clearance: softer null
    for design in (wider, DEFAULTS.replace(PSRN=2.8e7, w=2.0e-2, XSM=2.5e-4)):
        cal = calibrate(design)
        assert (design.xss, design.gpq) == (cal['XSS'], cal['GPQ'])
        assert design.resolved()['XSS'] == cal['XSS'] and design.k == design.CLk * cal['GPQ']
        assert design.kernel().XSS == cal['XSS'] and design.kernel().GPQ == cal['GPQ']
    same = DEFAULTS.replace(M=900.0, FSJ=400.0, compressible=True, beta=1e9)
    assert (same.xss, same.gpq) == (DEFAULTS.xss, DEFAULTS.gpq)
    given = wider.replace(XSS=2.0e-5, GPQ=1.1e12)
    assert (given.xss, given.gpq) == (2.0e-5, 1.1e12)


def test_over_pressure_when_the_load_drives_the_flow():
    # spool open towards +XJ but the jack pushed the other way (QJ < 0): port 1 is pumped
    p12, p1, p2, _ = hd_ports(3e-5, -8e-5, 20e6, DEFAULTS)
    print(f'P1 = {p1:.4e} Pa, PS = {20e6 + DEFAULTS.PR:.4e} Pa, P12 = {p12:.4e} Pa')
    assert p1 > 20e6 + DEFAULTS.PR and p12 > 20e6


def test_cavitation_is_clamped_and_flagged():
    p12, state, info = VALVE_MODELS['HD'](-1.5e-4, 1.2e-4, 20e6, DEFAULTS)
    assert info['cavitation'] & 1 and info['p1'] == DEFAULTS.Pcav


def test_asymmetric_laps_shift_the_null():
    p = DEFAULTS.replace(CLk=0.0, L_S1=2e-6, L_2R=2e-6, L_S2=-2e-6, L_1R=-2e-6)
    assert hd_ports(0.0, 0.0, 20e6, p)[0] < -1e6       # underlapped S2/1R edges drive P12 < 0


def test_compressible_variant_tracks_the_incompressible_one():
    inc = simulate('HD', 'paper')
    com = simulate('HD', 'paper', {'compressible': True})
    d = np.abs(com['xj'] - inc['xj'])
    print(f'compressible vs incompressible HD: max |dXJ| = {d.max() * 1e3:.3f} mm, '
          f'peak P12 {com["p12"].max() / 1e6:.2f} vs {inc["p12"].max() / 1e6:.2f} MPa')
    assert d.max() < 2e-3
    assert not np.array_equal(com['p12'], inc['p12'])


def _edge_flow(x, dp, p):
    """An edge's flow, written from MODELS.md section 3 independently of the compiled solver:
    orifice (opening from corner to bore) in series with a laminar gap when covered,
    dp = R_l*Q + R_t*Q*|Q| solved by the quadratic formula."""
    if x >= -p.r:
        d = math.hypot(x + p.r, p.c + p.r) - p.r
        gap = 0.0
    else:
        d, gap = p.c, -x - p.r
    rl = 12.0 * p.mu * gap / (p.w * p.c ** 3)
    rt = p.rho / (2.0 * (p.Cd * p.w * d) ** 2)
    a = abs(dp)
    q = a / rl if rt == 0 else (-rl + math.sqrt(rl * rl + 4.0 * rt * a)) / (2.0 * rt)
    return math.copysign(q, dp)


def _continuity(xs, qj, psr, p, p1, p2):
    ps, pr = psr + p.PR, p.PR
    leak = p.CLk * (p1 - p2)
    f1 = _edge_flow(xs - p.L_S1, ps - p1, p) - _edge_flow(-xs - p.L_1R, p1 - pr, p) - qj - leak
    f2 = _edge_flow(-xs - p.L_S2, ps - p2, p) - _edge_flow(xs - p.L_2R, p2 - pr, p) + qj + leak
    return f1, f2


@pytest.mark.parametrize('xs, frac', [(0.0, 0.0), (3e-6, 0.0), (2e-5, 0.4), (1.5e-4, 0.8),
                                      (-6e-5, -0.5), (1e-5, -0.3)])
def test_port_pressures_satisfy_both_continuity_equations(xs, frac):
    """HD's converged P1, P2 against the continuity equations evaluated independently: both
    residuals vanish to 1e-9 of the largest edge flow; and, leak-free (the ports decouple), P1
    equals a 200-step bisection of port 1's own equation to 1 Pa."""
    psr = 20e6
    for clk in (DEFAULTS.CLk, 0.0):
        p = DEFAULTS.replace(CLk=clk, L_S1=2e-6, L_2R=-1e-6)        # laps make it asymmetric
        qj = frac * p.Cd * p.w * max(abs(xs), 1e-5) * math.sqrt(psr / p.rho)
        _, p1, p2, vs = hd_ports(xs, qj, psr, p)
        if vs[6]:                                  # a cavitating port is clamped, not solved
            continue
        scale = p.Cd * p.w * p.XSM * math.sqrt(2 * psr / p.rho)
        f1, f2 = _continuity(xs, qj, psr, p, p1, p2)
        print(f'XS={xs:g} QJ={qj:.3g} CLk={clk:g}: P1={p1:.6g} P2={p2:.6g} residuals '
              f'{f1 / scale:.1e} {f2 / scale:.1e}')
        assert abs(f1) < 1e-9 * scale and abs(f2) < 1e-9 * scale
        if clk == 0.0:
            lo, hi = p.PR - psr, p.PR + 3 * psr            # over-pressure allowed
            for _ in range(200):
                mid = 0.5 * (lo + hi)
                if _continuity(xs, qj, psr, p, mid, p2)[0] > 0:
                    lo = mid
                else:
                    hi = mid
            assert p1 == pytest.approx(0.5 * (lo + hi), abs=1.0)


@pytest.mark.parametrize('c', [1e-8, 1e-9])
def test_a_critical_centre_characteristic_sweeps_to_merritt(c):
    """c -> 0 with no leakage, swept through ``characteristic`` (each point warm-started from
    the last, as a test bench sweeps): a port reaches supply pressure exactly, where an open
    edge's flow was 0/0 (ZeroDivisionError). Blocked load: P12 = sign(XS)*PSR within 1 %
    of PSR away from the null, 0 at it; with a load flow: Merritt's PS - rho (QL/(Cd w XS))^2
    where that is a pressure the valve can hold."""
    from servovalve_twin.physics.characteristic import characteristic
    p = DEFAULTS.replace(CLk=0.0, c=c)
    psr = 20e6
    q = 0.3 * p.Cd * p.w * 1e-4 * math.sqrt(psr / p.rho)
    out = characteristic('HD', p, psr, [0.0, q], n_points=101)
    assert not np.isnan(out['p12']).any()
    xs, qj, p12 = out['xs'], out['qj'], out['p12']
    blocked = (qj == 0.0) & (np.abs(xs) > 1e-6)
    assert np.max(np.abs(p12[blocked] - np.sign(xs[blocked]) * psr)) < 0.01 * psr
    assert p12[(qj == 0.0) & (xs == 0.0)] == pytest.approx(0.0, abs=1e-6 * psr)
    with np.errstate(divide='ignore'):
        merritt = psr - p.rho * q ** 2 / (p.Cd * p.w * xs) ** 2
    held = (qj == q) & (xs > 0) & (merritt > -psr)
    assert held.sum() > 20
    assert np.max(np.abs(p12[held] - merritt[held])) < 0.01 * psr


@pytest.mark.slow
def test_every_model_at_every_parameter_bound_answers_or_refuses():
    """Each float parameter at its lower (just inside an open one) and upper bound, one at a
    time, through ``characteristic`` and a 50 ms ``simulate`` of every valve model: a result
    or a one-line TwinError, never another exception (1752 runs, 51 s here)."""
    from servovalve_twin.errors import TwinError
    from servovalve_twin.physics.characteristic import characteristic
    from servovalve_twin.physics.params import param_table
    scen = {'duration': 0.05, 'com': [[0.0, 0.02]], 'fr': [[0.0, 0.0], [0.02, 5000.0]],
            'psr': [[0.0, 2.0e7], [0.04, 1.5e7]]}
    ran = 0
    for row in param_table():
        if row['kind'] != 'float':
            continue
        lo, hi = row['lo'], row['hi']
        for v in (hi, lo + 1e-9 * (hi - lo) if row['lo_open'] else lo):
            try:
                p = DEFAULTS.replace(**{row['name']: v})
            except TwinError:
                continue            # a cross-parameter rule refuses it: that is an answer
            for model in VALVE_MODELS:
                for run in (lambda: characteristic(model, p, min(p.PSRN, 3e7), [0.0],
                                                   n_points=21),
                            lambda: simulate(model, scen, params=p)):
                    try:
                        run()
                    except TwinError:
                        pass
                    ran += 1
    assert ran > 1000
