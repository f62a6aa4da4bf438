"""The results report: every registered model against HD on the paper scenario.

``servovalve-twin report --readme README.md`` regenerates the table between the README's
``<!-- results:begin -->`` / ``<!-- results:end -->`` markers and the figures in ``docs/figures``.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from .compare import error_metrics, plot_overlay
from .physics.characteristic import characteristic, plot_characteristic
from .physics.params import make_params
from .physics.simulate import RunResult, simulate
from .physics.valves import VALVE_MODEL_NAMES

BEGIN, END = '<!-- results:begin -->', '<!-- results:end -->'
DROP_WINDOW = ('overstall', (0.35, 0.50))


def back_movement(r: RunResult) -> float:
    """XJ at 0.35 s minus the minimum XJ in [0.35, 0.60] s [m] (the over-stall back movement)."""
    xj = r['xj']
    return float(xj[r.window(0.35, 0.35, closed=True)][0] - xj[r.window(0.35, 0.60, True)].min())


def paper_runs(overrides: Mapping[str, Any] | None = None) -> dict[str, RunResult]:
    return {m: simulate(m, 'paper', overrides) for m in VALVE_MODEL_NAMES}


def make_report(*, out_dir: Path, readme: Path | None = None,
                overrides: Mapping[str, Any] | None = None) -> str:
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
        m = error_metrics(ref.signals, r.signals, windows, ('xj', 'dxj', 'p12'))
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
              for n in ('HD', 'C1', 'C2', 'C3')}
    plot_characteristic(curves, out_dir / 'characteristic.png', params.PSRN)
    table = '\n'.join(lines)
    text = (f'{table}\n\nErrors are run - HD over the 1 ms rows of the paper scenario (whole run, '
            f'and the over-stall window 0.35-0.50 s). Back movement = XJ(0.35 s) - min XJ over '
            f'0.35-0.60 s. Regenerate with `servovalve-twin report --readme README.md`; '
            f'figures in `{out_dir.as_posix()}/`.')
    if readme is not None:
        body = readme.read_text(encoding='utf-8')
        if BEGIN not in body or END not in body:
            from .errors import TwinError
            raise TwinError(f'{readme} has no {BEGIN} ... {END} section to replace')
        body = re.sub(re.escape(BEGIN) + '.*?' + re.escape(END),
                      lambda _m: f'{BEGIN}\n{text}\n{END}', body, flags=re.S)
        readme.write_text(body, encoding='utf-8')
    return text
