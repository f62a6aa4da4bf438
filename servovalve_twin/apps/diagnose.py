"""``diagnose`` and ``prognose`` on bags: reading them, the JSON outputs and the plots (the
fitting itself is :mod:`..prognostics.diagnosis` and :mod:`..prognostics.prognosis`)."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from ..bag.anybag import open_any_bag
from ..bag.reader import read_bag_until
from ..errors import TwinError
from ..outputs import output_path
from ..prognostics.calibration import alpha_of, calibration_for
from ..prognostics.conformal import ALPHA
from ..prognostics.diagnosis import (DIAGNOSABLE, HEALTHY, SIGNALS, UNEXPLAINED, Diagnosis,
                                     diagnose)
from ..prognostics.flight_calibration import OWN, cached, flight_key, with_pooled
from ..prognostics.modelform import model_form_estimate
from ..prognostics.prognosis import MIN_CYCLES, Prognosis, prognose
from .plots import plot_overlay
from .replay import bag_params


def parse_window(text: str | None) -> tuple[float, float] | None:
    if text is None:
        return None
    try:
        t0, t1 = (float(x) for x in text.split(':'))
    except ValueError:
        raise TwinError(f'--window {text!r}: expected T0:T1 in seconds, e.g. 0.2:1.0'
                        ) from None
    return t0, t1


def parse_faults(text: str | None) -> tuple[str, ...]:
    if text is None or text == 'all':
        return DIAGNOSABLE
    return tuple(n.strip() for n in text.split(',') if n.strip())


def calibration_scenario(provenance) -> str | None:
    """The calibration scenario (:data:`..prognostics.calibration_set.CAL_SCENARIOS`) a bag
    flew, if its recorded inputs are that scenario's, whatever it was called; else None."""
    from ..config import load_scenario
    from ..prognostics.calibration_set import CAL_SCENARIOS
    if not provenance or provenance.scenario is None:
        return None
    flown = provenance.scenario_object()

    def inputs(scn):
        d = scn.to_dict()
        return [d.get(k) for k in ('duration', 'com', 'fr', 'psr')]
    for name, spec in CAL_SCENARIOS.items():
        if inputs(load_scenario(spec)) == inputs(flown):
            return name
    return None


#: the latest window end diagnose fits [s]: the model is integrated from t = 0 (its state is
#: not measured), so a fit's time (~2.5 s CPU per second) and memory grow with that end,
#: not with the window -- a late window of a long flight would take hours
MAX_FIT_END_S = 120.0


def diagnose_bag(bag: str | Path, *, model: str = 'SQ', faults: Sequence[str] = DIAGNOSABLE,
                 window: tuple[float, float] | None = None, free: Sequence[str] = (),
                 bootstrap: int = 0, pairs: bool = False,
                 nominal: Mapping[str, Any] | None = None,
                 control_period: float | None = None, onset: bool = False,
                 alpha: float = ALPHA) -> Diagnosis:
    """Diagnose a recorded run against the parameters and control period it was recorded
    with (its provenance record), ``nominal`` overriding them. The model-form calibration
    applies unless the bag says it was recorded with the fitted model itself (then exact). A
    bag without provenance, diagnosed without stated ``nominal`` parameters, is
    ``unexplained``: its design is not known, so no fault can be measured against it."""
    end = window[1] if window is not None else open_any_bag(bag).end_ns * 1e-9
    if end > MAX_FIT_END_S:
        raise TwinError(f'{bag}: diagnose integrates the model from t = 0 to the end of the '
                        f'window, here {end:.6g} s; allowed at most {MAX_FIT_END_S:g} s (give '
                        f'--window T0:T1 with T1 <= {MAX_FIT_END_S:g})')
    # only the rows up to the window's end are held (the rest is read and checked as it
    # passes): a window of a long flight costs its own memory, not the flight's
    run = read_bag_until(bag, None if window is None else window[1])
    design = bag_params(run)
    if nominal:
        design = design.replace(**nominal)
    design, stale = _calibrated_constants(design, nominal or {})
    period = control_period or run.control_period or 1e-3
    scenario = calibration_scenario(run.provenance)
    own = flight_calibration_of(run, design, model, free, period, alpha)
    d = diagnose(run.signals, design, control_period=period, model=model, faults=faults,
                 window=window, free=free, bootstrap=bootstrap, pairs=pairs,
                 model_form=run.valve_model != model, onset=onset,
                 scenario=OWN if own is not None else scenario, calibration=own,
                 sensor_bias=recorded_sensor_bias(run.provenance))
    if own is None and scenario is None and run.valve_model != model and run.provenance:
        d.warnings.append(
            f'{bag}: no calibration of this flight and design: the packaged one (other '
            'flights, the default design) is applied, and its intervals and verdict floor may '
            f'not hold here; calibrate it (minutes): servovalve-twin calibrate-diagnosis {bag}'
            + (f' --free {",".join(free)}' if free else ''))
    if own is None and run.valve_model != model and alpha != alpha_of(
            calibration_for(model, free)):
        d.warnings.append(
            f'{bag}: no calibration of this flight and design at alpha {alpha:g}: the '
            f'intervals are the packaged calibration\'s, {d.confidence:.0%}; for '
            f'{1 - alpha:.0%} calibrate it: servovalve-twin calibrate-diagnosis {bag} '
            f'--alpha {alpha:g}' + (f' --free {",".join(free)}' if free else ''))
    if stale:
        d.warnings.append(f'{bag}: {stale}')
    if run.provenance and run.provenance.scenario is not None:
        from ..prognostics.calibration import sensor_warnings
        d.warnings.extend(sensor_warnings(run.provenance.scenario_object().sensors, period))
    if not run.provenance:
        assumed = ('the parameters given with --param and the defaults for the rest'
                   if nominal else 'the design parameters (the defaults)')
        d.warnings.append(f'{bag}: the bag has no provenance record of the twin: assumed '
                          f'{assumed} and a {period * 1e3:g} ms control period')
        if not nominal:
            d.verdict = UNEXPLAINED
            d.warnings.append('unexplained: a fault is a departure from the actuator\'s design, '
                              'which a bag without provenance does not state; give it with '
                              '--param NAME=VALUE (and --control-period)')
    return d


