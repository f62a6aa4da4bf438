"""Closed forms of the simplified models, their bounds, C4 = C2, and the naive leakage loop."""

import numpy as np
import pytest

from servovalve_twin.physics.params import DEFAULTS
from servovalve_twin.physics.valves import VALVE_MODELS
from servovalve_twin.physics.valves.simplified import naive_leakage_loop
from conftest import cached_run
from test_valve_contract import random_points


def sat(u, lim):
    return np.clip(u, -lim, lim)


def closed_forms(p):
    """MODELS.md section 2, written independently of the implementation."""
    gpn, gpq, k, xss = p.PSRN / p.xss, p.gpq, p.CLk * p.gpq, p.xss

    def u(xs, qj, psr):
        return psr * xs / xss - gpq * qj
    return {
        'linear': lambda xs, qj, psr: gpn * xs - gpq * qj,
        'saturated': lambda xs, qj, psr: sat(gpn * xs, psr) - gpq * qj,
        'saturated_downstream': lambda xs, qj, psr: sat(gpn * xs - gpq * qj, psr),
        'linear_leakage': lambda xs, qj, psr: (gpn * xs - gpq * qj) / (1 + k),
        'A': lambda xs, qj, psr: u(xs, qj, psr) / (1 + k),
        'B': lambda xs, qj, psr: (sat(psr * xs / xss, psr) - gpq * qj) / (1 + k),
        'C1': lambda xs, qj, psr: sat(u(xs, qj, psr), psr) / (1 + k),
        'C2': lambda xs, qj, psr: sat(u(xs, qj, psr) / (1 + k), psr),
        'C3': lambda xs, qj, psr: sat(u(xs, qj, psr), psr) / (1 + k * xss / max(abs(xs), xss)),
        'C4': lambda xs, qj, psr: sat(u(xs, qj, psr) / (1 + k), psr),   # its fixed point
    }


@pytest.mark.parametrize('clk', [0.0, 2e-13, 2e-12, 1e-11])
@pytest.mark.parametrize('name', list(closed_forms(DEFAULTS)))
def test_closed_form_at_random_points(name, clk):
    # at large k the short run contracts slowly (by k/(1+k) per pass): give it room to converge
    p = DEFAULTS.replace(CLk=clk, C4_max_iter=100_000)
    ref = closed_forms(p)[name]
    # the short run stops when |dp| < tol; in saturation it contracts by k/(1+k), so its
    # distance to the fixed point is at most about k*tol
    tol = 2 * p.C4_tol * (1 + p.k) if name == 'C4' else 0.0
    for xs, qj, psr in zip(*random_points(200, seed=3)):
        got = VALVE_MODELS[name](xs, qj, psr, p)[0]
        assert got == pytest.approx(ref(xs, qj, psr), rel=1e-12, abs=tol + 1e-6)


@pytest.mark.parametrize('clk', [0.0, 2e-13, 1e-12, 1e-11])
def test_bounds(clk):
    """C2, C4 |P12| <= PSR for any CLk; C1 <= PSR/(1+k); C3 in between."""
    p = DEFAULTS.replace(CLk=clk)
    k = p.k
    for xs, qj, psr in zip(*random_points(300, seed=4)):
        c1 = abs(VALVE_MODELS['C1'](xs, qj, psr, p)[0])
        c2 = abs(VALVE_MODELS['C2'](xs, qj, psr, p)[0])
        c3 = abs(VALVE_MODELS['C3'](xs, qj, psr, p)[0])
        c4 = abs(VALVE_MODELS['C4'](xs, qj, psr, p)[0])
        assert c2 <= psr and c4 <= psr + 2 * p.C4_tol * (1 + k)
        assert c1 <= psr / (1 + k) * (1 + 1e-12)
        c3_cap = psr / (1 + k * p.xss / max(abs(xs), p.xss))
        assert c3 <= c3_cap * (1 + 1e-12)
        assert psr / (1 + k) <= c3_cap * (1 + 1e-12) and c3_cap <= psr


def test_c4_equals_c2_at_random_points_and_counts_iterations():
    p = DEFAULTS.replace(CLk=1e-12)
    state = None
    iters = []
    for xs, qj, psr in zip(*random_points(500, seed=5)):
        c4, state, info = VALVE_MODELS['C4'](xs, qj, psr, p, state)
        c2 = VALVE_MODELS['C2'](xs, qj, psr, p)[0]
        assert abs(c4 - c2) <= 2 * p.C4_tol * (1 + p.k)
        iters.append(info['iterations'])
    assert info['nonconverged_calls'] == 0
    print('C4 iterations per call: mean', np.mean(iters), 'max', max(iters))
    assert max(iters) > 1


def test_c4_nonconvergence_is_reported_not_hidden():
    p = DEFAULTS.replace(C4_max_iter=2, C4_tol=1e-9, CLk=1e-12)
    _, state, info = VALVE_MODELS['C4'](1e-4, 0.0, 20e6, p)    # saturated: contracts by k/(1+k)
    assert info['nonconverged_calls'] == 1 and info['iterations'] == 2


def test_c4_equals_c2_over_the_paper_scenario():
    c2, c4 = cached_run('C2'), cached_run('C4')
    d = np.max(np.abs(c4['xj'] - c2['xj']))
    print(f'max |XJ(C4) - XJ(C2)| over the paper scenario: {d:.3e} m; C4 '
          f'{c4.info["max_iterations"]} iterations at most, '
          f'{c4.info["nonconverged_calls"]} non-converged calls')
    assert d <= 1e-9
    assert c4.info['nonconverged_calls'] == 0


def test_naive_leakage_loop_diverges_for_k_above_1_solved_form_does_not():
    p = DEFAULTS.replace(CLk=1.5 / DEFAULTS.gpq)             # k = 1.5
    xs, qj = 5e-6, 0.0
    naive = naive_leakage_loop(xs, qj, p.kernel(), 40)
    solved = VALVE_MODELS['linear_leakage'](xs, qj, 20e6, p)[0]
    print(f'k = {p.k}: naive loop after 40 passes {naive[-1]:.3e} Pa; solved {solved:.3e} Pa')
    assert abs(naive[-1]) > 1e6 * abs(solved)
    assert np.all(np.sign(naive[1:]) != np.sign(naive[:-1]))    # it oscillates
    # for k < 1 the same loop converges to the solved form
    p = DEFAULTS.replace(CLk=0.5 / DEFAULTS.gpq)
    naive = naive_leakage_loop(xs, qj, p.kernel(), 200)
    assert naive[-1] == pytest.approx(VALVE_MODELS['linear_leakage'](xs, qj, 20e6, p)[0])
