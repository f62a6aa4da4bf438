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
                 process_noise={'leakage_growth': 10.0, 'leakage_growth_growth': 20.0})
    x0 = dict(zip(m.states, np.asarray(m.initialize(u={'psr': psr[0]}).matrix)[:, 0]))
    samples = [dict(x0, leakage_growth=rng.uniform(1.0, 4.0),
                    leakage_growth_growth=rng.uniform(0.0, 30.0)) for _ in range(300)]
    pf = ParticleFilter(m, UnweightedSamples(samples), num_particles=300,
                        measurement_noise={'xj': 5e-5, 'dxj': 3e-3, 'p12': 1e5})
    for i in range(400):                # the unit flies; every 5 ms the filter takes a reading
        u = m.InputContainer({'com': com[i], 'fr': fr[i], 'psr': psr[i]})
        x = truth.next_state(x, u, 1e-3)
        if (i + 1) % 5 == 0:
            z = {k: float(np.asarray(truth.output(x)[k]).ravel()[0]) + rng.normal(0, sd)
                 for k, sd in NOISE.items()}
            pf.estimate(t[i + 1], u, z, dt=1e-3)

    def load(tt, xx=None):
        return m.InputContainer({'com': 0.02, 'fr': 0.0, 'psr': 2.0e7})
    res = MonteCarlo(m).predict(pf.x, load, t0=NOW, horizon=1.0, n_samples=50)
    toe = np.array(res.time_of_event.key('leakage_growth_alarm'), dtype=float)
    true_toe = (ALARM - LEAK0) / RATE
    rul = float(np.median(toe)) - NOW
    print(f'filter model {args.model}, seed {args.seed}: leak {pf.x.mean["leakage_growth"]:.2f} '
          f'(truth {LEAK0 + RATE * NOW:.2f}), growth {pf.x.mean["leakage_growth_growth"]:.2f} '
          f'/s (truth {RATE:.2f}); alarm at {np.median(toe):.3f} s [{np.percentile(toe, 5):.3f}, '
          f'{np.percentile(toe, 95):.3f}] (truth {true_toe:.3f}); RUL {rul:.3f} s, '
          f'{rul / (true_toe - NOW) - 1:+.0%} off; {time.perf_counter() - t0:.0f} s')


if __name__ == '__main__':
    main()
