"""``HD``: the high-fidelity four-edge servovalve reference (doc/design/MODELS.md section 3) -- its
solver, its initial state, its hand-over when switched to mid-run and its diagnostics. The
calibration of the simplified models from it is :mod:`.calibration`.

Edges (lap L > 0 overlap, < 0 underlap): ``x_S1 = XS - L_S1``, ``x_2R = XS - L_2R``,
``x_S2 = -XS - L_S2``, ``x_1R = -XS - L_1R``. Each passage is a turbulent orifice of width w
and opening d (clearance c and corner radius r included) in series with a laminar gap of length
l when covered: ``dp = R_l*Q + R_t*Q*|Q|``, inverted in the cancellation-free form
``Q = sign(dp)*2|dp|/(R_l + sqrt(R_l^2 + 4*R_t*|dp|))``.

Port continuity (incompressible default) ``F1(P1, P2) = F2(P1, P2) = 0`` is solved by a 2x2
Newton (its Jacobian is exact and diagonally dominant: each F_i is strictly decreasing in P_i,
the leakage couples them by +CLk), with a bracketed per-port Gauss-Seidel fallback. It starts
from the line through the last two steps' port pressures, ``2*P[n-1] - P[n-2]`` (error O(DT^2)
where the last step's is O(DT)), and stops when the next Newton step is below ``_TOL`` or,
once converging quadratically, when the error it leaves, estimated as ``d^3/d_prev^2``, is:
2.26 Newton passes per step on the paper flight where the last step's pressures and
``|d| < _TOL`` took 2.73; against a solve to 1e-9 Pa, P12 within 2.7e-5 Pa on four built-in
flights where the old rule kept 4e-8 Pa (issue 22; doc/results/benchmarks.md). The
compressible option makes P1, P2 states and integrates them by backward Euler, which is the
same root problem with a capacitance V/(beta*DT) added to the diagonal -- so one solver serves
both, and the stiff laminar null does not limit DT.
Over-pressure (P_i > PS: reverse flow into supply) is allowed: it is how |P12| exceeds PSR when
the jack brakes or is over-run. A port below Pcav is clamped (a vapour cavity) and flagged.
"""

from __future__ import annotations

import math

import numpy as np
from ...jitcache import jit

from ...errors import ModelError
from ..params import EhaParams
from ..valve_state import (V_CALLS, V_CAV, V_FAIL, V_ITER, V_ITSUM, V_MAXITER, V_NCAV,
                           V_NONCONV, V_P1, V_P1_PREV, V_P2, V_P2_PREV, V_P12, V_XJ,
                           new_state)

_TOL = 1.0e-4          # Pa: the largest error a converged solve leaves (as estimated above)
_NEWTON_MAX = 60
_GS_MAX = 200
_G_CAP = 1.0e-3        # m^3/(s*Pa): caps dQ/ddp of a pure orifice at dp = 0 (infinite there)


@jit(inline='always')
def edge_resistances(x, P):
    """(R_l, R_t) of an edge with opening x [m]: laminar [Pa*s/m^3] and turbulent [Pa*s^2/m^6]."""
    r = P.r
    c = P.c
    if x >= -r:
        # open, or on the rounded corner: orifice opening from the land corner to the bore
        d = math.sqrt((x + r) ** 2 + (c + r) ** 2) - r
        ell = 0.0
    else:
        # covered: the radial clearance is the orifice and the overlap a laminar gap
        d = c
        ell = -x - r
    cwd = P.Cd * P.w * d
    return 12.0 * P.mu * ell / (P.w * c ** 3), P.rho / (2.0 * cwd * cwd)


@jit(inline='always')
def edge_flow(rl, rt, dp):
    """Flow [m^3/s] through an edge under dp [Pa] and its conductance dQ/ddp."""
    a = abs(dp)
    root = rl + math.sqrt(rl * rl + 4.0 * rt * a)
    # an open edge (no laminar gap, rl = 0) under no pressure drop passes nothing: 0/0 here
    # (a critical-centre valve's port at supply pressure) raised ZeroDivisionError
    q = 2.0 * a / root if root > 0.0 else 0.0
    den = rl + 2.0 * rt * q
    g = 1.0 / den if den > 1.0 / _G_CAP else _G_CAP
    if dp < 0.0:
        q = -q
    return q, g


@jit(inline='always')
def _port_residual(rli, rti, rlo, rto, ps, pr, b, gdiag, p):
    """F(p) = Q_in(PS - p) - Q_out(p - PR) + b - gdiag*p and dF/dp (< 0)."""
    qi, gi = edge_flow(rli, rti, ps - p)
    qo, go = edge_flow(rlo, rto, p - pr)
    return qi - qo + b - gdiag * p, -(gi + go + gdiag)


