"""When a fault began: the change point of the diagnosis (``diagnose(..., onset=True)``).

Each single-fault hypothesis is refitted with the fault starting at instants of the window --
a coarse grid, and the instants around the change point of its from-start fit against the
healthy one (:func:`change_point`) -- the best one's instant refined by golden section and
tried by every hypothesis (an onset's cost can be a few ms wide), and the verdict's refined in
turn (:func:`fit_onset`)."""

from __future__ import annotations

import math
from typing import Any, Callable, Mapping

import numpy as np

from ..physics.faults import FAULTS
from .rules import PAIR_EVIDENCE, sized
from .fit_intervals import jacobian_interval
from .fitting import CHI2_95, SIGNALS, Problem, effective_n, fit, start_grid
from .verdict import HEALTHY, Candidate

#: the onset screen: candidate instants over the window per single-fault hypothesis (the
#: best is then refined by golden section), and severities each instant's fit may start from
ONSET_GRID = 9
ONSET_STARTS = 5
#: the instants tried around each hypothesis' change point [s]: the cost of an onset can
#: have a valley far narrower than the grid (a null bias from 0.3 s: RSS 3.0e3 at 0.30,
#: 1.3e4 at 0.34, 3.0e4 at 0.36, a local minimum of 1.9e4 at 0.44 -- the grid's 0.359 and
#: 0.478 put the refinement there: measured)
AROUND_CHANGE = (-0.02, 0.0, 0.02)
#: an onset is stated as pinned when its interval is at most this wide [s] (+-50 ms); wider,
#: the run does not show when the fault began (a first-stage flow loss while the jack holds
#: still shows only at the next command): ``identifiable`` is then false and the interval is
#: the answer
ONSET_PINNED = 0.1
#: the instants around the best hypothesis' refined onset tried by every hypothesis [s]
SHARED = (-0.002, 0.0, 0.002)
#: the hypotheses whose onset profile's RSS is within this factor of the best one's are
#: refitted with the nuisance at their onset before one is chosen (:func:`_at_onset`)
CONTENDER = 3.0
#: a hypothesis whose onset profile (the nuisance held) comes within this factor of the
#: answer's RSS is refitted with the nuisance free before it is ruled out as a rival
#: (:func:`_rivals`): held, a dynamic friction of 24.6 x from 0.3 s on the paper flight fitted
#: 8.6 x the RSS of the verdict, a static friction of 16.5 x from the start; refitted, as well
#: (2112 against 2128: a dynamic friction far above the static one sticks as it does)
RIVAL_SCREEN = 10.0


def change_point(problem: Problem, healthy: Candidate, cand: Candidate) -> float | None:
    """Where the from-start fit of ``cand`` begins to explain the run better than the healthy
    fit: the argmin of the cumulative difference of their squared residuals per row (before
    an onset the faulty model is the worse, after it the better). Costs no model run."""
    if not healthy.fitted or not cand.fitted:
        return None
    m = len(SIGNALS)
    rh = problem.residuals(healthy.fitted).reshape(m, -1)
    rf = problem.residuals(cand.fitted).reshape(m, -1)
    k = int(np.argmin(np.cumsum((rh ** 2 - rf ** 2).sum(axis=0))))
    return float(problem.t[k])


