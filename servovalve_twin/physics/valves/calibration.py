"""Calibration of the simplified models' gains (XSS, GPN, GQN, GPQ, k) from the leak-free HD
valve (doc/design/MODELS.md section 3): the C-models and SQ are driven by these numbers only,
never by HD's geometry."""

from __future__ import annotations

import math

from ...errors import ModelError
from ..params import EhaParams, register_hd_calibration
from .hd import hd_ports


def _bisect(fn, lo: float, hi: float, target: float, n: int = 200) -> float:
    """x in [lo, hi] with fn(x) = target for an increasing fn (used only by the calibration)."""
    flo = fn(lo) - target
    fhi = fn(hi) - target
    if flo * fhi > 0:
        raise ModelError(f'calibration: target {target:g} not bracketed in [{lo:g}, {hi:g}]')
    for _ in range(n):
        mid = 0.5 * (lo + hi)
        fm = fn(mid) - target
        if (fm > 0) == (fhi > 0):
            hi, fhi = mid, fm
        else:
            lo, flo = mid, fm
        if hi - lo <= 1e-15 * max(abs(lo), abs(hi), 1e-30):
            break
    return 0.5 * (lo + hi)


def calibrate(params: EhaParams) -> dict[str, float]:
    """XSS, GPN, GQN, GPQ, k of the simplified models from the leak-free HD valve
    (doc/design/MODELS.md section 3): the simplified models add leakage themselves through k =
    CLk*GPQ.

    - XSS from the mean slope of the zero-flow P12(XS) curve between -40 % and +40 % of PSRN:
      GP = 0.8*PSRN/(x(+40 %) - x(-40 %)), XSS = PSRN/GP;
    - GQN = QJ(XSM, P12 = 0)/XSM at PSRN; GPQ = GP/GQN; k = CLk*GPQ with the given CLk.
    """
    leak_free = params.replace(CLk=0.0, compressible=False)
    psrn = params.PSRN

    def p12_of_xs(xs):
        return hd_ports(xs, 0.0, psrn, leak_free)[0]

    x_pos = _bisect(p12_of_xs, -params.XSM, params.XSM, 0.4 * psrn)
    x_neg = _bisect(p12_of_xs, -params.XSM, params.XSM, -0.4 * psrn)
    gp = 0.8 * psrn / (x_pos - x_neg)
    xss = psrn / gp
    q_max = 4.0 * params.Cd * params.w * params.XSM * math.sqrt(2.0 * psrn / params.rho)
    # P12 falls as QJ grows: bisect on -P12
    qj0 = _bisect(lambda q: -hd_ports(params.XSM, q, psrn, leak_free)[0], 0.0, q_max, 0.0)
    gqn = qj0 / params.XSM
    gpq = gp / gqn
    return dict(XSS=xss, GPN=gp, GQN=gqn, GPQ=gpq, k=params.CLk * gpq)


def hd_gains(params: EhaParams) -> tuple[float, float]:
    """(XSS, GPQ) of the design ``params``: :func:`calibrate`'s (the parameters' own XSS and
    GPQ, given or not, are not among its inputs)."""
    cal = calibrate(params.replace(XSS=1e-5, GPQ=1e12))
    return cal['XSS'], cal['GPQ']


# EhaParams derives XSS and GPQ through this when they are not given
register_hd_calibration(hd_gains)