@jit
def _solve_port(rli, rti, rlo, rto, ps, pr, b, gdiag, p0, span):
    """Root of the strictly decreasing port residual by the Illinois method (regula falsi that
    halves a stale end), inside a bracket grown from the warm start ``p0`` in doubling steps.
    Derivative-free: the orifice law's infinite slope at dp = 0 cannot throw it off."""
    flo = _port_residual(rli, rti, rlo, rto, ps, pr, b, gdiag, p0)[0]
    if flo == 0.0:
        return p0, 1, True
    step = span
    n = 1
    if flo > 0.0:
        lo, hi = p0, p0 + step
        fhi = _port_residual(rli, rti, rlo, rto, ps, pr, b, gdiag, hi)[0]
        while fhi > 0.0:
            lo, flo = hi, fhi
            step *= 2.0
            hi = p0 + step
            fhi = _port_residual(rli, rti, rlo, rto, ps, pr, b, gdiag, hi)[0]
            n += 1
            if step > 1.0e12:
                return p0, n, False
    else:
        hi, fhi = p0, flo
        lo = p0 - step
        flo = _port_residual(rli, rti, rlo, rto, ps, pr, b, gdiag, lo)[0]
        while flo < 0.0:
            hi, fhi = lo, flo
            step *= 2.0
            lo = p0 - step
            flo = _port_residual(rli, rti, rlo, rto, ps, pr, b, gdiag, lo)[0]
            n += 1
            if step > 1.0e12:
                return p0, n, False
    side = 0
    p_prev = lo
    for _ in range(300):
        p = (lo * fhi - hi * flo) / (fhi - flo)
        if not (lo < p < hi):
            p = 0.5 * (lo + hi)
        f = _port_residual(rli, rti, rlo, rto, ps, pr, b, gdiag, p)[0]
        n += 1
        if f == 0.0 or hi - lo < _TOL or abs(p - p_prev) < 0.01 * _TOL:
            return p, n, True
        if f > 0.0:
            lo, flo = p, f
            if side == 1:
                fhi *= 0.5
            side = 1
        else:
            hi, fhi = p, f
            if side == -1:
                flo *= 0.5
            side = -1
        p_prev = p
    return p, n, False


@jit(inline='always')
def _continuity(p1, p2, ps, pr, qj, clk, c1, c2, p1_old, p2_old,
                rl_s1, rt_s1, rl_1r, rt_1r, rl_s2, rt_s2, rl_2r, rt_2r):
    """Port residuals F1, F2 [m^3/s] and minus their diagonal derivatives a1, a2 [m^3/(s*Pa)]."""
    qa, ga = edge_flow(rl_s1, rt_s1, ps - p1)
    qb, gb = edge_flow(rl_1r, rt_1r, p1 - pr)
    qc, gc = edge_flow(rl_s2, rt_s2, ps - p2)
    qd, gd = edge_flow(rl_2r, rt_2r, p2 - pr)
    leak = clk * (p1 - p2)
    f1 = qa - qb - qj - leak - c1 * (p1 - p1_old)
    f2 = qc - qd + qj + leak - c2 * (p2 - p2_old)
    return f1, f2, ga + gb + clk + c1, gc + gd + clk + c2