class OnsetProfile:
    """One fault's severity refitted with the fault starting at each tried instant tau."""

    def __init__(self, problem: Problem, cand: Candidate):
        self.problem, self.cand = problem, cand
        self.fault = cand.faults[0]
        self.nominal = problem.params((), [], cand.free)
        self.fits: dict[float, tuple[float, float, Any]] = {}
        self.refined = False
        #: :func:`_at_onset`'s answer, with how many instants had been tried when it was made
        self.at_onset: tuple[int, tuple] | None = None

    def cost(self, tau: float) -> float:
        from scipy.optimize import least_squares
        tau = round(float(tau), 4)
        if tau not in self.fits:
            spec = FAULTS[self.fault]

            def fun(x):
                return self.problem.residuals(self.problem.run(
                    self.nominal, ((tau, self.fault, float(x[0])),)))
            # started from the best of the from-start fit and a coarse grid: the cost can be
            # far from convex (a supply loss from 0.6 s: RSS 1.9e5 at 0.2, 2.8e4 at the true
            # 0.3, 2.7e6 at 0.4), and from the from-start fit (near 0) the solver stalled
            starts = [min(max(float(self.cand.severity), spec.lo), spec.hi)] + start_grid(
                self.fault, ONSET_STARTS)
            self.problem.run_many([(self.nominal, ((tau, self.fault, float(v)),))
                                   for v in starts])
            x0 = min(starts, key=lambda v: float(np.sum(fun([v]) ** 2)))
            sol = least_squares(fun, [x0], bounds=([spec.lo], [spec.hi]),
                                x_scale=[(spec.hi - spec.lo) / 10.0], diff_step=1e-3,
                                xtol=1e-6, ftol=1e-8, max_nfev=30)
            self.fits[tau] = (float(sol.x[0]), float(sol.fun @ sol.fun), sol)
        return self.fits[tau][1]

    def costs(self) -> dict[float, float]:
        """The RSS of the fit at each tried instant."""
        return {t: f[1] for t, f in self.fits.items()}

    def best(self) -> tuple[float, float, float, Any]:
        tau = min(self.fits, key=lambda t: self.fits[t][1])
        sev, rss, sol = self.fits[tau]
        return tau, sev, rss, sol


def _refine(prof: OnsetProfile) -> None:
    """Golden section on the onset between the tried instants either side of the best
    (once per profile)."""
    if prof.refined:
        return
    prof.refined = True
    tried = sorted(prof.fits)
    k = tried.index(prof.best()[0])
    a, b = tried[max(k - 1, 0)], tried[min(k + 1, len(tried) - 1)]
    g = (math.sqrt(5) - 1) / 2
    for _ in range(8):
        c, d = b - g * (b - a), a + g * (b - a)
        if prof.cost(c) <= prof.cost(d):
            b = d
        else:
            a = c


def onset_interval(costs: Mapping[float, float], rss: float, width: float, t0: float,
                   t1: float) -> tuple[float, float]:
    """The instants whose fit (``costs``: RSS per tried instant) stays within ``rss * (1 +
    width)``: the tried ones that bracket them (the limit is crossed between an instant inside
    and its neighbour outside), the window's ends ``t0``, ``t1`` where none does."""
    limit = rss * (1.0 + width)
    tried = sorted(costs)
    inside = [t for t in tried if costs[t] <= limit] or [min(tried, key=costs.get)]
    below = [t for t in tried if t < min(inside) and costs[t] > limit]
    above = [t for t in tried if t > max(inside) and costs[t] > limit]
    return (max(below) if below else t0), (min(above) if above else t1)


def lr_width(n: int, n_eff: float) -> float:
    """The relative rise of the RSS at the 95 % likelihood-ratio limit of one parameter, the
    residuals' autocorrelation counted (``n_eff`` of ``n`` rows independent)."""
    return CHI2_95 * (n / n_eff) / max(n - 2, 1)


def _interval(costs: Mapping[float, float], rss: float, n: int, n_eff: float, t0: float,
              t1: float, widen: float = 1.0) -> tuple[float, float]:
    """:func:`onset_interval` of the tried instants' ``costs`` at the likelihood-ratio limit,
    ``widen`` times as wide (the model-form calibration's factor)."""
    return onset_interval(costs, rss, widen * lr_width(n, n_eff), t0, t1)


def _from_start(problem: Problem, ref: Candidate, profiles: list[OnsetProfile], n: int,
                n_eff: float, widen: float = 1.0) -> dict[str, Any] | None:
    """No onset beats the verdict from the start: None where the start is pinned (a later
    onset fits worse), else the answer that the run cannot tell when the fault began -- a
    static friction of 20 x from 0.3 s on the paper flight fits as well from any instant
    before 0.3 s (the jack first sticks there: measured), and "present from the start" would
    claim what the data do not show. ``from_start``: the verdict's severity stays the one
    fitted from the start; ``severity_range``: the severities that fit as well from the
    latest tried instant inside the interval (:func:`severity_range`), which its interval
    must hold too."""
    prof = next((pr for pr in profiles if len(ref.faults) == 1 and pr.fault == ref.fault),
                None)
    if prof is None:
        return None
    t0, t1 = problem.window
    rss = min(ref.rss, prof.best()[2])
    _, hi = _interval(prof.costs(), rss, n, n_eff, t0, t1, widen)
    if hi - t0 <= ONSET_PINNED:
        return None
    late = max((t for t in prof.fits if t < hi), default=None)
    return dict(t=float(t0), interval=[float(t0), float(hi)], fault=prof.fault,
                identifiable=False, from_start=True,
                severity_range=None if late is None else severity_range(
                    problem, prof, late, rss * (1.0 + lr_width(n, n_eff))))


