"""Prognosis scored as a PHM user would, on seeded histories whose truth is known: how often the
90 % RUL interval holds the true RUL, how often the alpha-lambda criterion is met (progpy.metrics:
at least half of the RUL samples within +-alpha of the true RUL) and the relative accuracy (RA)
of the median, at 25, 50 and 75 % of life and at every flight from half of life on; what
trend-free and step histories are called; and that a unit read past its threshold gets RUL 0.

The laws (each unit draws its own end of life, the cycle its *true* severity reaches the
threshold, the fault's alarm value):

- ``linear``: dynamic friction, s = 1 + (T - 1) n / EOL, EOL 20-60 cycles;
- ``accelerating``: a leak, s = 1 + a e^(b n) (a from 0.2 to 0.6: worn from the start),
  EOL 30-100 cycles;
- ``irregular``: either of the two (a gain loss for the linear one), flights at irregular
  spacing (exponential gaps, some flights bunched, some far apart);
- ``power``: a gain loss s = T (n / EOL)^p, p from 1.3 to 2.5 -- a law none of the trend models
  is (reported, not a claim);
- ``trend-free``: healthy units read with noise (no finite RUL is the right answer);
- ``step``: flights near one level, then a step past the threshold (RUL 0 is right);
- ``past``: a trend whose last reading's interval lies wholly past the threshold (RUL 0).

Each flight's reading is what ``diagnose`` hands to ``prognose``: the true departure from
healthy times (1 + a unit bias of sd ``model_sigma``, stated as such) plus a flight's error of
sd ``rel`` x the departure + 1 % of the alarm span (``rel`` drawn per unit in 1-4 %), with a 95 %
interval of 1.96 x ``--stated`` x that sd (1: honest intervals; 0.5: intervals half as wide as
the error, the harder case). Flights: 8-40 per unit over its life.

    .venv/bin/python bench/bench_prognosis.py [--units 30] [--seed 7001] [--stated 1.0]
        [--model-sigma 0.03] [--json F] [--doc SECTION]

Seeds: the method was built on ``--seed 1001`` and ``--seed 2001``; the README and
doc/results/prognosis.md report ``--seed 7001`` (and others never used while building it).
"""

import argparse
import json
import math
import time

import numpy as np

from servovalve_twin.physics.faults import FAULTS
from servovalve_twin.prognostics.metrics import alpha_lambda
from servovalve_twin.prognostics.prognosis import prognose

ALPHA = 0.2
MODEL_SIGMA = 0.03
TRENDING = ('linear', 'accelerating', 'irregular', 'power')


def law(kind: str, rng):
    """(fault, truth(n), EOL, flight cycles) of one unit of ``kind``."""
    if kind == 'irregular':
        kind = ('linear', 'accelerating')[int(rng.integers(2))]
        fault = 'torque_motor_gain_loss' if kind == 'linear' else 'leakage_growth'
        irregular = True
    else:
        fault = {'linear': 'dynamic_friction', 'accelerating': 'leakage_growth',
                 'power': 'torque_motor_gain_loss'}[kind]
        irregular = False
    spec = FAULTS[fault]
    h, thr = spec.healthy, spec.demo
    if kind == 'linear':
        eol = rng.uniform(20, 60)

        def truth(n):
            return h + (thr - h) * np.asarray(n, float) / eol
    elif kind == 'accelerating':
        a = rng.uniform(0.2, 0.6)
        eol = rng.uniform(30, 100)
        b = math.log((thr - h) / a) / eol

        def truth(n):
            return h + a * np.exp(b * np.asarray(n, float))
    else:
        p = rng.uniform(1.3, 2.5)
        eol = rng.uniform(20, 60)

        def truth(n):
            return h + (thr - h) * (np.asarray(n, float) / eol) ** p
    flights = int(rng.integers(8, 41))
    if irregular:
        gaps = rng.exponential(1.0, flights)
        cycles = np.cumsum(gaps) / gaps.sum() * eol * rng.uniform(0.95, 1.0)
    else:
        cycles = np.linspace(0.0, eol, flights, endpoint=False)
    cycles = np.round(cycles, 2)
    cycles = cycles[np.r_[True, np.diff(cycles) > 0]]
    return fault, truth, eol, cycles


def readings(fault, truth, cycles, rng, stated, model_sigma=MODEL_SIGMA, with_bias=False):
    """What diagnose reports per flight: severity, 95 % interval, model_sigma (and, with
    ``with_bias``, the unit's bias too)."""
    spec = FAULTS[fault]
    h = spec.healthy
    span = abs(spec.demo - h)
    rel = rng.uniform(0.01, 0.04)
    bias = rng.normal(0.0, model_sigma)
    d = truth(cycles) - h
    sd = rel * np.abs(d) + 0.01 * span
    s = h + d * (1 + bias) + rng.normal(0.0, 1.0, d.size) * sd
    half = 1.96 * stated * sd
    out = [dict(cycles=float(n), severity=float(x), interval=[float(x - w), float(x + w)],
                model_sigma=model_sigma) for n, x, w in zip(cycles, s, half)]
    return (out, bias) if with_bias else out


