"""Score the LeakDetector over a fault sweep, as `servovalve-twin sweep --algorithm` does: the
fleet of doc/examples/leakage_detection.py (HD plants, mass +-10 %, viscous and dynamic friction
+-20 %, leakage from 0.1 s) -- the same runs the C2 and SQ monitors were scored on there.

    PYTHONPATH=doc/examples/my_detector .venv/bin/python doc/examples/my_detector/score.py
"""

import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from servovalve_twin.prognostics.dataset import summarize  # noqa: E402
from servovalve_twin.prognostics.sweep import make_cases, run_cases  # noqa: E402

SEVERITIES = [2.0, 3.0, 5.0, 7.0, 10.0, 15.0, 20.0]
VARY = {'M': 0.1, 'CJ': 0.2, 'FDJ': 0.2}


def main() -> None:
    cases = make_cases(plant_model='HD', scenario='paper', faults={'leakage_growth': SEVERITIES},
                       repeats=8, nominal_runs=20, vary=VARY, onset=0.1, seed=1,
                       algorithm='leak_detector:LeakDetector')
    t0 = time.perf_counter()
    rows = [r['row'] for r in run_cases(cases)]
    wall = time.perf_counter() - t0
    s = summarize(rows)
    healthy = [r['peak_leak_index'] for r in rows if not r['faulty']]
    print(f'{len(rows)} runs in {wall:.1f} s; false alarms {s["false_alarms"]}/'
          f'{s["nominal_runs"]}; healthy peak leak index {min(healthy):.2f}-{max(healthy):.2f}')
    print('| leakage (x CLk) | LeakDetector: detected | mean delay |')
    print('|---|---|---|')
    for r in s['faults']['leakage_growth']:
        delay = '-' if r['mean_delay'] is None else f'{r["mean_delay"] * 1e3:.0f} ms'
        print(f'| {r["severity"]:g} | {round(r["detection_rate"] * r["runs"])}/{r["runs"]} | '
              f'{delay} |')


if __name__ == '__main__':
    main()
