"""A plain ``pip install .`` as a user without the project's scripts does it: a fresh venv,
the install timed (PyPI downloads, the wheel's build with the step loops compiled ahead of time
by setup.py's build_py), then ``servovalve-twin simulate`` run ``--repeat`` times as separate
processes, each checked not to import numba (``-X importtime``): the loops come from the
compiled module, nothing is compiled after the install.

Needs PyPI (the venv's dependencies) and gcc; about 3-7 min, most of it the install.

    .venv/bin/python bench/bench_install.py [--repeat 5] [--keep DIR]
"""

import argparse
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--repeat', type=int, default=5)
    ap.add_argument('--keep', type=Path, help='make the venv here and keep it')
    args = ap.parse_args()
    work = Path(tempfile.mkdtemp())
    venv = args.keep or work / 'venv'
    try:
        subprocess.run([sys.executable, '-m', 'venv', str(venv)], check=True)
        py = venv / 'bin' / 'python'
        t = time.perf_counter()
        r = subprocess.run([str(py), '-m', 'pip', 'install', '-q', str(ROOT)],
                           capture_output=True, text=True)
        install_s = time.perf_counter() - t
        if r.returncode:
            print(r.stdout[-3000:], r.stderr[-3000:], file=sys.stderr)
            return 1
        check = subprocess.run([str(py), '-m', 'servovalve_twin.aot', '--check'], cwd=work)
        times, numba = [], []
        for i in range(args.repeat):
            t = time.perf_counter()
            p = subprocess.run([str(py), '-X', 'importtime', str(venv / 'bin' / 'servovalve-twin'),
                                'simulate', '--valve-model', 'SQ', '--out',
                                str(work / f'run{i}.csv')], cwd=work, capture_output=True,
                               text=True)
            times.append(time.perf_counter() - t)
            if p.returncode:
                print(p.stderr[-2000:], file=sys.stderr)
                return 1
            numba.append(any(line.split('|')[-1].strip().split('.')[0] == 'numba'
                             for line in p.stderr.splitlines() if '|' in line))
        print('| what | measured |')
        print('|---|---|')
        print(f'| `pip install .` into a fresh venv (downloads, build, the loops compiled) | '
              f'{install_s:.0f} s |')
        print(f'| the compiled loops installed (`python -m servovalve_twin.aot --check`) | '
              f'{"yes" if check.returncode == 0 else "no"} |')
        print(f'| `servovalve-twin simulate --valve-model SQ` as a process, median of '
              f'{args.repeat} | {statistics.median(times):.2f} s (max {max(times):.2f} s); '
              f'numba imported in {sum(numba)} of {args.repeat} |')
        return 0 if check.returncode == 0 and not any(numba) else 1
    finally:
        shutil.rmtree(work, ignore_errors=True)


if __name__ == '__main__':
    sys.exit(main())
