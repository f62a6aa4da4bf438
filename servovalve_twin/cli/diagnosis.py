"""The diagnosis commands: ``diagnose`` (which fault, how severe, from a bag or a fleet of
them) and ``calibrate-diagnosis`` (its conformal calibration on the flight and design at
hand)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Sequence

from ..errors import TwinError
from ..physics.faults import FAULTS
from ..prognostics.conformal import ALPHA
from .common import (Command, add_param_options, miscoverage, nonnegative_float, overrides,
                     positive_float)

#: the fewest block-bootstrap refits whose percentiles make an interval
MIN_BOOTSTRAP = 20


class Diagnose(Command):
    name = 'diagnose'
    help = 'which catalog fault, how severe: a simplified model fitted to a recorded bag'

    def add_arguments(self, p):
        p.add_argument('bags', metavar='BAG', nargs='*',
                       help='bag directory, .mcap or .db3 file; several: a fleet, diagnosed '
                            'in parallel, one JSON each in the --json directory')
        p.add_argument('--model', default='SQ', metavar='SQ|C2|...',
                       help='the simplified model fitted (default SQ)')
        p.add_argument('--workers', type=int, default=None, metavar='N',
                       help='with several bags: processes (default one per core)')
        p.add_argument('--scheduler', metavar='tcp://HOST:PORT',
                       help='with several bags: diagnose them on this Dask cluster')
        p.add_argument('--limits', metavar='SCENARIO',
                       help="instead of a bag: each fault's detection limit and severity "
                            'resolution on this excitation (a built-in name or a YAML file)')
        p.add_argument('--onset-at', type=nonnegative_float, metavar='T',
                       help='with --limits: the limits of faults that begin at T s of the '
                            'flight (default 0: present from the start)')
        p.add_argument('--faults', metavar='NAMES|all', help='comma-separated hypotheses '
                       '(default all the catalog faults a simplified model can see)')
        p.add_argument('--window', metavar='T0:T1', help='fit the rows in [T0, T1] s (default '
                       'the whole bag); T1 at most 120 s: the model runs from t = 0')
        p.add_argument('--free', metavar='M,CJ,...', help='nuisance estimated alongside: '
                       'parameters (factors on the recorded values, in [0.5, 2]) and sensor '
                       'offsets dxj_bias, p12_bias (SI; JSON: nuisance, with intervals)')
        p.add_argument('--bootstrap', type=int, default=0, metavar='N',
                       help='the interval from N >= 20 block-bootstrap refits (default 0: the '
                            'Jacobian)')
        p.add_argument('--pairs', action='store_true',
                       help="also every two faults at once (named 'a+b'; severity and interval "
                            'then list one entry per fault)')
        p.add_argument('--onset', action='store_true',
                       help='also fit when the fault began (a change point over the window; '
                            'about 5 x the cost)')
        p.add_argument('--alpha', type=miscoverage, default=ALPHA, metavar='A',
                       help='the intervals\' miscoverage: the flight\'s own calibration at A '
                            '(calibrate-diagnosis --alpha A) is used (default 0.1: 90 %%)')
        add_param_options(p)
        p.add_argument('--control-period', type=positive_float, metavar='S',
                       help="the ECU's period of the run (default: the bag's, else 1 ms)")
        p.add_argument('--json', metavar='FILE|DIR', help='the diagnosis as JSON (needed with '
                       'BAG); with several bags a new directory: one JSON per bag and '
                       'summary.json')
        p.add_argument('--plot', metavar='FILE.png', help='recorded against fitted signals')

    def main(self, args):
        import time
        from ..outputs import write_json
        from ..apps.diagnose import diagnose_bag, parse_faults, parse_window, plot_diagnosis
        free = tuple(n.strip() for n in (args.free or '').split(',') if n.strip())
        if args.limits is not None:
            if args.bags:
                raise TwinError('diagnose takes BAG or --limits SCENARIO, not both')
            from ..prognostics.excitation import LIMITS_FREE
            return _print_limits(args, LIMITS_FREE if args.free is None else free,
                                 parse_faults(args.faults))
        if args.onset_at is not None:
            raise TwinError('--onset-at goes with --limits SCENARIO (a fit finds the onset '
                            'with --onset)')
        if not args.bags or args.json is None:
            raise TwinError('diagnose needs BAG and --json FILE (or --limits SCENARIO for the '
                            'detection limits of an excitation)')
        if args.bootstrap < 0 or 0 < args.bootstrap < MIN_BOOTSTRAP:
            # the 2.5 and 97.5 % percentiles of fewer refits are a refit or two, not an
            # interval (one refit gave an interval that excluded its own estimate)
            raise TwinError(f'--bootstrap {args.bootstrap}: allowed 0 (the Jacobian interval) '
                            f'or at least {MIN_BOOTSTRAP} refits')
        options = dict(model=args.model, faults=parse_faults(args.faults),
                       window=parse_window(args.window), free=free, bootstrap=args.bootstrap,
                       pairs=args.pairs, nominal=overrides(args),
                       control_period=args.control_period, onset=args.onset, alpha=args.alpha)
        if len(args.bags) > 1 or args.workers is not None or args.scheduler:
            return _diagnose_fleet(args, options)
        args.bag = args.bags[0]
        t = time.perf_counter()
        d = diagnose_bag(args.bag, **options)
        wall = time.perf_counter() - t
        write_json(args.json, d.to_json())
        for w in d.warnings:
            print(f'servovalve-twin diagnose: warning: {w}', file=sys.stderr)
        if args.plot:
            plot_diagnosis(d, args.plot)
        print(f'{args.bag}: {_verdict_line(d)} -- {len(d.candidates)} hypotheses, '
              f'{d.evaluations} model runs with {d.model} in {wall:.2f} s -> {args.json}')
        print('  candidates, best score (information criterion: lower is better) first; the '
              'verdict is the best unless it is a fault below the floor:')
        for c in d.candidates:
            sev = ' ' + ' / '.join(FAULTS[f].show(s) for f, s in zip(c.faults, c.severities)
                                   ) if c.severities else ''
            extra = ''.join(f' {k}={v:.3g}' if k.endswith('_bias') else f' {k}x{v:.3f}'
                            for k, v in c.free.items())
            print(f'  {c.fault:24s}{sev:>18s}  score {c.score:10.1f}{extra}')
        return 0


def _diagnose_fleet(args, options) -> int:
    """``diagnose BAG1 BAG2 ... --json DIR``: each bag on a local process or a Dask worker,
    its JSON and its line as it finishes; ``summary.json`` at the end (of what finished, on
    Ctrl-C too)."""
    from ..outputs import write_json
    from ..apps.diagnose import diagnose_fleet_member
    from ..prognostics.parallel import (check_scheduler, interrupt_code, map_unordered,
                                        restore_signals, stop_on_signals)
    if args.plot:
        raise TwinError('--plot goes with one bag')
    if args.workers is not None and args.workers < 1:
        raise TwinError(f'--workers must be >= 1, got {args.workers}')
    if args.scheduler:
        check_scheduler(args.scheduler)
    out = Path(args.json)
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise TwinError(f'--json {out}: with several bags a new or empty directory (one JSON '
                        'per bag and summary.json; nothing is overwritten)')
    out.mkdir(parents=True, exist_ok=True)
    jobs = [(i, bag, options) for i, bag in enumerate(args.bags)]
    rows = []
    old = stop_on_signals()
    code = 0
    try:
        for i, bag, d in map_unordered(diagnose_fleet_member, jobs, workers=args.workers,
                                       scheduler=args.scheduler):
            if isinstance(d, str):              # the bag's one error line
                print(f'{bag}: error: {d}', file=sys.stderr)
                rows.append(dict(index=i, bag=bag, error=d))
                code = 2
                continue
            name = f'{i:03d}_{Path(bag).name or "bag"}.json'
            j = d.to_json()
            write_json(out / name, j)
            print(f'{bag}: {_verdict_line(d)} -> {out / name}')
            rows.append(dict(index=i, bag=bag, json=name, fault=j['fault'],
                             severity=j['severity'],
                             interval=j['interval'], confidence=j['confidence'],
                             warnings=len(j['warnings'])))
    except KeyboardInterrupt as exc:
        code = interrupt_code(exc)
        print(f'servovalve-twin diagnose: interrupted after {len(rows)} of {len(jobs)} bags; '
              f'{out} holds theirs', file=sys.stderr)
    finally:
        restore_signals(old)
        rows.sort(key=lambda r: r['index'])
        write_json(out / 'summary.json', dict(bags=len(jobs), diagnosed=rows))
    print(f'{sum("error" not in r for r in rows)} of {len(jobs)} bags diagnosed -> '
          f'{out / "summary.json"}')
    return code


#: a fit worse than this share of the calibration's right fits is called poor on the line
POOR_FIT_P = 0.05


def _verdict_line(d) -> str:
    """The diagnosis in words: the verdict, or each fault's severity and interval (and the
    onset when fitted), the hypotheses that fit as well, and a poor fit said as such."""
    what = _answer(d)
    if d.rivals:
        what += f'; also consistent with {", ".join(d.rivals)}'
    if not d.verdict and d.p_value is not None and d.p_value < POOR_FIT_P:
        what += (f'; poor fit: RMS {d.fit_rms:.3g} of the residual scales, worse than '
                 f'{1 - d.p_value:.1%} of right fits in the calibration')
    return what


def _answer(d) -> str:
    b = d.best
    if d.verdict:
        return f'{d.verdict} (best candidate: {b.fault})'
    conf = f'{d.confidence:.0%}'.replace('%', ' %')
    what = 'healthy' if b.severity is None else ', '.join(
        f'{f}, severity {FAULTS[f].show(s)} ({conf} [{FAULTS[f].show(i[0], False)}, '
        f'{FAULTS[f].show(i[1], False)}])' for f, s, i in zip(b.faults, b.severities,
                                                               b.intervals))
    if d.onset:
        lo, hi = d.onset['interval']
        oc = f'{d.onset.get("confidence", 0.95):.0%}'.replace('%', ' %')
        what += (f', from t = {d.onset["t"]:.3f} s ({oc} [{lo:.3f}, {hi:.3f}])'
                 if d.onset.get('identifiable', True) else
                 f', begun between {lo:.3f} and {hi:.3f} s (the run cannot tell when)')
    return what


def _print_limits(args: argparse.Namespace, free: tuple[str, ...],
                  faults: Sequence[str]) -> int:
    """``diagnose --limits SCENARIO``: each fault's detection limit and resolution."""
    from ..outputs import write_json
    from ..config import load_scenario
    from ..physics.simulate import effective_params
    from ..prognostics.excitation import detection_limits, format_limits
    scn = load_scenario(args.limits)
    design = effective_params(scn, overrides(args))
    onset = args.onset_at or 0.0
    lims = detection_limits(scn, design, model=args.model, free=free, faults=faults,
                            control_period=args.control_period or 1e-3, onset=onset)
    if args.json:
        write_json(args.json, dict(scenario=scn.name, model=args.model, free=list(free),
                                   onset=onset, limits=[x.to_json() for x in lims]))
    print(format_limits({scn.name + (f' (faults from {onset:g} s)' if onset else ''): lims},
                        free))
    return 0