def oracle_rul(fault, truth, eol, n_now, bias, model_sigma, rng, draws=1000):
    """The RUL samples of a predictor that knows the unit's law and reads its flights without
    error, but not the unit's bias (it knows its spread): reading a departure d (1 + bias), it
    takes the true crossing at d_thr (1 + b') / (1 + bias) for b' ~ N(0, model_sigma), so its
    samples carry exactly the uncertainty no trend can remove. Its alpha-lambda is the ceiling
    of any method's on these histories."""
    h = FAULTS[fault].healthy
    d_thr = FAULTS[fault].demo - h
    grid = np.linspace(0.0, 3.0 * eol, 30001)
    dep = (truth(grid) - h) / d_thr                 # rising from 0 to 1 at eol, monotone
    b = rng.normal(0.0, model_sigma, draws) if model_sigma > 0 else np.zeros(draws)
    target = (1.0 + b) / (1.0 + bias)
    cross = np.interp(target, dep, grid, right=np.inf)
    return np.maximum(cross - n_now, 0.0)


def trending(kind: str, units: int, seed: int, stated: float,
             model_sigma: float = MODEL_SIGMA) -> dict:
    rng = np.random.default_rng(seed)
    orng = np.random.default_rng(seed + 10_000)     # the oracle's own draws: same histories
    marks = {25: [], 50: [], 75: []}
    after = []          # (covered, alpha-lambda, RA, oracle's alpha-lambda) per flight after half
    for u in range(units):
        fault, truth, eol, cycles = law(kind, rng)
        hist, bias = readings(fault, truth, cycles, rng, stated, model_sigma, with_bias=True)
        thr = FAULTS[fault].demo
        todo = {}
        for pct in marks:
            k = int(np.searchsorted(cycles, pct / 100 * eol))
            if k < len(cycles):
                todo.setdefault(k, []).append(pct)
        for k in range(len(cycles)):
            if cycles[k] >= eol / 2:
                todo.setdefault(k, []).append('after')
        for k, tags in sorted(todo.items()):
            if k < 2:
                continue
            p = prognose(hist[:k + 1], fault, thr, draws=1000, seed=u * 1000 + k)
            true_rul = eol - cycles[k]
            covered = p.rul['p05'] <= true_rul <= p.rul['p95']
            draws = np.where(np.isfinite(p.draws), p.draws, 1e9)
            al = alpha_lambda({float(cycles[k]): draws}, eol, float(cycles[k]), alpha=ALPHA)
            ra = 1.0 - abs(true_rul - p.rul['median']) / true_rul
            od = oracle_rul(fault, truth, eol, float(cycles[k]), bias, model_sigma, orng)
            oal = alpha_lambda({float(cycles[k]): np.where(np.isfinite(od), od, 1e9)}, eol,
                               float(cycles[k]), alpha=ALPHA)
            for t in tags:
                (after if t == 'after' else marks[t]).append((covered, al, ra, oal))
    out = {}
    for key, rows in [*((f'{p} %', marks[p]) for p in marks), ('after half', after)]:
        if rows:
            c, a, r, o = zip(*rows)
            out[key] = dict(points=len(rows), covered=int(sum(c)), alpha_lambda=int(sum(a)),
                            ra_median=float(np.median(r)), oracle_alpha_lambda=int(sum(o)))
    return out


def trend_free(units: int, seed: int, stated: float) -> dict:
    rng = np.random.default_rng(seed)
    said = []
    for u in range(units):
        fault = ('leakage_growth', 'dynamic_friction', 'torque_motor_gain_loss')[u % 3]
        h = FAULTS[fault].healthy
        cycles = np.arange(int(rng.integers(3, 41)), dtype=float) * rng.uniform(0.5, 3)
        p = prognose(readings(fault, lambda n: h + 0.0 * n, cycles, rng, stated), fault)
        said.append(p.status == 'no degradation trend' and math.isinf(p.rul['median']))
    return dict(units=units, no_trend=sum(said))


