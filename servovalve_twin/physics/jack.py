"""Hydraulic jack: M*D2XJ = AJ*P12 - FR - CJ*DXJ - FF, end stops at +-XJM
(doc/design/MODELS.md section 4).

Coulomb friction FF follows Borello & Dalla Vedova's stick/slip conditions, with the active force
FA = AJ*P12 - FR - CJ*DXJ:

1. at rest and |FA| <= FSJ: stays at rest (static friction balances FA);
2. at rest and |FA| > FSJ: breaks away, FF = FDJ*sign(FA);
3. moving: FF = FDJ*sign(DXJ);
4. moving, and the velocity would change sign within the step: it stops (DXJ = 0) and sticking is
   re-tested at the next step -- this is what makes a reversal pass through a real stop instead
   of chattering around zero.
"""

from ..jitcache import jit

from .servovalve import S_DXJ, S_XJ, end_of_travel


@jit(inline='always')
def jack_advance(x, v, p12, fr, P):
    """XJ, DXJ one DT later under P12 [Pa] and the external load FR [N] (> 0 opposes +XJ),
    from XJ = ``x``, DXJ = ``v`` (the step loops keep them in registers)."""
    dt = P.DT
    fa = P.AJ * p12 - fr - P.CJ * v
    if v == 0.0:
        if abs(fa) <= P.FSJ:
            v_new = 0.0
        else:
            ff = P.FDJ if fa > 0.0 else -P.FDJ
            v_new = dt * (fa - ff) / P.M
    else:
        ff = P.FDJ if v > 0.0 else -P.FDJ
        v_new = v + dt * (fa - ff) / P.M
        if v_new * v < 0.0:
            v_new = 0.0
    return end_of_travel(x + dt * v_new, v_new, P.XJM)


@jit
def jack_step(s, p12, fr, P):
    """Advance XJ, DXJ in the plant state ``s`` by one DT (:func:`jack_advance`)."""
    s[S_XJ], s[S_DXJ] = jack_advance(s[S_XJ], s[S_DXJ], p12, fr, P)