class CalibrateDiagnosis(Command):
    name = 'calibrate-diagnosis'
    help = ('calibrate diagnose on a flight and design of your own: fly seeded HD units on it, '
            'diagnose them, fit the intervals and the verdict floor (cached; diagnose uses it)')

    def add_arguments(self, p):
        p.add_argument('flight', metavar='SCENARIO|BAG',
                       help='a built-in scenario, a scenario YAML file, or a bag whose flight '
                            '(and design) its provenance records')
        p.add_argument('--model', default='SQ', metavar='SQ|C2|...',
                       help='the simplified model diagnose fits (default SQ)')
        p.add_argument('--free', metavar='M,CJ,...', help='the nuisance diagnose will free '
                       '(as you will give it to diagnose)')
        p.add_argument('--units', type=int, default=None, metavar='N',
                       help='HD units per fault and level (default 3; twice as many healthy '
                            'per level)')
        p.add_argument('--seed', type=int, default=0, help="the units' seed (default 0)")
        p.add_argument('--alpha', type=miscoverage, default=ALPHA, metavar='A',
                       help='the intervals\' miscoverage (default 0.1: 90 %% intervals); '
                            'diagnose --alpha A uses this calibration')
        p.add_argument('--workers', type=int, default=None, metavar='N',
                       help='processes (default: one per core)')
        p.add_argument('--scheduler', metavar='tcp://HOST:PORT',
                       help='run the units on this Dask cluster instead of local processes')
        p.add_argument('--control-period', type=positive_float, metavar='S',
                       help="the ECU's period (default: the bag's, else 1 ms)")
        add_param_options(p)

    def main(self, args):
        from ..prognostics.flight_calibration import DEFAULT_UNITS, calibrate_flight, jobs
        from ..prognostics.diagnosis import DIAGNOSABLE
        scenario, design, period = _flight_and_design(args)
        free = tuple(n.strip() for n in (args.free or '').split(',') if n.strip())
        units = DEFAULT_UNITS if args.units is None else args.units
        if args.workers is not None and args.workers < 1:
            raise TwinError(f'--workers must be >= 1, got {args.workers}')
        if not 0 <= args.seed < 2 ** 63:
            raise TwinError(f'--seed must be an integer in [0, 2**63 - 1], got {args.seed}')
        from ..prognostics.parallel import (check_scheduler, interrupt_code, restore_signals,
                                            stop_on_signals)
        if args.scheduler:
            check_scheduler(args.scheduler)
        n = len(jobs(DIAGNOSABLE, max(units, 1), args.seed))
        print(f'calibrating diagnose on {args.flight}: {n} HD units (model {args.model}, '
              f'free {",".join(free) or "none"}); a rerun resumes', file=sys.stderr)
        old = stop_on_signals()
        try:
            cal, path = calibrate_flight(scenario, design, model=args.model, free=free,
                                         control_period=period, units=units, seed=args.seed,
                                         workers=args.workers, alpha=args.alpha,
                                         scheduler=args.scheduler)
        except KeyboardInterrupt as exc:
            print('servovalve-twin calibrate-diagnosis: interrupted; the finished units are '
                  'kept: run the same command again to resume', file=sys.stderr)
            return interrupt_code(exc)
        finally:
            restore_signals(old)
        print(_calibration_summary(cal))
        print(f'-> {path}')
        return 0


