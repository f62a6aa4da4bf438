"""The results report: every registered model against HD on the paper scenario, and SQ against
C1-C3 beyond it.

``servovalve-twin report [--out-dir out/report]`` writes ``report.md`` (the tables, with the
machine and its load while it measured: the step costs depend on them) and the figures into a
new (or empty) directory. It never edits a file of the repository: the results pages
(doc/results/against-hd.md, beyond-the-paper.md) and doc/figures are updated by copying from
there, after a quiet-machine run.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Mapping


from ..outputs import discard_directory, write_new
from ..physics.characteristic import characteristic
from ..physics.params import make_params
from ..physics.signals import MEASURED
from ..physics.simulate import RunResult
from ..physics.valves import VALVE_MODEL_NAMES
from ..progress import progress
from ..runs import simulate
from .compare import error_metrics
from .plots import plot_characteristic, plot_overlay

#: the scenarios of the comparison beyond the paper, with the windows reported beside the run
BEYOND_SCENARIOS = (('paper', None, ('overstall', 'braking')),
                    ('paper', {'CLk': 2e-12}, ('overstall', 'braking')),
                    ('sine_opposing', None, ('late',)))
BEYOND_MODELS = ('SQ', 'C1', 'C2', 'C3')
DROP_WINDOW = ('overstall', (0.35, 0.50))


def back_movement(r: RunResult) -> float:
    """XJ at 0.35 s minus the minimum XJ in [0.35, 0.60] s [m] (the over-stall back movement)."""
    xj = r['xj']
    return float(xj[r.window(0.35, 0.35, closed=True)][0] - xj[r.window(0.35, 0.60, True)].min())


def paper_runs(overrides: Mapping[str, Any] | None = None) -> dict[str, RunResult]:
    return {m: simulate(m, 'paper', overrides)
            for m in progress(VALVE_MODEL_NAMES, desc='report: paper runs', unit='model')}


def make_report(*, out_dir: Path, overrides: Mapping[str, Any] | None = None) -> str:
    """Write ``out_dir/report.md`` and the figures; ``out_dir`` must be new or empty (nothing
    is overwritten). Returns the page's text."""
    import os
    import platform
    import time
    from .. import __version__
    from ..errors import TwinError
    if out_dir.exists() and (not out_dir.is_dir() or any(out_dir.iterdir())):
        raise TwinError(f'--out-dir {out_dir}: exists and is not an empty directory; report '
                        'writes into a new one (nothing is overwritten)')
    load0 = os.getloadavg()[0]
    created = not out_dir.exists()
    try:
        tables = _tables(out_dir, overrides)
        import numba
        page = (f'# servovalve_twin report\n\nservovalve_twin {__version__}, '
                f'{time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())}; '
                f'{platform.processor() or platform.machine()}, {os.cpu_count()} CPUs, Python '
                f'{platform.python_version()}, numba {numba.__version__}; load average '
                f'{load0:.2f} before, {os.getloadavg()[0]:.2f} after (the step costs move with '
                f'it).\n\n{tables}\n')
        write_new(out_dir / 'report.md', page)
    except BaseException:
        # a report is whole or absent (a full disk left an empty directory, or figures
        # without their page)
        discard_directory(out_dir, created)
        raise
    return page


def _tables(out_dir: Path, overrides: Mapping[str, Any] | None) -> str:
    runs = paper_runs(overrides)
    ref = runs['HD']
    out_dir.mkdir(parents=True, exist_ok=True)
    windows = dict([DROP_WINDOW])
    lines = [
        '| model | XJ rms / max [mm] | DXJ rms / max [mm/s] | P12 rms / max [MPa] | '
        'XJ rms / max, 0.35-0.50 s [mm] | DXJ rms / max, 0.35-0.50 s [mm/s] | '
        'P12 rms / max, 0.35-0.50 s [MPa] | back movement [mm] | peak P12 after 0.75 s [MPa] |',
        '|---|---|---|---|---|---|---|---|---|']
    for name, r in runs.items():
        m = error_metrics(ref.signals, r.signals, windows, MEASURED)
        cells = []
        for w in ('all', DROP_WINDOW[0]):
            for sig, scale in (('xj', 1e3), ('dxj', 1e3), ('p12', 1e-6)):
                e = m[w][sig]
                cells.append(f'{e["rms"] * scale:.3g} / {e["max"] * scale:.3g}')
        peak = r['p12'][r.window(0.75, 1.0, closed=True)].max()
        lines.append(f'| {name} | ' + ' | '.join(cells) +
                     f' | {back_movement(r) * 1e3:.2f} | {peak * 1e-6:.2f} |')
        if name != 'HD':
            plot_overlay({'HD': ref.signals, name: r.signals}, out_dir / f'paper_{name}.png',
                         title=f'{name} against HD, paper scenario', reference='HD',
                         shade=[(0.35, 0.45)])
    plot_overlay({n: runs[n].signals for n in ('HD', 'C1', 'C2', 'C3')},
                 out_dir / 'paper_C1_C2_C3.png', reference='HD',
                 title='C1, C2, C3 against HD (paper Figs. 19-23)', shade=[(0.35, 0.45)])
    params = make_params(overrides)
    curves = {n: characteristic(n, params, params.PSRN, [0.0, 8.0e-5], n_points=201)
              for n in ('HD', 'C1', 'C2', 'C3', 'SQ')}
    plot_characteristic(curves, out_dir / 'characteristic.png', params.PSRN)
    table = '\n'.join(lines)
    text = (f'## Every model against HD, paper scenario\n\n{table}\n\nErrors are run - HD over '
            f'the 1 ms rows of the paper scenario (whole run, and the over-stall window '
            f'0.35-0.50 s). Back movement = XJ(0.35 s) - min XJ over 0.35-0.60 s. '
            f'`servovalve-twin report`; figures beside this page.')
    return text + '\n\n## SQ against C1, C2, C3 beyond the paper\n\n' + beyond_report(out_dir)