def steps(units: int, seed: int, stated: float) -> dict:
    rng = np.random.default_rng(seed)
    right = 0
    for _ in range(units):
        before, after_ = int(rng.integers(3, 15)), int(rng.integers(1, 10))
        lvl, lvl2 = rng.uniform(1.0, 3.0), rng.uniform(10.5, 14.0)
        cycles = np.arange(before + after_, dtype=float)

        def truth(n, lvl=lvl, lvl2=lvl2, before=before):
            return np.where(np.asarray(n) < before, lvl, lvl2)
        hist = readings('leakage_growth', truth, cycles, rng, stated)
        p = prognose(hist, 'leakage_growth', 10.0)
        right += p.rul['median'] == 0.0 and p.rul['p05'] == 0.0
    return dict(units=units, rul_zero=right)


def past(units: int, seed: int, stated: float) -> dict:
    """Every law, run past its end of life: each history whose last reading's interval lies
    wholly past the threshold must get 'past threshold', RUL 0."""
    rng = np.random.default_rng(seed)
    asked = right = 0
    while asked < units:
        fault, truth, eol, cycles = law(TRENDING[asked % 4], rng)
        cycles = np.r_[cycles, eol * rng.uniform(1.0, 1.3, 3)]
        cycles = np.unique(np.round(cycles, 2))
        hist = readings(fault, truth, cycles, rng, stated)
        thr = FAULTS[fault].demo
        sign = 1.0 if thr > FAULTS[fault].healthy else -1.0
        lo, hi = hist[-1]['interval']
        if sign * ((lo if sign > 0 else hi) - thr) <= 0:
            continue
        asked += 1
        p = prognose(hist, fault, thr)
        right += p.status == 'past threshold' and p.rul == dict(median=0.0, p05=0.0, p95=0.0)
    return dict(units=units, rul_zero=right)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument('--units', type=int, default=30)
    ap.add_argument('--seed', type=int, default=7001)
    ap.add_argument('--stated', type=float, default=1.0,
                    help='stated sd / true sd of each flight\'s error (default 1: honest)')
    ap.add_argument('--model-sigma', type=float, default=MODEL_SIGMA,
                    help='sd of each unit\'s bias, relative to its departure from healthy '
                         f'(stated to prognose as model_sigma; default {MODEL_SIGMA:g})')
    ap.add_argument('--json', help='write the results here too')
    ap.add_argument('--doc', metavar='SECTION',
                    help='write the tables into that section of doc/results/diagnosis.md and '
                         'the JSON into doc/results/data/SECTION.json')
    args = ap.parse_args()
    t0 = time.perf_counter()
    results = {}
    for i, kind in enumerate(TRENDING):
        results[kind] = trending(kind, args.units, args.seed + i, args.stated, args.model_sigma)
    results['trend-free'] = trend_free(3 * args.units, args.seed + 7, args.stated)
    results['step'] = steps(args.units, args.seed + 8, args.stated)
    results['past'] = past(args.units, args.seed + 9, args.stated)
    data = dict(args=vars(args), results=results, seconds=time.perf_counter() - t0)
    print(render(data))
    if args.json:
        with open(args.json, 'w') as f:
            json.dump(data, f, indent=1)
    if args.doc:
        import results as pages
        pages.write(pages.ROOT / 'doc' / 'results' / 'diagnosis.md', args.doc, data,
                    render(data))


def render(data) -> str:
    """The bench's tables (markdown) from its JSON (``data``: args, results, seconds)."""
    args, results = data['args'], data['results']
    out = [f'Seeded histories: {args["units"]} units per law, 8-40 flights, flight error 1-4 % '
           f'of the departure + 1 % of the alarm span (intervals state {args["stated"]:g} x '
           f'it), unit bias sd {args["model_sigma"]:.0%} (stated); seed {args["seed"]}; '
           f'{data["seconds"]:.0f} s.', '',
           '| law | at | points | 90 % RUL interval holds the truth | alpha-lambda met '
           f'(alpha {ALPHA:g}) | median RA | ceiling: an oracle of the law, not the bias |',
           '|---|---|---|---|---|---|---|']
    for kind in TRENDING:
        for at, x in results[kind].items():
            out.append(f'| {kind} | {at} | {x["points"]} | {x["covered"]} '
                       f'({x["covered"] / x["points"]:.1%}) | {x["alpha_lambda"]} '
                       f'({x["alpha_lambda"] / x["points"]:.1%}) | {x["ra_median"]:.2f} | '
                       f'{x["oracle_alpha_lambda"] / x["points"]:.1%} |')
    tf, st, pa = results['trend-free'], results['step'], results['past']
    out += ['', f'Trend-free histories called `no degradation trend`: {tf["no_trend"]}/'
            f'{tf["units"]}; steps past the threshold given RUL 0 (median and p05): '
            f'{st["rul_zero"]}/{st["units"]}; last reading wholly past the threshold given '
            f'`past threshold`, RUL 0: {pa["rul_zero"]}/{pa["units"]}.']
    return '\n'.join(out) + '\n'


if __name__ == '__main__':
    main()