#: severities tried across the catalog's range by :func:`severity_range` (4.2 % apart for a
#: multiplier of 1-50 x: static friction's valley on the built-in test is ~10 % wide)
RANGE_POINTS = 96


def severity_range(problem: Problem, prof: OnsetProfile, tau: float, limit: float
                   ) -> tuple[float, float] | None:
    """The severities of ``prof``'s fault from ``tau`` whose RSS stays within ``limit`` (a
    grid of :data:`RANGE_POINTS` over the catalog's range and the profile's own fit there,
    the nuisance held), None where none does. A fault that may have begun as late as
    ``tau`` is not bounded by what the fit from the start makes of the flight before it: a
    static friction of 20 x from 1.2 s on the built-in test fits alike (RSS within 0.04 %)
    from 8 to 25 x with any onset from 0.6 s on and within 3.5 % at 50 x, but from the
    start the jack sticks in the opening steps from ~20 x (RSS 2.1 x) -- a 31 x one from
    1.2 s was reported as 16.4 x in [9.1, 29.5] (measured)."""
    grid = start_grid(prof.fault, RANGE_POINTS) + (
        [prof.fits[tau][0]] if tau in prof.fits else [])
    runs = [(prof.nominal, ((tau, prof.fault, float(v)),)) for v in grid]
    problem.run_many(runs)
    ok = [float(v) for v, r in zip(grid, runs)
          if float(np.sum(problem.residuals(problem.run(*r)) ** 2)) <= limit]
    return (min(ok), max(ok)) if ok else None


def _at_onset(problem: Problem, prof: OnsetProfile) -> tuple:
    """``prof``'s fault at its refined onset, its severity refitted jointly with the free
    nuisance (the profile holds the nuisance where the fault's fit from the start put it,
    which that fit bent to explain the healthy part: a gain loss of 0.7 from 0.3 s left 15 x
    a right fit's RSS there and was called unexplained: measured): (prof, tau, severity, rss,
    x, residuals, jacobian, nuisance). Made once per state of the profile: a contender
    refitted to choose the verdict is not refitted again to see whether it is a rival."""
    _refine(prof)
    if prof.at_onset is not None and prof.at_onset[0] == len(prof.fits):
        return prof.at_onset[1]
    tau, sev, rss, sol = prof.best()
    x, res, jac, free = sol.x, sol.fun, sol.jac, dict(prof.cand.free)
    if free:
        names = list(free)
        x2, res2, jac2 = fit(problem, [prof.fault], names, onset=tau,
                             starts=[[sev] + [free[k] for k in names]])
        if float(res2 @ res2) < rss:
            x, res, jac = x2, res2, jac2
            sev, rss = float(x2[0]), float(res2 @ res2)
            free = {k: float(v) for k, v in zip(names, x2[1:])}
    prof.at_onset = (len(prof.fits), (prof, tau, sev, rss, x, res, jac, free))
    return prof.at_onset[1]


def _nuisance_profile(problem: Problem, prof: OnsetProfile, chosen: tuple
                      ) -> tuple[dict[float, float], tuple]:
    """The chosen fault's onset cost as a profile likelihood: at each tried instant whose cost
    with the nuisance held (where the fit from the start put it) comes within
    :data:`CONTENDER` of the best, the severity is refitted jointly with the free nuisance.
    Held, the nuisance makes valleys of the mismatch: a null bias from 0.6 s on the built-in
    test, where the jack slews at its rate limit from 0.55 to past 0.9 s (the bias does not
    show while the spool is at its stop), fitted 1.2e4 just before the step at 0.547 s and
    1.39e4 anywhere on the slew with CJ held at 0.95; refitted, CJ 0.67 and 9.5e3 anywhere on
    the slew and 1.45e4 at 0.550 s -- the onset is not identifiable on the slew, and the held
    profile placed it at 0.547 s within +-9 ms (measured). ``chosen``: the fault's fit at
    its refined onset (:func:`_at_onset`, without ``prof``). Returns the costs per tried
    instant (the lower of held and refitted) and the best refitted fit, as ``chosen``."""
    tau, *_, free = chosen
    names, held = list(free), prof.cand.free
    fits = {tau: chosen}
    best_held = prof.best()[2]
    for t, (sev, cost, _) in sorted(prof.fits.items()):
        if t in fits or cost > CONTENDER * best_held:
            continue
        # (from the held nuisance and from the onset's refit of it, where that moved it)
        starts = [[sev] + [held[k] for k in names]]
        if free != held:
            starts.append([sev] + [free[k] for k in names])
        x, res, jac = fit(problem, [prof.fault], names, onset=t, starts=starts)
        fits[t] = (t, float(x[0]), float(res @ res), x, res, jac,
                   {k: float(v) for k, v in zip(names, x[1:])})
    costs = prof.costs()
    for t, f in fits.items():
        costs[t] = min(costs[t], f[2])
    return costs, min(fits.values(), key=lambda f: f[2])