def _flight_and_design(args):
    """(scenario dict, design, control period) of ``args.flight`` and ``--param``."""
    from ..config import load_scenario
    from ..physics.simulate import effective_params
    flight = Path(args.flight)
    if flight.is_dir() or flight.suffix in ('.mcap', '.db3'):
        from ..apps.replay import bag_params
        from ..bag.anybag import open_any_bag
        bag = open_any_bag(flight)
        prov = bag.provenance
        if not prov or prov.scenario is None:
            raise TwinError(f'{args.flight}: the bag records no flight (no provenance): give '
                            'the scenario it flew instead')
        design = bag_params(bag)
        if args.param:
            design = design.replace(**overrides(args))
        return (prov.scenario_object().to_dict(), design,
                args.control_period or prov.control_period or 1e-3)
    scn = load_scenario(args.flight)
    return scn.to_dict(), effective_params(scn, overrides(args)), args.control_period or 1e-3


def _calibration_summary(cal) -> str:
    """Per fault: the verdict floor and the detection limit (as severities) and the
    model-form spread and bias."""
    from ..physics.faults import FAULTS
    from ..prognostics.calibration_set import from_g
    lines = [f'{"fault":24s} {"verdict floor":>14s} {"revealed from":>14s} {"spread (g)":>11s} '
             f'{"bias (g)":>9s}  named units']
    for f, floor in cal['healthy_floor'].items():
        c = cal['faults'].get(f)
        spec = FAULTS[f]
        unit = spec.unit.split()[0]
        sev = from_g(f, floor if spec.demo >= spec.healthy else -floor)
        limit = cal.get('revealed_from', {}).get(f)
        lines.append(f'{f:24s} {sev:>9.4g} {unit:>4s} '
                     + (f'{limit:>9.4g} {unit:>4s} ' if limit is not None else
                        f'{"not revealed":>14s} ')
                     + (f'{c["sigma"]:>11.3g} {c["bias"]:>9.3g}  {c["units"]}' if c else
                        f'{"-":>11s} {"-":>9s}  too few named'))
    lines.append(f'(verdict floor {cal["verdict_fraction"]:.3f} of the way to each alarm value, '
                 f'from {cal["healthy_units"]} healthy units: a healthy unit of this flight is '
                 f'named a fault with probability at most 1/{cal["healthy_units"] + 1}; '
                 'revealed from: the lowest level from which every calibration unit of the '
                 'fault was named; "not revealed": fly the built-in test, '
                 'servovalve-twin bit --out bit.yaml)')
    return '\n'.join(lines)
