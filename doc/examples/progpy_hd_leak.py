"""progpy's tutorial loop on HD data: an HD unit whose leakage grows at 10 x CLk per second
from 2 x (the catalog's alarm, 10 x, reached at 0.8 s) flies 0.4 s of steps under load, measured
with noise (XJ 10 um, DXJ 1 mm/s, P12 50 kPa) every 5 ms; progpy's ParticleFilter (300
particles, the leak and its growth rate as random walks) estimates both, then MonteCarlo
predicts the time of the alarm from t = 0.4 s -- half of life. The filter's model is
``--model`` (HD by default: the data's own physics; SQ shows what its mismatch against HD does
to the filter). Prints the estimates, the predicted time of event and the RUL's error.

    .venv/bin/python doc/examples/progpy_hd_leak.py [--seed 3] [--model HD|SQ]
"""

import argparse
import math
import time

import numpy as np
from progpy.predictors import MonteCarlo
from progpy.state_estimators import ParticleFilter
from progpy.uncertain_data import UnweightedSamples

from servovalve_twin.config import load_scenario
from servovalve_twin.progpy import EhaModel

FLIGHT = {'duration': 0.4, 'com': [[0.0, 0.02], [0.05, -0.01], [0.1, 0.02], [0.2, -0.01],
                                   [0.3, 0.02]],
          'fr': [[0.0, 0.0], [0.05, 3000.0]]}
LEAK0, RATE, ALARM, NOW = 2.0, 10.0, 10.0, 0.4
NOISE = {'xj': 1e-5, 'dxj': 1e-3, 'p12': 5e4}
#: the filter's prior of its two parameter states: the leak [x CLk] and its growth rate [x/s]
PRIOR = {'leakage_growth': (1.0, 4.0), 'leakage_growth_growth': (0.0, 30.0)}
PARTICLES, EVERY, STEP = 300, 5, 1e-3   # a reading every 5 control periods of 1 ms


def roughening(lo: float, hi: float) -> float:
    """progpy's process noise of a parameter state (each step adds dt * N(0, q)): the
    roughening of Gordon, Salmond and Smith (1993), a jitter of sd K E N^(-1/d) per reading
    (K = 0.2, E the prior's range, N the particles, d the parameter states). Without it the
    particles' growth rates stay the prior's draws, and after a few resamplings one or two of
    them stand for the whole posterior: a rate of 6.7 /s for 10, its interval missing it."""
    per_reading = 0.2 * (hi - lo) * PARTICLES ** (-1 / len(PRIOR))
    return per_reading / (STEP * math.sqrt(EVERY))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--seed', type=int, default=3)
    ap.add_argument('--model', default='HD', help="the filter's valve model (default HD)")
    args = ap.parse_args()
    t0 = time.perf_counter()
    truth = EhaModel(valve_model='HD', degradation=['leakage_growth'],
                     x0={'leakage_growth': LEAK0}, growth={'leakage_growth': RATE})
    t = np.arange(0, 401) * 1e-3
    com, fr, psr = load_scenario(FLIGHT).inputs((t * 1e9).round().astype(np.int64))
    x = truth.initialize(u={'psr': psr[0]})
    rng = np.random.default_rng(args.seed)
    np.random.seed(0)                   # progpy's process noise and filterpy's resampling
    m = EhaModel(valve_model=args.model, degradation=['leakage_growth'],
                 process_noise={k: roughening(*v) for k, v in PRIOR.items()})
    x0 = dict(zip(m.states, np.asarray(m.initialize(u={'psr': psr[0]}).matrix)[:, 0]))
    samples = [dict(x0, **{k: rng.uniform(*v) for k, v in PRIOR.items()})
               for _ in range(PARTICLES)]
    pf = ParticleFilter(m, UnweightedSamples(samples), num_particles=PARTICLES,
                        measurement_noise={'xj': 5e-5, 'dxj': 3e-3, 'p12': 1e5})
    for i in range(400):                # the unit flies; every EVERY steps the filter reads it
        u = m.InputContainer({'com': com[i], 'fr': fr[i], 'psr': psr[i]})
        x = truth.next_state(x, u, STEP)
        if (i + 1) % EVERY == 0:
            z = {k: float(np.asarray(truth.output(x)[k]).ravel()[0]) + rng.normal(0, sd)
                 for k, sd in NOISE.items()}
            pf.estimate(t[i + 1], u, z, dt=STEP)

    def load(tt, xx=None):
        return m.InputContainer({'com': 0.02, 'fr': 0.0, 'psr': 2.0e7})
    res = MonteCarlo(m).predict(pf.x, load, t0=NOW, horizon=1.0, n_samples=50)
    # a sample that does not reach the alarm within the horizon has no time of event (None):
    # its life is longer than the horizon, so it counts as infinite, not as missing
    toe = np.array([math.inf if v is None else v
                    for v in res.time_of_event.key('leakage_growth_alarm')], dtype=float)
    true_toe = (ALARM - LEAK0) / RATE
    ranked = np.sort(toe)           # order statistics: no arithmetic on an infinite life
    p05, p50, p95 = (ranked[int(round(q * (len(toe) - 1)))] for q in (0.05, 0.5, 0.95))
    rul = float(p50) - NOW
    print(f'filter model {args.model}, seed {args.seed}: leak {pf.x.mean["leakage_growth"]:.2f} '
          f'(truth {LEAK0 + RATE * NOW:.2f}), growth {pf.x.mean["leakage_growth_growth"]:.2f} '
          f'/s (truth {RATE:.2f}); alarm at {p50:.3f} s [{p05:.3f}, {p95:.3f}] (truth '
          f'{true_toe:.3f}); RUL {rul:.3f} s, '
          f'{rul / (true_toe - NOW) - 1:+.0%} off; {time.perf_counter() - t0:.0f} s')


if __name__ == '__main__':
    main()