def diagnose_fleet_member(job) -> tuple[int, str, Any]:
    """One bag of ``diagnose BAG1 BAG2 ...`` (``job``: its index, path and
    :func:`diagnose_bag`'s options) on a worker: (index, bag, the Diagnosis or the bag's one
    error line) -- one bad bag is that bag's error, not the fleet's."""
    i, bag, options = job
    try:
        return i, bag, diagnose_bag(bag, **options)
    except TwinError as exc:
        return i, bag, ' '.join(str(exc).split())


def recorded_sensor_bias(provenance) -> dict[str, float]:
    """The offsets of the measured signals' sensors a bag's provenance records (its
    scenario's ``sensors:``): the model's runs read with them."""
    from ..physics.signals import MEASURED
    if not provenance or provenance.scenario is None:
        return {}
    sensors = provenance.scenario_object().sensors
    return {name: spec.bias for name, spec in (sensors.specs if sensors else ())
            if name in MEASURED and spec.bias}


def flight_calibration_of(run, design, model: str, free: Sequence[str], period: float,
                          alpha: float = ALPHA):
    """The cached calibration of the flight a bag recorded (its provenance scenario) for this
    design, model and free nuisance (:mod:`..prognostics.flight_calibration`), or None."""
    if not run.provenance or run.provenance.scenario is None:
        return None
    own = cached(flight_key(run.provenance.scenario_object().to_dict(), design, model, free,
                            period, alpha))
    return None if own is None else with_pooled(own, model, free)


def _calibrated_constants(design, given: Mapping[str, Any]):
    """``design`` with XSS and GPQ from HD's calibration of its geometry and supply, unless
    the user gave them; and a line when the bag recorded others (a bag of an older version,
    or of a run given stale constants): the fitted model's gains must be those of the unit's
    design, whatever the twin that recorded it was told."""
    from ..physics.params import hd_constants
    if 'XSS' in given or 'GPQ' in given:
        return design, None
    xss, gpq = hd_constants(design)
    recorded = (design.xss, design.gpq)
    if all(abs(a - b) <= 1e-9 * abs(b) for a, b in zip(recorded, (xss, gpq))):
        return design, None
    return design.replace(XSS=None, GPQ=None), (
        f'the bag records XSS = {recorded[0]:.6g} m, GPQ = {recorded[1]:.6g} Pa*s/m^3, but '
        f'HD\'s calibration of its design gives {xss:.6g}, {gpq:.6g}: the design\'s are used '
        '(give --param XSS=... --param GPQ=... to impose others)')


