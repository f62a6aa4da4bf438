"""Worked example: from diagnosis to remaining useful life, on a fleet whose leakage grows.

Each unit of the fleet is an HD actuator whose mass, viscous and dynamic friction differ from
the design by up to +-10 %, +-20 %, +-20 % (drawn once per unit: the nuisance a diagnosis must
tolerate); its internal leakage grows flight after flight, exponentially, reaching the
catalog's alarm severity (10 x CLk) at an end of life (EOL) drawn between 30 and 50 flights.
Every flight is the paper scenario, measured with noise (XJ 10 um, DXJ 1 mm/s, P12 50 kPa RMS).

After every flight the leakage is diagnosed with SQ (``diagnose``, the leakage hypothesis, M
and CJ free as nuisance); at 25 %, 50 % and 75 % of each unit's life the history so far is
trended (``prognose``) into a remaining-useful-life prediction, scored against the truth with
the alpha-lambda accuracy of PHM (Saxena et al., 2010: at a fraction lambda of life, is the
prediction within +-alpha of the true RUL? alpha = 30 % here), twice: the median against the
bounds, and progpy's own metric (``progpy.metrics.alpha_lambda``: at least beta = 50 % of the
Monte-Carlo end-of-life distribution within them; progpy is the ``[progpy]`` extra). Prints the
table and writes doc/figures/prognosis.png.

    .venv/bin/python doc/examples/prognosis.py [--units 6] [--seed 2]
"""

import argparse
import math
import time
from pathlib import Path

import numpy as np

from servovalve_twin.config import load_scenario
from servovalve_twin.physics.params import DEFAULTS
from servovalve_twin.apps.diagnose import flight_entry
from servovalve_twin.prognostics.metrics import alpha_lambda
from servovalve_twin.prognostics.diagnosis import UNEXPLAINED, diagnose
from servovalve_twin.prognostics.prognosis import prognose
from servovalve_twin.prognostics.sweep import draw_nuisance, measured
from servovalve_twin.runs import simulate

VARY = {'M': 0.1, 'CJ': 0.2, 'FDJ': 0.2}
NOISE = {'xj': 10e-6, 'dxj': 1e-3, 'p12': 50e3}
ALARM = 10.0                       # leakage_growth's alarm severity in the catalog
ALPHA = 0.3
BETA = 0.5
LAMBDAS = (0.25, 0.5, 0.75)