_COST_CHILD = """
import sys
from servovalve_twin.runs import simulate
for model in sys.argv[1:]:
    simulate(model)
    print(min(simulate(model).info['wall_s'] for _ in range(7)) / 100000 * 1e6)
"""


def step_costs_us(models, processes: int = 3) -> dict[str, float]:
    """Physics cost per plant step [us] of the paper scenario, per model: the median, over
    ``processes`` fresh processes, of the fastest of 7 runs. Fresh processes because on this
    machine a compiled loop lands in a fast or a slow mode (about 2x) per process; every
    process measures every model (one start-up per process, not per model)."""
    import statistics
    import subprocess
    import sys
    models = list(models)
    costs = [[float(x) for x in subprocess.run(
        [sys.executable, '-c', _COST_CHILD, *models], check=True, capture_output=True,
        text=True).stdout.split()[-len(models):]]
        for _ in progress(range(processes), desc='report: step cost', unit='process')]
    return {m: statistics.median(c[i] for c in costs) for i, m in enumerate(models)}


def beyond_report(out_dir: Path) -> str:
    """SQ against C1, C2, C3 on three scenarios, errors against HD and step cost."""
    from ..config import load_scenario
    out_dir.mkdir(parents=True, exist_ok=True)
    cost = step_costs_us(BEYOND_MODELS)
    lines = ['| scenario | model | XJ rms / max [mm] | DXJ rms / max [mm/s] | P12 rms / max [MPa] '
             '| window | XJ rms / max [mm] | DXJ rms / max [mm/s] | P12 rms / max [MPa] | '
             'step cost [us] |', '|---|---|---|---|---|---|---|---|---|---|']
    for scenario, overrides, wins in progress(BEYOND_SCENARIOS, desc='report: beyond the paper',
                                              unit='scenario'):
        scn = load_scenario(scenario)
        label = scenario + (' ' + ', '.join(f'{k}={v:g}' for k, v in overrides.items())
                            if overrides else '')
        ref = simulate('HD', scn, overrides)
        runs = {'HD': ref.signals}
        for model in BEYOND_MODELS:
            r = simulate(model, scn, overrides)
            runs[model] = r.signals
            m = error_metrics(ref.signals, r.signals, {w: scn.windows[w] for w in wins},
                              MEASURED)
            for i, w in enumerate(wins):
                t0, t1 = scn.windows[w]
                first = i == 0
                cells = [label if first else '', model if first else '',
                         *(_cells(m['all']) if first else ['', '', '']), f'{w} {t0:g}-{t1:g} s',
                         *_cells(m[w]), f'{cost[model]:.3f}' if first else '']
                lines.append('| ' + ' | '.join(cells) + ' |')
        tag = scenario + ('_CLk' if overrides else '')
        plot_overlay({k: runs[k] for k in ('HD', 'C2', 'SQ')}, out_dir / f'beyond_{tag}.png',
                     reference='HD', title=f'SQ and C2 against HD: {label}')
    return ('\n'.join(lines) + '\n\nErrors are run - HD over the 1 ms rows. Step cost: physics '
            'time per 10 us plant step on the paper scenario, plant mechanics included (median '
            'over 3 fresh processes of the fastest of 7 runs; `servovalve-twin report`).')


def _cells(m) -> list[str]:
    return [f'{m[s]["rms"] * k:.3g} / {m[s]["max"] * k:.3g}'
            for s, k in (('xj', 1e3), ('dxj', 1e3), ('p12', 1e-6))]
