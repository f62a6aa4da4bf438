r"""``SQ``: an explicit square-root (orifice-law) servovalve model -- beyond the paper
(doc/design/MODELS.md section 8, issue 6).

Why. Every C-model of the paper lets the flow fall *linearly* with the load pressure
(``QJ = (PSR*XS/XSS - (1 + k)*P12)/GPQ``) and clamps P12 at PSR. A real valve meters through
sharp-edged orifices: at a given opening the flow falls as ``sqrt(1 - P12/PSR)`` -- much faster
under an opposing load -- and when the load drives the jack (braking, over-stall) the port
pressure rises *above* supply, reversing the flow through the metering edge. HD shows both.

Assumptions.

1. A matched, symmetric four-way spool valve; supply PS = PSR, return PR = 0 (gauge). Each edge
   is a turbulent orifice: edge flow ``Q = a*K*sqrt(2*dp)`` (sign-preserving), opening ``a``.
2. A soft null: the edges feeding in the commanded direction open as ``a1 = (r + XS)/2``, the
   opposite pair as ``a2 = (r - XS)/2``, ``r = sqrt(XS^2 + x0^2)`` (XS >= 0; odd symmetry for
   XS < 0): a hyperbola that tends to the critical-centre openings XS and 0 away from null and
   has a finite null pressure gain; ``x0`` stands for everything that makes HD's null soft
   (radial clearance, corner radius, laminar gaps).
3. While both ports stay between return and supply, symmetry gives P1 = (PS + P12)/2 and
   P2 = (PS - P12)/2 (Merritt). Outside, the starved port cavitates at ~PR (as in HD, with PR
   neglected against PSR) and the other port carries the whole load pressure.
4. Port-to-port leakage ``CLk*P12`` is added to the flow the valve must pass,
   ``P12 = f(QJ + CLk*P12)``, and solved by one fixed secant step (no iteration, below).

Equations (XS >= 0, ``A = K*a1``, ``B = K*a2``, QL the flow the valve passes):

- normal, ``-B*sqrt(2*PS) <= QL <= A*sqrt(2*PS)``: ``QL = A*sqrt(PS - P12) - B*sqrt(PS + P12)``,
  solved in closed form for ``u = sqrt(PS - P12)``:
  ``u = (A*QL + B*sqrt(2*PS*(A^2 + B^2) - QL^2))/(A^2 + B^2)``, ``P12 = PS - u^2``;
  with ``B = 0`` this is Merritt's critical-centre law ``P12 = PS - (QL/A)^2``;
- over-run, ``QL < -B*sqrt(2*PS)`` (the load pushes the jack against the valve: braking,
  over-stall): port 2 cavitates, flow reverses through the supply edge,
  ``-QL = A*w + B*sqrt(w^2 + 2*PS)`` with ``w = sqrt(2*(P12 - PS))``, i.e.
  ``w = (q^2 - 2*B^2*PS)/(A*q + B*sqrt(q^2 + 2*(A^2 - B^2)*PS))``, ``P12 = PS + w^2/2 > PS``;
- pulled, ``QL > A*sqrt(2*PS)`` (the load pulls the jack faster than supply can fill):
  port 1 cavitates, the meter-out edge brakes,
  ``w = (QL^2 - 2*A^2*PS)/(B*QL + A*sqrt(QL^2 - 2*(A^2 - B^2)*PS))``, ``P12 = -(PS + w^2/2)``.

The three branches meet continuously at ``P12 = +-PS``. The conjugate forms avoid cancellation.

Calibration, from the same HD-derived parameters as the C-models (nothing of HD's geometry):

- null pressure gain: at QL = 0, ``P12 = PS*2*r*XS/(r^2 + XS^2)``, slope ``2*PS/x0`` at null;
  the paper's ``PSR/XSS`` gives ``x0 = 2*XSS``;
- flow gain: unloaded, ``QL = (A - B)*sqrt(PS) = K*XS*sqrt(PS)``, which is ``GQN*XS`` at PSRN
  (``GQN = GPN/GPQ``) with ``K = GQN/sqrt(PSRN)`` (:func:`sq_constants`).

Leakage: with ``P0 = f(QJ)`` the leak-free pressure and ``P1 = f(QJ + CLk*P0)`` the pressure
at the flow the leak would add, the secant through both gives
``P12 = P0^2/(2*P0 - P1)``. Near null the secant slope plays the part of GPQ (the C-models'
``1 + k``); at large openings it vanishes, as C3's divisor does, but from the orifice law
itself. (The tangent at P0 was tried first: its slope drops to zero at the ``P12 = PSR`` branch
boundary and made P12 non-monotonic in QJ there; the secant does not.) Limit: with ten times the
paper's leakage, deep in over-run (|P12| > 2*PSR at small openings) the secant step leaves P12
non-monotonic in QJ by steps of about 0.01 %; the tests check monotonicity up to 2*PSR.
"""

