"""Two-stage servovalve mechanics: torque motor + flapper (2nd order) and spool (integrator),
both with ends of travel (MODELS.md section 4).

    MF*D2XF + CF*DXF + KF*XF = GM*(Cor + CorB) - KFB*(XS + XF),  |XF| <= XFM
    DXS = (GQF/AS)*XF,                                           |XS| <= XSM

At steady state XF = 0 and XS = GM*(Cor + CorB)/KFB.
"""

from numba import njit

S_XF = 0      # flapper displacement XF [m]
S_DXF = 1     # flapper velocity DXF [m/s]
S_XS = 2      # spool displacement XS [m]
S_XJ = 3      # jack position XJ [m]
S_DXJ = 4     # jack velocity DXJ [m/s]
S_SIZE = 5


@njit(cache=True)
def servovalve_step(s, cor, P):
    """Advance flapper and spool by one DT (semi-implicit Euler: velocity first, then position).

    An end of travel clamps the position and zeroes the velocity pointing outward, so the stage
    leaves the stop as soon as the net force reverses.
    """
    dt = P.DT
    xf = s[S_XF]
    dxf = s[S_DXF]
    xs = s[S_XS]
    force = P.GM * (cor + P.CorB) - P.KFB * (xs + xf) - P.CF * dxf - P.KF * xf
    dxf += dt * force / P.MF
    xf += dt * dxf
    if xf > P.XFM:
        xf = P.XFM
        if dxf > 0.0:
            dxf = 0.0
    elif xf < -P.XFM:
        xf = -P.XFM
        if dxf < 0.0:
            dxf = 0.0
    xs += dt * P.GQF_AS * xf
    if xs > P.XSM:
        xs = P.XSM
    elif xs < -P.XSM:
        xs = -P.XSM
    s[S_XF] = xf
    s[S_DXF] = dxf
    s[S_XS] = xs
