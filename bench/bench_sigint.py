"""How fast each ROS executable of the package stops on SIGINT (issue: a launch stopped by
Ctrl-C waited 2-3 s per node under load, the interpreter's teardown after numba and scipy).

Each executable is started as ``ros2 run`` would start it (the console script), left until it
says it is up (its one start-up line), then sent SIGINT; the time from the signal to the
process's exit is measured, ``--repeat`` times each, and the exit code checked (0 for the
nodes, the twin and the player: a clean stop). A second SIGINT 50 ms after the first checks
that a stop in progress is not an error. With ``--at S`` the signal goes S seconds after the
process started instead, whatever it is doing then (importing, creating its node, loading the
compiled loops): the window before "started" (its output is checked for a traceback).

Run it inside ../shared/tools/isolated, on a quiet machine:

    ../shared/tools/isolated .venv/bin/python bench/bench_sigint.py [--repeat 5] [--at 0.05]
"""

import argparse
import os
import signal
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / 'test'))

LONG = 'duration: 600.0\ncom: [[0.0, 0.02]]\n'


def executables(tmp: Path) -> dict[str, tuple[list[str], str]]:
    """name -> (arguments after the executable, the line that says it is up)."""
    scenario = tmp / 'long.yaml'
    scenario.write_text(LONG)
    bag = ROOT / 'servovalve_twin' / 'data' / 'paper_HD'
    node = lambda *p: (['--ros-args', *sum((['-p', x] for x in p), [])], 'started:')  # noqa
    return {
        'clock': node(),
        'command_generator': node(),
        'load_supply': node(),
        'ecu': node(),
        'plant': node('valve_model:=HD'),
        'monitor': node(),
        'twin': (['--ros-args', '-p', 'valve_model:=HD', '-p', f'scenario:={scenario}',
                  '-p', 'record:=false'], 'twin: running'),
        'player': (['--ros-args', '-p', f'bag:={bag}', '-p', 'rate:=0.01'], 'player: playing'),
    }


def one(exe: str, args: list[str], ready: str, second: bool, at: float | None = None
        ) -> tuple[float, int, bool]:
    """(seconds from SIGINT to exit, exit code, whether it printed a traceback)."""
    proc = subprocess.Popen([exe, *args], stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            text=True, bufsize=1)
    up = threading.Event()
    lines: list[str] = []

    def watch():
        for line in proc.stdout:
            lines.append(line)
            if ready in line:
                up.set()
    reader = threading.Thread(target=watch, daemon=True)
    reader.start()
    if at is not None:
        time.sleep(at)
    elif not up.wait(180):
        proc.kill()
        raise RuntimeError(f'{exe} did not come up')
    else:
        time.sleep(0.3)
    t = time.perf_counter()
    proc.send_signal(signal.SIGINT)
    if second:
        time.sleep(0.05)
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)
    code = proc.wait(60)
    took = time.perf_counter() - t
    reader.join(5)
    return took, code, any('Traceback' in line for line in lines)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--repeat', type=int, default=5)
    ap.add_argument('--at', type=float, metavar='S',
                    help='send the SIGINT S seconds after the start (default: once it is up)')
    args = ap.parse_args()
    from conftest import console_script
    with tempfile.TemporaryDirectory() as d:
        table = executables(Path(d))
        print('| executable | SIGINT -> exit, median [s] | max [s] | exit codes | '
              'second SIGINT: exit code | tracebacks |')
        print('|---|---|---|---|---|---|')
        for name, (a, ready) in table.items():
            exe = console_script(name)
            runs = [one(exe, a, ready, False, args.at) for _ in range(args.repeat)]
            _, code2, tb2 = one(exe, a, ready, True, args.at)
            times = [t for t, _, _ in runs]
            print(f'| {name} | {statistics.median(times):.3f} | {max(times):.3f} | '
                  f'{sorted(set(c for _, c, _ in runs))} | {code2} | '
                  f'{sum(tb for _, _, tb in runs) + tb2} |', flush=True)
    print(f'\n{os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.2f} at the end')
    return 0


if __name__ == '__main__':
    sys.exit(main())