def _rivals(problem: Problem, profiles: list[OnsetProfile], fault: str, rss: float,
            n_eff: float, extra: int) -> list[str]:
    """The faults of ``profiles`` other than ``fault`` whose fit from an onset comes within
    :data:`.diagnosis.PAIR_EVIDENCE` of the answer's in the information criterion (``rss``;
    ``extra``: the parameters an onset fit has more than the answer, 1 against an answer
    from the start): the run cannot tell them from it. One within :data:`RIVAL_SCREEN` of it
    with the nuisance held is refitted with it free first (:func:`_at_onset`)."""
    def evidence(cost: float) -> float:
        return n_eff * math.log(max(cost, 1e-300) / max(rss, 1e-300)) + extra * math.log(n_eff)

    out = []
    for pr in profiles:
        cost = pr.best()[2]
        if pr.fault == fault or cost > RIVAL_SCREEN * rss:
            continue
        if evidence(cost) >= PAIR_EVIDENCE and pr.cand.free:
            cost = min(cost, _at_onset(problem, pr)[3])
        if evidence(cost) < PAIR_EVIDENCE:
            out.append(pr.fault)
    return out


def _profiles(problem: Problem, candidates: list[Candidate], singles: list[Candidate]
              ) -> list[OnsetProfile]:
    """Each single fault's cost at the onsets of a coarse grid of the window and around its
    change point (:func:`change_point`), the leading one refined, and every one tried at the
    leader's instant."""
    healthy = next((c for c in candidates if c.fault == HEALTHY), None)
    t0, t1 = problem.window
    lo_t, hi_t = max(t0, problem.t_start) + 0.005, t1 - 0.05
    grid = np.linspace(lo_t, hi_t, ONSET_GRID)
    profiles = [OnsetProfile(problem, c) for c in singles]
    for prof in profiles:
        tc = change_point(problem, healthy, prof.cand) if healthy is not None else None
        near = [] if tc is None else [tc + d for d in AROUND_CHANGE if lo_t <= tc + d <= hi_t]
        for t in list(grid) + near:
            prof.cost(t)
    # the instant the best hypothesis finds is tried by every one: an onset's cost can be far
    # narrower than the grid (a supply loss of 0.18 from 0.6 s fits with RSS 3.0e3 at 0.600 s
    # and not at all at 0.595 or 0.61 s: the grid missed it, and leakage growth from 0.599 s
    # won with 4.8e3: measured)
    lead = min(profiles, key=lambda pr: pr.best()[2])
    _refine(lead)
    t_lead = lead.best()[0]
    for pr in profiles:
        for t in (t_lead + d for d in SHARED):
            if lo_t <= t <= hi_t:
                pr.cost(t)
    return profiles


