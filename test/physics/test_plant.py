"""EHA plant blocks: servovalve steady state and stops, stick/slip, end stops, DT convergence,
sampled ECU, determinism."""

import numpy as np
import pytest

from servovalve_twin.errors import ParameterError
from servovalve_twin.physics.params import DEFAULTS
from servovalve_twin.physics.simulate import EhaPlant
from servovalve_twin.runs import simulate
from conftest import cached_run


def hold(com=0.0, fr=0.0, psr=20e6, duration=0.3):
    return {'duration': duration, 'com': [[0.0, com]], 'fr': [[0.0, fr]], 'psr': [[0.0, psr]]}


def test_servovalve_steady_state_and_end_of_travel():
    plant = EhaPlant('C2', DEFAULTS.replace(FSJ=1e7, FDJ=1e7))      # jack locked by friction
    for _ in range(50):
        plant.tick(0.004, 0.0, 20e6, 100)
    # XS = GM*Cor/KFB at steady state
    assert plant.xs == pytest.approx(DEFAULTS.gm * 0.004 / DEFAULTS.KFB, rel=1e-6)
    for _ in range(50):
        plant.tick(0.05, 0.0, 20e6, 100)                  # beyond full current: spool stop
    assert plant.xs == DEFAULTS.XSM


def test_stick_then_slip_at_the_static_friction():
    # a load below FSJ with the valve centred: the jack must not creep
    r = simulate('C2', hold(fr=250.0), {'GAP': 1e-9})
    assert np.all(r['xj'] == 0.0) and np.all(r['dxj'] == 0.0)
    # above FSJ it breaks away, against the load's direction sign (FR > 0 pushes towards -XJ)
    r = simulate('C2', hold(fr=350.0), {'GAP': 1e-9})
    assert r['xj'][-1] < -1e-4
    print(f'FR = 350 N > FSJ: XJ(0.3 s) = {r["xj"][-1] * 1e3:.3f} mm')


def test_moving_jack_stops_instead_of_chattering():
    # coasting against dynamic friction only: the velocity reaches exactly 0 and stays there
    plant = EhaPlant('linear', DEFAULTS.replace(GAP=1e-9, CJ=0.0, GPQ=1e-3))
    plant.s[4] = 0.01                                       # DXJ = 10 mm/s, P12 ~ 0
    for _ in range(100):
        plant.tick(0.0, 0.0, 20e6, 100)
    assert plant.dxj == 0.0
    # m*v/FDJ = 500*0.01/200 = 25 ms of coasting: x = v^2*m/(2*FDJ) = 0.125 mm
    assert plant.xj == pytest.approx(0.01 ** 2 * 500 / (2 * 200), rel=0.01)


def test_end_stops():
    r = simulate('C2', hold(com=0.5, duration=1.0))
    assert r['xj'].max() == DEFAULTS.XJM
    at_stop = r['xj'] == DEFAULTS.XJM
    assert np.all(r['dxj'][at_stop] == 0.0)


def test_halving_dt_barely_changes_the_run():
    for model in ('C2', 'HD'):
        a = cached_run(model)
        b = simulate(model, 'paper', {'DT': 5e-6})
        d = np.max(np.abs(a['xj'] - b['xj']))
        print(f'{model}: max |XJ(DT) - XJ(DT/2)| = {d * 1e3:.4f} mm')
        assert d < 1e-4


def test_sampled_ecu_is_close_to_continuous():
    a = cached_run('C2')
    b = simulate('C2', 'paper', ecu_period=1e-3)
    d = np.max(np.abs(a['xj'] - b['xj']))
    print(f'ECU sampled at 1 ms vs continuous: max |dXJ| = {d * 1e3:.3f} mm')
    assert 0 < d < 1e-3
    # Cor is held over the period: constant within each 1 ms of a 0.1 ms-sampled output? rows
    # are 1 ms apart, so check the hold through the tick API instead
    with pytest.raises(Exception, match='multiple of DT'):
        simulate('C2', 'paper', ecu_period=1.5e-5)


def test_runs_are_deterministic():
    a = simulate('HD', 'paper')
    b = simulate('HD', 'paper')
    for c in a.columns:
        np.testing.assert_array_equal(a[c], b[c])


