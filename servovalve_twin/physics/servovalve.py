"""Two-stage servovalve mechanics: torque motor + flapper (2nd order) and spool (integrator),
both with ends of travel (doc/design/MODELS.md section 4).

    MF*D2XF + CF*DXF + KF*XF = GM*(Cor + CorB) - KFB*(XS + XF),  |XF| <= XFM
    DXS = (GQF/AS)*XF,                                           |XS| <= XSM

At steady state XF = 0 and XS = GM*(Cor + CorB)/KFB.
"""

from ..jitcache import jit

S_XF = 0      # flapper displacement XF [m]
S_DXF = 1     # flapper velocity DXF [m/s]
S_XS = 2      # spool displacement XS [m]
S_XJ = 3      # jack position XJ [m]
S_DXJ = 4     # jack velocity DXJ [m/s]
S_SIZE = 5
#: the same layout by name (progpy states, simulate's ``initial``)
PLANT_STATE = ('xf', 'dxf', 'xs', 'xj', 'dxj')


@jit(inline='always')
def end_of_travel(x, v, lim):
    """Clamp a position to +-lim and zero the velocity pointing out of the stop, so that the
    stage leaves the stop as soon as the net force reverses. Returns (x, v)."""
    if x > lim:
        return lim, (0.0 if v > 0.0 else v)
    if x < -lim:
        return -lim, (0.0 if v < 0.0 else v)
    return x, v


@jit(inline='always')
def servovalve_advance(xf, dxf, xs, cor, P):
    """XF, DXF, XS one DT later under the current ``cor`` (semi-implicit Euler: velocity
    first, then position), both stages stopped at their ends of travel
    (:func:`end_of_travel`)."""
    dt = P.DT
    force = P.GM * (cor + P.CorB) - P.KFB * (xs + xf) - P.CF * dxf - P.KF * xf
    dxf += dt * force / P.MF
    xf, dxf = end_of_travel(xf + dt * dxf, dxf, P.XFM)
    xs += dt * P.GQF_AS * xf
    if xs > P.XSM:
        xs = P.XSM
    elif xs < -P.XSM:
        xs = -P.XSM
    return xf, dxf, xs


@jit
def servovalve_step(s, cor, P):
    """Advance flapper and spool in the plant state ``s`` by one DT
    (:func:`servovalve_advance`)."""
    s[S_XF], s[S_DXF], s[S_XS] = servovalve_advance(s[S_XF], s[S_DXF], s[S_XS], cor, P)