def flight(unit_params, severity, rng):
    """One flight of a unit: HD with its parameters and leakage, measured with noise."""
    scn = dict(load_scenario('paper').to_dict(),
               faults=[{'at': 0.0, 'fault': 'leakage_growth', 'severity': severity}])
    return measured(simulate('HD', scn, params=unit_params, ecu_period=1e-3).signals, NOISE,
                    rng)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument('--units', type=int, default=6)
    ap.add_argument('--seed', type=int, default=2)
    ap.add_argument('--figure', default='doc/figures/prognosis.png')
    args = ap.parse_args()
    rng = np.random.default_rng(args.seed)
    t0 = time.perf_counter()
    rows, units = [], []
    for u in range(args.units):
        unit = DEFAULTS.replace(**draw_nuisance(rng, VARY, DEFAULTS))
        eol = float(rng.uniform(30, 50))
        rate = math.log(ALARM) / eol                  # severity = exp(rate * n): 1 at n = 0
        checkpoints = {lam: int(round(lam * eol)) for lam in LAMBDAS}
        history = []
        for n in range(max(checkpoints.values()) + 1):
            truth = math.exp(rate * n)
            d = diagnose(flight(unit, truth, rng), DEFAULTS, control_period=1e-3, model='SQ',
                         faults=['leakage_growth'], free=('M', 'CJ'), scenario='paper')
            # as `prognose` does with bags: the model-form correction and spread alike
            c = next(c for c in d.candidates if c.fault == 'leakage_growth')
            history.append(dict(flight_entry(d, 'leakage_growth', float(n)), truth=truth,
                                stated=tuple(c.interval),
                                named=d.best is c and d.verdict != UNEXPLAINED))
        for lam, n in checkpoints.items():
            p = prognose([{k: v for k, v in h.items() if k not in ('truth', 'stated', 'named')}
                          for h in history[:n + 1]], 'leakage_growth', ALARM)
            true_rul = eol - n
            ok = abs(p.rul['median'] - true_rul) <= ALPHA * true_rul
            # progpy's metric on the predicted end of life (cycle of the prediction + RUL)
            met = alpha_lambda({float(n): p.draws}, eol, float(n), alpha=ALPHA, beta=BETA)
            held = p.rul['p05'] <= true_rul <= p.rul['p95']
            rows.append(dict(unit=u, eol=eol, lam=lam, n=n, true=true_rul, rul=p.rul,
                             trend=p.trend.kind, ok=ok, progpy=bool(met), held=held,
                             status=p.status))
        units.append((unit, eol, history))
        print(f'unit {u}: EOL {eol:.1f} flights; M x{unit.M / DEFAULTS.M:.3f}, CJ '
              f'x{unit.CJ / DEFAULTS.CJ:.3f}, FDJ x{unit.FDJ / DEFAULTS.FDJ:.3f}', flush=True)
    wall = time.perf_counter() - t0
    sev_err = [abs(h['severity'] / h['truth'] - 1) for _, _, hist in units for h in hist]
    inside = [h['interval'][0] <= h['truth'] <= h['interval'][1]
              for _, _, hist in units for h in hist]
    stated = [h['stated'][0] <= h['truth'] <= h['stated'][1]
              for _, _, hist in units for h in hist if h['named']]
    named = [h['truth'] for _, _, hist in units for h in hist if h['named']]
    unnamed = [h['truth'] for _, _, hist in units for h in hist if not h['named']]
    print(f'\n{args.units} units, {sum(len(h) for _, _, h in units)} flights diagnosed in '
          f'{wall:.0f} s; severity error median {np.median(sev_err):.1%}, 95th percentile '
          f'{np.percentile(sev_err, 95):.1%}; named in {len(stated)} (the others healthy: '
          f'truth at most {max(unnamed, default=math.nan):.3g}, the lowest named '
          f'{min(named, default=math.nan):.3g}), '
          f'the truth inside the verdict\'s 90 % interval (model-form included) in '
          f'{sum(stated)}, inside the noise-only interval '
          f'handed to prognose (the model-form spread goes as model_sigma, common to a '
          f'unit\'s flights) in {np.mean(inside):.0%}\n')
    print('| fraction of life | units | RUL median / truth, each unit | median within +-30 % '
          '| progpy alpha_lambda (beta 0.5) | 90 % RUL interval holds the truth '
          '| verdict, trend chosen |')
    print('|---|---|---|---|---|---|---|')
    for lam in LAMBDAS:
        rs = [r for r in rows if r['lam'] == lam]
        ratios = ', '.join(f'{r["rul"]["median"] / r["true"]:.2f}' for r in rs)
        trends = ', '.join(sorted({f'{r["status"]} ({r["trend"]})' for r in rs}))
        print(f'| {lam:.2f} | {len(rs)} | {ratios} | {sum(r["ok"] for r in rs)}/{len(rs)} | '
              f'{sum(r["progpy"] for r in rs)}/{len(rs)} | {sum(r["held"] for r in rs)}/'
              f'{len(rs)} | {trends} |')
    plot(units, rows, args.figure)
    print(f'\nfigure: {args.figure}')


def plot(units, rows, path) -> None:
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    fig, (ax, ax2) = plt.subplots(1, 2, figsize=(11.0, 4.2))
    for i, (_, eol, hist) in enumerate(units):
        n = [h['cycles'] for h in hist]
        ax.plot(n, [h['truth'] for h in hist], color=f'C{i}', lw=1)
        ax.errorbar(n, [h['severity'] for h in hist],
                    yerr=[[h['severity'] - h['interval'][0] for h in hist],
                          [h['interval'][1] - h['severity'] for h in hist]],
                    fmt='.', color=f'C{i}', ms=3, lw=0.5)
    ax.axhline(ALARM, color='k', ls='--', lw=0.8)
    ax.set_xlabel('flight', fontsize=9)
    ax.set_ylabel('leakage severity [x CLk]', fontsize=9)
    ax.set_title('truth (lines) and diagnosed with SQ (dots: the noise-only 95 % interval\n'
                 'handed to prognose, which adds the model-form spread)', fontsize=9)
    ax.grid(True, lw=0.3)
    for r in rows:
        x = r['lam'] + (r['unit'] - len(units) / 2) * 0.01
        med, lo, hi = (min(r['rul'][k] / r['true'], 3.0) for k in ('median', 'p05', 'p95'))
        ax2.errorbar([x], [med], yerr=[[med - lo], [hi - med]], fmt='o',
                     color=f'C{r["unit"]}', ms=4, lw=0.8)
    ax2.axhspan(1 - ALPHA, 1 + ALPHA, color='0.9', label='+-30 % of the true RUL')
    ax2.axhline(1.0, color='k', lw=0.8)
    ax2.set_xlabel('fraction of life at the prediction (lambda)', fontsize=9)
    ax2.set_ylabel('predicted / true RUL', fontsize=9)
    ax2.set_title('RUL predicted by prognose (median, 90 %)', fontsize=9)
    ax2.set_ylim(0, 3)
    ax2.legend(fontsize=8)
    ax2.grid(True, lw=0.3)
    fig.tight_layout()
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=90)
    plt.close(fig)


if __name__ == '__main__':
    main()