def fit_onset(problem: Problem, candidates: list[Candidate], n: int, n_eff: float,
              unbiased: Callable[[str, float], float] | None = None, widen: float = 1.0,
              rivals: list[str] | None = None) -> dict[str, Any] | None:
    """A change point: each single-fault hypothesis starting at an instant tau of the window
    instead of from the start, its severity refitted at each tau of a coarse grid; the best
    fault whose severity is of a size worth reporting (:func:`.diagnosis.sized`, read after
    ``unbiased``, the model-form correction of an onset's answer) has its tau refined by
    golden section. Reported when it beats the best candidate from the
    start by PAIR_EVIDENCE in BIC (tau, and the severity too against healthy, are parameters
    more); the taus whose RSS stays within the 95 % likelihood-ratio limit, ``widen`` times as
    wide (the model-form calibration's factor: above 1 where the simplified model's mismatch
    makes the cost sharper than the noise alone would, below where the noise's interval holds
    the truth more often than the stated 90 %), are its interval, ``identifiable`` when it is
    at most :data:`ONSET_PINNED` wide. The answer keeps the chosen fault's cost per tried instant
    (``costs``, with ``rss`` and ``width``: what the calibration reads the factor from).
    The hypotheses whose profiles come within :data:`CONTENDER` of the best are refitted at
    their onsets jointly with the free nuisance (:func:`_at_onset`); the best of those is moved
    to the front as the verdict, with its Jacobian interval. Where no onset beats the
    fit from the start, :func:`_from_start` says whether the start is pinned. ``rivals``
    (a list) is extended by the faults of a size worth reporting that fit from an onset as
    well as the answer (:func:`_rivals`). About 100 model runs per hypothesis."""
    singles = [c for c in candidates if len(c.faults) == 1]
    if not singles:
        return None
    t0, t1 = problem.window
    profiles = _profiles(problem, candidates, singles)
    # a change point of a fault too small to report is the mismatch's, as from the start (a
    # static friction below its limit read as a 1.2-1.5 x dynamic friction from a wrong
    # instant: measured)
    reportable = [pr for pr in profiles if sized(pr.fault, pr.best()[1] if unbiased is None
                                                 else unbiased(pr.fault, pr.best()[1]))]
    if not reportable:
        return None
    # the hypotheses whose onset fits come near the best one's are each refitted with the
    # nuisance at their own instant before one is chosen: the profiles hold M and CJ where the
    # from-start fit put them, and that can rank faults wrongly (a supply loss of 0.3 from
    # 1.2 s on the built-in test: its profile 12.4e3 against a gain loss's 9.1e3, refitted
    # 5.4e3 against 7.4e3 -- and 0.300 against a truth of 0.3: measured)
    lowest = min(pr.best()[2] for pr in reportable)
    ref = candidates[0]
    extra = 1 + (1 if ref.fault == HEALTHY else 0)
    # the evidence against the fit from the start is the best profile's (its nuisance as
    # fitted from the start, like the verdict's)
    gain = n_eff * math.log(max(ref.rss, 1e-300) / max(lowest, 1e-300)) \
        - extra * math.log(n_eff)
    if gain < PAIR_EVIDENCE:
        if rivals is not None and len(ref.faults) == 1:
            rivals += _rivals(problem, reportable, ref.fault, ref.rss, n_eff, 1)
        return _from_start(problem, ref, profiles, n, n_eff, widen)
    fits = [_at_onset(problem, pr) for pr in reportable if pr.best()[2] <= CONTENDER * lowest]
    prof, tau, sev, rss, x, res, jac, free = min(fits, key=lambda f: f[3])
    costs = prof.costs()
    if free:
        costs, (tau, sev, rss, x, res, jac, free) = _nuisance_profile(
            problem, prof, (tau, sev, rss, x, res, jac, free))
    best_rss = min(costs.values())
    lo, hi = _interval(costs, best_rss, n, n_eff, t0, t1, widen)
    spec = FAULTS[prof.fault]
    cand = prof.cand
    cand.free = free
    nominal = problem.params((), [], free)
    n_own = effective_n(res, len(SIGNALS))
    iv = jacobian_interval(prof.fault, 0, x, res, jac, n, n_own) or (spec.lo, spec.hi)
    cand.severity, cand.interval, cand.rss = sev, iv, rss
    cand.fitted = problem.run(nominal, ((tau, prof.fault, sev),)) or {}
    candidates.remove(cand)
    candidates.insert(0, cand)
    if rivals is not None:
        # (the fit from the start lost: so did the faults as good as it)
        rivals[:] = _rivals(problem, reportable, prof.fault, rss, n_eff, 0)
    return dict(t=float(tau), interval=[float(lo), float(hi)], fault=prof.fault,
                identifiable=bool(hi - lo <= ONSET_PINNED),
                profile=dict(costs=costs, rss=best_rss, width=lr_width(n, n_eff)))


__all__ = ['fit_onset', 'change_point', 'OnsetProfile', 'onset_interval', 'lr_width',
           'severity_range',
           'ONSET_GRID', 'ONSET_STARTS', 'ONSET_PINNED']