def test_eha_plant_tick_equals_simulate_with_sampled_ecu():
    ref = simulate('C4', 'paper', ecu_period=1e-3)
    plant = EhaPlant('C4', DEFAULTS)
    com, fr, psr = ref['com'], ref['fr'], ref['psr']
    xj = [plant.xj]
    for i in range(len(com) - 1):
        cor = plant.control(com[i], plant.xj)
        plant.tick(cor, fr[i], psr[i], 100)
        xj.append(plant.xj)
    assert np.max(np.abs(np.array(xj) - ref['xj'])) == 0.0


def test_model_switch_keeps_mechanical_state():
    plant = EhaPlant('C2', DEFAULTS)
    for _ in range(30):
        plant.tick(plant.control(0.02, plant.xj), 0.0, 20e6, 100)
    before = plant.s.copy()
    plant.set_valve_model('HD')
    np.testing.assert_array_equal(plant.s, before)
    out = plant.tick(plant.control(0.02, plant.xj), 0.0, 20e6, 100)
    assert np.isfinite(out[2]) and plant.xj > before[3]


def test_ecu_current_saturates_at_corm_and_never_beyond(runs):
    """Cor = sat(GAP*(Com - XJ), CorM): the paper's 10 mm command step asks for 16.9 mA, so
    the ECU must sit at CorM = 10 mA, and never above it, whatever the valve model."""
    for name in ('C2', 'HD'):
        cor = runs[name]['cor']
        assert np.max(np.abs(cor)) == DEFAULTS.CorM
        assert np.count_nonzero(np.abs(cor) == DEFAULTS.CorM) > 10
    err = runs['HD']['com'] - runs['HD']['xj']
    inside = np.abs(DEFAULTS.GAP * err) < DEFAULTS.CorM
    np.testing.assert_allclose(runs['HD']['cor'][inside], DEFAULTS.GAP * err[inside],
                               rtol=1e-12, atol=0.0)


def test_first_stage_step_response_against_the_closed_form():
    """The two-stage servovalve, linear range: MF*XF'' + CF*XF' + (KF + KFB)*XF = GM*Cor -
    KFB*XS, XS' = (GQF/AS)*XF -- a third-order system solved exactly by its matrix exponential
    (numpy eigendecomposition) and compared with the compiled stage stepped at DT = 1e-7 s.
    Dropping the flapper from the feedback spring (KFB*XS instead of KFB*(XS + XF)) or the
    damping moves the response far outside the tolerance."""
    from servovalve_twin.physics.servovalve import S_SIZE, S_XF, S_XS, servovalve_step
    p = DEFAULTS.replace(DT=1e-7)
    cor = 2e-3                                    # XS -> 3e-5 m, XF peak well below XFM
    a = np.array([[0.0, 1.0, 0.0],
                  [-(p.KF + p.KFB) / p.MF, -p.CF / p.MF, -p.KFB / p.MF],
                  [p.GQF_AS, 0.0, 0.0]])
    b = np.array([0.0, p.gm * cor / p.MF, 0.0])
    lam, vec = np.linalg.eig(a)
    inv = np.linalg.inv(vec)
    x_ss = -np.linalg.solve(a, b)                 # the steady state: XS = GM*Cor/KFB, XF = 0
    assert x_ss[2] == pytest.approx(p.gm * cor / p.KFB, rel=1e-12)
    wn = np.sqrt((p.KF + p.KFB) / p.MF)
    print(f'flapper alone: wn = {wn:.0f} rad/s, zeta = '
          f'{p.CF / (2 * np.sqrt((p.KF + p.KFB) * p.MF)):.3f}; poles {np.sort_complex(lam)}')
    s = np.zeros(S_SIZE)
    k = p.kernel()
    worst_s = worst_f = 0.0
    n = 0
    for t_ms in (0.1, 0.2, 0.5, 1.0, 2.0, 5.0):
        while n * p.DT < t_ms * 1e-3 - 1e-15:
            servovalve_step(s, cor, k)
            n += 1
        exact = x_ss - (vec @ np.diag(np.exp(lam * n * p.DT)) @ inv @ x_ss).real
        worst_s = max(worst_s, abs(s[S_XS] - exact[2]) / x_ss[2])
        worst_f = max(worst_f, abs(s[S_XF] - exact[0]) / x_ss[2])
    print(f'|XS - exact| <= {worst_s:.2e}, |XF - exact| <= {worst_f:.2e} of the final XS')
    assert worst_s < 2e-3 and worst_f < 2e-3


