"""The paper's explicit simplified fluid-dynamic models (doc/design/MODELS.md section 2).

Every function has the registry's shared signature ``(xs, qj, psr, P, vs) -> p12``:

:param xs: spool displacement XS [m] (> 0 opens supply->1 and 2->return)
:param qj: working flow QJ = AJ*DXJ [m^3/s]
:param psr: supply-return pressure PSR = PS - PR [Pa], time-varying
:param P: :class:`~servovalve_twin.physics.params.KernelParams`
:param vs: valve state vector (:mod:`..valve_state`); these models neither read nor write it
:returns: P12 = P1 - P2 [Pa]

``U = PSR*XS/XSS - GPQ*QJ`` is the paper's undamped pressure with the flow feedback; ``k =
CLk*GPQ`` is the gain of the leakage loop, whose instantaneous form is solved in closed form
(the ``/(1 + k)``) because evaluated with the previous P12 it diverges for k > 1 (Figs. 6-7).
"""

from ...jitcache import jit

from ..valve_state import V_CALLS, V_ITER, V_ITSUM, V_MAXITER, V_NONCONV, V_P12


@jit(inline='always')
def sat(u, lim):
    """sat(u, L) = max(-L, min(L, u))."""
    if u > lim:
        return lim
    if u < -lim:
        return -lim
    return u


@jit
def linear(xs, qj, psr, P, vs):
    """Fig. 4: P12 = GPN*XS - GPQ*QJ. Never stalls, ignores PSR."""
    return P.GPN * xs - P.GPQ * qj


@jit
def saturated(xs, qj, psr, P, vs):
    """Fig. 5: P12 = sat(GPN*XS, PSR) - GPQ*QJ. Clamping upstream of the flow feedback caps the
    no-load flow at GQ*XSS: the fully-open rate is badly underestimated."""
    return sat(P.GPN * xs, psr) - P.GPQ * qj


@jit
def saturated_downstream(xs, qj, psr, P, vs):
    """Fig. 11 (Borello & Villero): P12 = sat(GPN*XS - GPQ*QJ, PSR)."""
    return sat(P.GPN * xs - P.GPQ * qj, psr)


@jit
def linear_leakage(xs, qj, psr, P, vs):
    """Figs. 6-8: P12 = (GPN*XS - GPQ*QJ)/(1 + k), the leakage loop solved."""
    return (P.GPN * xs - P.GPQ * qj) / (1.0 + P.k)


@jit
def model_a(xs, qj, psr, P, vs):
    """Fig. 9 (MODEL A): P12 = U/(1 + k), pressure gain scaled with PSR, no saturation."""
    return (psr * xs / P.XSS - P.GPQ * qj) / (1.0 + P.k)


@jit
def model_b(xs, qj, psr, P, vs):
    """Fig. 10 (MODEL B): P12 = (sat(PSR*XS/XSS, PSR) - GPQ*QJ)/(1 + k)."""
    return (sat(psr * xs / P.XSS, psr) - P.GPQ * qj) / (1.0 + P.k)


@jit
def model_c1(xs, qj, psr, P, vs):
    """Fig. 12 (MODEL C1): P12 = sat(U, PSR)/(1 + k); |P12| <= PSR/(1 + k) = PSR*."""
    return sat(psr * xs / P.XSS - P.GPQ * qj, psr) / (1.0 + P.k)


@jit
def model_c2(xs, qj, psr, P, vs):
    """Fig. 13 (MODEL C2): P12 = sat(U/(1 + k), PSR); |P12| <= PSR for any CLk."""
    return sat((psr * xs / P.XSS - P.GPQ * qj) / (1.0 + P.k), psr)


@jit
def model_c3(xs, qj, psr, P, vs):
    """Figs. 14-15, eqs. 2-7 (MODEL C3): P12 = sat(U, PSR)/(1 + k*XSS/max(|XS|, XSS)).

    The leakage divisor fades with spool opening beyond XSS: C1 near null, C2 at full stroke.
    """
    ax = abs(xs)
    return sat(psr * xs / P.XSS - P.GPQ * qj, psr) / (1.0 + P.k * P.XSS / max(ax, P.XSS))


@jit
def model_c4(xs, qj, psr, P, vs):
    """Figs. 16-17 (MODEL C4): the fixed point of P12 = sat(U - k*P12, PSR), found by the
    paper's pseudo-dynamic short run ``p <- p + alpha*(sat(U - k*p, PSR) - p)`` from the previous
    step's P12, until |dp| < C4_tol or C4_max_iter iterations.

    It is computed by iteration on purpose (never by calling C2): its fixed point equals C2
    exactly, which the tests check. The iteration count goes to ``vs[V_ITER]``; a call that hits
    the cap is counted in ``vs[V_NONCONV]`` (reported by the run, never hidden).
    """
    u = psr * xs / P.XSS - P.GPQ * qj
    k = P.k
    alpha = P.C4_alpha
    p = vs[V_P12]
    n_max = int(P.C4_max_iter)
    it = 0
    converged = False
    while it < n_max:
        it += 1
        dp = alpha * (sat(u - k * p, psr) - p)
        p += dp
        if abs(dp) < P.C4_tol:
            converged = True
            break
    vs[V_P12] = p
    vs[V_ITER] = it
    if it > vs[V_MAXITER]:
        vs[V_MAXITER] = it
    if not converged:
        vs[V_NONCONV] += 1
    vs[V_CALLS] += 1
    vs[V_ITSUM] += it
    return p


def naive_leakage_loop(xs, qj, P, n_steps, p12_0=0.0):
    """Figs. 6-7 written as an instantaneous loop evaluated with the previous P12,
    ``P12 <- GPN*XS - GPQ*(QJ + CLk*P12)``, iterated ``n_steps`` times (plain Python, for the
    test that shows why the solved form of Fig. 8 is used: it oscillates, diverging for k > 1).
    """
    p = p12_0
    out = []
    for _ in range(n_steps):
        p = P.GPN * xs - P.GPQ * (qj + P.CLk * p)
        out.append(p)
    return out


def c4_info(vs):
    """Diagnostics of C4's last call: iterations of its short run, calls that hit the cap."""
    return dict(iterations=int(vs[V_ITER]), nonconverged_calls=int(vs[V_NONCONV]))