@jit
def hd_solve(xs, qj, psr, P, vs):
    """Port pressures (P1, P2) of the four-edge valve; updates the warm start and diagnostics
    in ``vs``. Returns P12 = P1 - P2 [Pa].

    A damped 2x2 Newton: the full step is taken when it lowers |F|, else halved (the orifice
    law's square root makes a plain Newton cycle around a root near dp = 0). Started from
    the extrapolation of the last two calls' port pressures (``vs`` keeps both; the last ones
    stay the backward-Euler state of the compressible option).
    """
    pr = P.PR
    ps = psr + pr
    rl_s1, rt_s1 = edge_resistances(xs - P.L_S1, P)
    rl_2r, rt_2r = edge_resistances(xs - P.L_2R, P)
    rl_s2, rt_s2 = edge_resistances(-xs - P.L_S2, P)
    rl_1r, rt_1r = edge_resistances(-xs - P.L_1R, P)
    clk = P.CLk
    p1 = vs[V_P1]
    p2 = vs[V_P2]
    if not (math.isfinite(p1) and math.isfinite(p2)):
        p1 = p2 = 0.5 * (ps + pr)
    # compressible: backward Euler adds C*(P - P_old), C = V/(beta*DT), to each port
    if P.compressible != 0.0:
        c1 = (P.V0 + P.AJ * vs[V_XJ]) / (P.beta * P.DT)
        c2 = (P.V0 - P.AJ * vs[V_XJ]) / (P.beta * P.DT)
    else:
        c1 = 0.0
        c2 = 0.0
    p1_old = p1
    p2_old = p2
    p1_prev = vs[V_P1_PREV]
    p2_prev = vs[V_P2_PREV]
    if math.isfinite(p1_prev) and math.isfinite(p2_prev):
        p1 = 2.0 * p1_old - p1_prev
        p2 = 2.0 * p2_old - p2_prev
    vs[V_FAIL] = 0.0
    ok = False
    it = 0
    taken = 0.0
    f1, f2, a1, a2 = _continuity(p1, p2, ps, pr, qj, clk, c1, c2, p1_old, p2_old, rl_s1, rt_s1,
                                 rl_1r, rt_1r, rl_s2, rt_s2, rl_2r, rt_2r)
    while it < _NEWTON_MAX:
        it += 1
        det = a1 * a2 - clk * clk
        d1 = (a2 * f1 + clk * f2) / det
        d2 = (clk * f1 + a1 * f2) / det
        # converged: this step is below _TOL, or -- after a full Newton step ``taken`` --
        # the error left after it, ~ dmax**2 * (dmax/taken**2) at quadratic convergence, is
        dmax = max(abs(d1), abs(d2))
        if dmax < _TOL or dmax * dmax * dmax < _TOL * taken * taken:
            p1 += d1
            p2 += d2
            ok = True
            break
        norm0 = f1 * f1 + f2 * f2
        lam = 1.0
        for _ in range(40):
            q1 = p1 + lam * d1
            q2 = p2 + lam * d2
            g1, g2, b1, b2 = _continuity(q1, q2, ps, pr, qj, clk, c1, c2, p1_old, p2_old,
                                         rl_s1, rt_s1, rl_1r, rt_1r, rl_s2, rt_s2, rl_2r, rt_2r)
            if g1 * g1 + g2 * g2 < norm0:
                break
            lam *= 0.5
        taken = 0.0 if lam < 1.0 else dmax      # a damped step says nothing of the rate
        p1, p2, f1, f2, a1, a2 = q1, q2, g1, g2, b1, b2
    if not ok:
        # bracketed per-port Gauss-Seidel: slower, but it cannot wander
        p1 = p1_old
        p2 = p2_old
        span = 0.05 * psr + 1.0e4
        for _ in range(_GS_MAX):
            p1n, n1, ok1 = _solve_port(rl_s1, rt_s1, rl_1r, rt_1r, ps, pr,
                                       -qj + clk * p2 + c1 * p1_old, clk + c1, p1, span)
            p2n, n2, ok2 = _solve_port(rl_s2, rt_s2, rl_2r, rt_2r, ps, pr,
                                       qj + clk * p1n + c2 * p2_old, clk + c2, p2, span)
            it += n1 + n2
            if not (ok1 and ok2):
                break
            done = abs(p1n - p1) < _TOL and abs(p2n - p2) < _TOL
            p1 = p1n
            p2 = p2n
            if done:
                ok = True
                break
    cav = 0
    if p1 < P.Pcav:
        p1 = P.Pcav
        cav += 1
    if p2 < P.Pcav:
        p2 = P.Pcav
        cav += 2
    vs[V_P1_PREV] = p1_old
    vs[V_P2_PREV] = p2_old
    vs[V_P1] = p1
    vs[V_P2] = p2
    vs[V_P12] = p1 - p2
    vs[V_ITER] = it
    if it > vs[V_MAXITER]:
        vs[V_MAXITER] = it
    vs[V_CAV] = cav
    if cav:
        vs[V_NCAV] += 1
    vs[V_CALLS] += 1
    vs[V_ITSUM] += it
    if not ok:
        vs[V_FAIL] = 1.0
    return p1 - p2


def hd_ports(xs: float, qj: float, psr: float, params: EhaParams,
             state: np.ndarray | None = None) -> tuple[float, float, float, np.ndarray]:
    """Static HD operating point from Python: (P12, P1, P2, state) [Pa]; raises on failure."""
    P = params.replace(compressible=False).kernel()
    vs = new_state(0.5 * (psr + 2 * params.PR)) if state is None else state.copy()
    p12 = hd_solve(float(xs), float(qj), float(psr), P, vs)
    if vs[V_FAIL]:
        raise ModelError(f'HD port continuity did not converge at XS={xs!r} m, QJ={qj!r} m^3/s,'
                         f' PSR={psr!r} Pa')
    return p12, vs[V_P1], vs[V_P2], vs


def hd_initial_state(params: EhaParams, xj: float = 0.0) -> np.ndarray:
    """HD at rest: both ports at (PS + PR)/2 = PR + PSRN/2 (P12 = 0), the Newton's warm start."""
    vs = new_state(params.PR + 0.5 * params.PSRN)
    vs[V_XJ] = xj
    return vs


def hd_handover(vs: np.ndarray, old_vs: np.ndarray, old_has_ports: bool) -> None:
    """Switched to HD mid-run: keep the last P12, and the port pressures when the model before
    had them (HD itself); otherwise the ports start from mid-pressure as at rest."""
    vs[V_P12] = old_vs[V_P12]
    if old_has_ports:
        vs[V_P1] = old_vs[V_P1]
        vs[V_P2] = old_vs[V_P2]
        vs[V_P1_PREV] = old_vs[V_P1_PREV]
        vs[V_P2_PREV] = old_vs[V_P2_PREV]


def hd_info(vs: np.ndarray) -> dict:
    """Diagnostics of HD's last call: Newton iterations, port pressures, cavitation flags."""
    return dict(iterations=int(vs[V_ITER]), nonconverged_calls=int(vs[V_NONCONV]),
                p1=float(vs[V_P1]), p2=float(vs[V_P2]), cavitation=int(vs[V_CAV]))