def test_simulate_continues_from_a_given_plant_state():
    """``initial``: a jack already at the commanded 10 mm, at rest, with no load, stays there
    (row 0 holds exactly the given state; the loop has nothing to correct: XJ moves by less
    than a micrometre), where the same run from rest travels the 10 mm. An ignored or
    misplaced initial state fails both."""
    scn = {'duration': 0.05, 'com': [[0.0, 0.01]], 'fr': [[0.0, 0.0]], 'psr': [[0.0, 2.0e7]]}
    held = simulate('C2', scn, initial={'xj': 0.01})
    assert held['xj'][0] == 0.01 and held['dxj'][0] == 0.0
    assert np.max(np.abs(held['xj'] - 0.01)) < 1e-6
    assert simulate('C2', scn)['xj'][-1] > 0.005
    with pytest.raises(ParameterError, match='unknown plant state'):
        simulate('C2', scn, initial={'x': 0.0})


@pytest.mark.parametrize('severity', [0.0, 0.3, 0.55])
def test_a_supply_loss_lowers_the_supply_the_valve_sees(severity):
    """A jack held at its end stop by a load far beyond stall, the spool wide open: the
    `saturated` valve's P12 is then the supply it sees, PSR x (1 - s) -- 20, 14, 9 MPa. (A
    loop that ignored PSR_scale passed every physics test before this one.)"""
    from servovalve_twin.runs import simulate
    sc = {'duration': 0.3, 'com': [[0.0, 0.0], [0.01, 0.05]], 'fr': [[0.0, 0.0], [0.01, 1e6]],
          'psr': [[0.0, 2.0e7]],
          'faults': [{'at': 0.0, 'fault': 'supply_loss', 'severity': severity}]}
    r = simulate('saturated', sc, ecu_period=1e-3)
    assert r['xj'][-1] == pytest.approx(-DEFAULTS.XJM)
    np.testing.assert_allclose(r['p12'][-50:], 2.0e7 * (1.0 - severity), rtol=1e-9)


@pytest.mark.parametrize('severity', [0.0, 0.3, 0.6])
def test_a_torque_motor_gain_loss_takes_that_share_of_the_spool_s_stroke(severity):
    """The ECU saturated (a 90 mm step): full current gives full stroke, XSM, on a healthy
    valve (GM = KFB*XSM/CorM); a gain loss s leaves (1 - s) of it. (Declared a multiplier, the
    loss 0.3 made GM x 0.3, and the physics tests passed.)"""
    from servovalve_twin.runs import simulate
    sc = {'duration': 0.1, 'com': [[0.0, 0.0], [0.01, 0.09]], 'fr': [[0.0, 0.0]],
          'psr': [[0.0, 2.0e7]],
          'faults': [{'at': 0.0, 'fault': 'torque_motor_gain_loss', 'severity': severity}]}
    r = simulate('saturated', sc, ecu_period=1e-3)
    assert np.all(r['cor'][40:60] == DEFAULTS.CorM)
    # (the spool's first-order lag has settled to 3e-6 of it by then)
    np.testing.assert_allclose(r['xs'][40:60], DEFAULTS.XSM * (1.0 - severity), rtol=1e-5)


def test_a_plant_loads_its_tick_when_built_not_at_its_first_period(monkeypatch):
    """EhaPlant runs its model's tick once on copies of its state (EhaPlant.compile) when it
    is built and when it changes model: the loop is loaded (or compiled: seconds without the
    compiled module) before a node built on it says it has started, and a Ctrl-C is then not
    held up by a compile. The plant's own state is not touched."""
    from servovalve_twin.physics import simulate as sim
    calls = []

    def fake_tick_for(model_id):
        def tick(mid, s, vs, P, cor, fr, psr, n_sub, out):
            calls.append((mid, s, vs, n_sub, psr))
            return -1
        return tick
    monkeypatch.setattr(sim, 'tick_for', fake_tick_for)
    plant = sim.EhaPlant('C2')
    assert len(calls) == 1
    mid, s, vs, n_sub, psr = calls[0]
    assert psr == plant.params.PSRN and mid == plant.model.id
    assert s is not plant.s and vs is not plant.vs
    plant.set_valve_model('SQ')
    assert len(calls) == 2 and calls[1][0] == plant.model.id