import math

from ...jitcache import jit


def sq_constants(params) -> tuple[float]:
    """SQ's kernel constant ``VC0``: the orifice coefficient ``K = GQN/sqrt(PSRN)`` with
    ``GQN = GPN/GPQ`` (named K, not k: the paper's k is the leakage gain CLk*GPQ)."""
    return (params.gpn / (params.gpq * math.sqrt(params.PSRN)),)


@jit(inline='always')
def _branches(a, b, ql, ps, a2ps2, b2ps2, ab2ps2, inv_ab2):
    """Leak-free P12 for XS >= 0 (A = a, B = b, QL = ql, PS = ps), with the shared terms
    ``2*A^2*PS``, ``2*B^2*PS``, ``2*PS*(A^2 + B^2)`` and ``1/(A^2 + B^2)`` computed once per step.
    The branch tests ``QL > A*sqrt(2*PS)`` and ``QL < -B*sqrt(2*PS)`` are made on squares."""
    ql2 = ql * ql
    if ql > 0.0 and ql2 > a2ps2:                      # pulled: port 1 cavitates
        w = (ql2 - a2ps2) / (b * ql + a * math.sqrt(ql2 - a2ps2 + b2ps2))
        return -(ps + 0.5 * w * w)
    if ql < 0.0 and ql2 > b2ps2:                      # over-run: port 2 cavitates
        w = (ql2 - b2ps2) / (-a * ql + b * math.sqrt(ql2 + a2ps2 - b2ps2))
        return ps + 0.5 * w * w
    u = (a * ql + b * math.sqrt(max(ab2ps2 - ql2, 0.0))) * inv_ab2   # both ports inside
    return ps - u * u


@jit
def model_sq(xs, qj, psr, P, vs):
    """SQ: explicit four-edge orifice-law model (see the module docstring for the derivation)."""
    if psr <= 0.0:
        return 0.0
    x0 = 2.0 * P.XSS
    kq = P.VC0                      # the orifice coefficient K = GQN/sqrt(PSRN), sq_constants
    sign = 1.0
    if xs < 0.0:                                      # odd symmetry
        xs = -xs
        qj = -qj
        sign = -1.0
    r = math.sqrt(xs * xs + x0 * x0)
    a = 0.5 * kq * (r + xs)
    b = 0.5 * kq * (r - xs)          # r - xs >= x0^2/(2*r): no harmful cancellation up to XSM
    a2ps2 = 2.0 * a * a * psr
    b2ps2 = 2.0 * b * b * psr
    ab2ps2 = a2ps2 + b2ps2
    inv_ab2 = 2.0 * psr / ab2ps2
    p0 = _branches(a, b, qj, psr, a2ps2, b2ps2, ab2ps2, inv_ab2)
    if P.CLk == 0.0 or p0 == 0.0:
        return sign * p0
    # leakage: one secant step of P = f(QJ + CLk*P) from the leak-free point, through the
    # predicted point Q1 = QJ + CLk*P0 -- a fixed formula, no iteration
    p1 = _branches(a, b, qj + P.CLk * p0, psr, a2ps2, b2ps2, ab2ps2, inv_ab2)
    return sign * p0 * p0 / (2.0 * p0 - p1)