def plot_diagnosis(d: Diagnosis, path: str | Path) -> None:
    """Recorded signals against the best hypothesis' fit and the healthy model's."""
    t = d.recorded['t']
    runs = {'recorded': d.recorded}
    best = d.best
    if best.fault != HEALTHY:
        sevs = '/'.join(f'{s:.4g}' for s in best.severities)
        runs[f'{best.fault} {sevs} ({d.model})'] = dict(best.fitted, t=t)
    healthy = next(c for c in d.candidates if c.fault == HEALTHY)
    runs[f'healthy ({d.model})'] = dict(healthy.fitted, t=t)
    plot_overlay(runs, path, title=f'diagnosis: {best.fault}', reference='recorded',
                 signals=SIGNALS)


def prognose_bags(bags: Sequence[str | Path], fault: str, threshold: float | None, *,
                  cycles: Sequence[float] | None = None, model: str = 'SQ',
                  window: tuple[float, float] | None = None) -> Prognosis:
    """Diagnose ``fault`` on each flight's bag (in order), trend it, predict the RUL."""
    if cycles is not None and len(cycles) != len(bags):
        raise TwinError(f'--cycles gives {len(cycles)} counts for {len(bags)} bags')
    if len(bags) < MIN_CYCLES:
        raise TwinError(f'a trend needs at least {MIN_CYCLES} flights (bags), got {len(bags)}')
    history = []
    for i, bag in enumerate(bags):
        d = diagnose_bag(bag, model=model, faults=[fault], window=window)
        history.append(flight_entry(d, fault, float(cycles[i]) if cycles is not None
                                    else float(i)))
    return prognose(history, fault, threshold)


def flight_entry(d: Diagnosis, fault: str, cycles: float) -> dict[str, Any]:
    """One flight of a prognosis history from its diagnosis: the fault's severity (the
    verdict's or not) with the model-form correction applied alike to every flight, the
    fit's noise interval around it, and the model-form spread as ``model_sigma``, which is
    common to a unit's flights and so carried by the trend, not averaged away."""
    c = next(c for c in d.candidates if c.fault == fault)
    severity, interval = c.raw or (c.severity, c.interval)
    entry = dict(cycles=cycles, severity=severity, interval=list(interval))
    if d.calibration is not None:
        severity, _, model_sigma = model_form_estimate(d.calibration, fault, severity,
                                                       tuple(interval), d.calibration_scenario)
        half = (interval[1] - interval[0]) / 2
        entry.update(severity=severity, interval=[severity - half, severity + half],
                     model_sigma=model_sigma)
    return entry


def plot_prognosis(p: Prognosis, path: str | Path) -> None:
    """History with intervals, the trend extrapolated, the threshold and the RUL histogram."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    n = np.array([h['cycles'] for h in p.history])
    s = np.array([h['severity'] for h in p.history])
    lo = np.array([h['interval'][0] for h in p.history])
    hi = np.array([h['interval'][1] for h in p.history])
    fig, (ax, ax2) = plt.subplots(2, 1, figsize=(8.0, 6.0))
    ax.errorbar(n, s, yerr=[s - lo, hi - s], fmt='o', color='k', label='diagnosed (95 %)')
    finite = p.draws[np.isfinite(p.draws)]
    end = n[-1] + (np.percentile(finite, 97) if finite.size else n[-1] - n[0]) + 1
    grid = np.linspace(n[0], end, 200)
    ax.plot(grid, p.trend(grid), 'C0', label=f'{p.trend.kind} trend')
    ax.axhline(p.threshold, color='C3', ls='--', label=f'threshold {p.threshold:g}')
    ax.set_xlabel('flight cycles')
    ax.set_ylabel(f'{p.fault} severity')
    ax.legend(fontsize=8)
    ax.grid(True, lw=0.3)
    if finite.size:
        ax2.hist(finite, bins=40, color='C0', alpha=0.7)
    for k, ls in (('p05', ':'), ('median', '-'), ('p95', ':')):
        if np.isfinite(p.rul[k]):
            ax2.axvline(p.rul[k], color='k', ls=ls, label=f'{k} {p.rul[k]:.1f}')
    ax2.set_xlabel('remaining useful life [cycles]')
    ax2.legend(fontsize=8)
    ax2.grid(True, lw=0.3)
    fig.tight_layout()
    with output_path(path) as tmp:              # whole or absent
        fig.savefig(tmp, dpi=90)
    plt.close(fig)


__all__ = ['diagnose_bag', 'prognose_bags', 'flight_entry', 'plot_diagnosis', 'plot_prognosis',
           'parse_window', 'parse_faults']
