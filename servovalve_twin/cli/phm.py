"""The PHM commands: evaluate (your Algorithm on a bag), diagnose, prognose, bit (a designed
built-in test), monitor-thresholds."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Sequence

from ..errors import TwinError
from ..outputs import write_new
from ..physics.faults import FAULTS
from ..prognostics.conformal import ALPHA
from .common import (Command, add_algorithm_options, add_param_options, algorithm_params,
                     miscoverage, nonnegative_float, overrides, positive_float)

#: the fewest block-bootstrap refits whose percentiles make an interval
MIN_BOOTSTRAP = 20


class Evaluate(Command):
    name = 'evaluate'
    help = 'run your Algorithm on a recorded bag, ROS-free (the same outputs as live)'

    def add_arguments(self, p):
        p.add_argument('bag', metavar='BAG', help='bag directory, .mcap or .db3 file')
        add_algorithm_options(p)
        p.add_argument('--json', metavar='FILE', help='outputs, levels and alarm times as JSON')

    def main(self, args):
        from ..apps.evaluate import Evaluation, evaluate_blocks
        # block by block: a bag of any length in the same memory (the JSON's columns wait in
        # temporary files beside it)
        alg, blocks = evaluate_blocks(args.bag, args.algorithm, algorithm_params(args))
        ev = Evaluation(alg, args.bag, args.json)
        try:
            for block in blocks:
                ev.add(block)
            if args.json:
                ev.write_json()
        finally:
            ev.close()
        print(ev.line())
        return 0


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
    from ..prognostics.calibration import from_g
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


class MonitorThresholds(Command):
    name = 'monitor-thresholds'
    help = "the monitor's thresholds for a stated false-alarm rate, from healthy HD units on " \
           'your flights'

    def add_arguments(self, p):
        p.add_argument('--monitor-model', metavar='NAME', help='default SQ')
        p.add_argument('--scenario', action='append', default=[], metavar='NAME|FILE.yaml',
                       help='a flight of the calibration set (repeatable; default the built-in '
                            'set: every built-in scenario, chirps, random steps)')
        p.add_argument('--units', type=int, default=4, help='healthy units per flight (default '
                       '4)')
        p.add_argument('--seed', type=int, default=11,
                       help="seed of the units' nuisance and noise")
        p.add_argument('--far-error', type=float, default=1e-3, metavar='P',
                       help='per-flight false-alarm rate of ERROR (default 1e-3)')
        p.add_argument('--far-warn', type=float, default=1e-2, metavar='P',
                       help='per-flight false-alarm rate of WARN (default 1e-2)')
        p.add_argument('--out', required=True, metavar='FILE.yaml',
                       help='a ROS 2 parameters file for the monitor node (a new file)')
        p.add_argument('--reveal-units', type=int, default=2, metavar='N',
                       help='HD units per catalog fault (at its alarm severity) and flight '
                            'flown to report what the thresholds reveal (default 2; 0: none)')

    def main(self, args):
        import yaml
        from ..physics.valves import get_monitor_model
        from ..prognostics.monitor import DEFAULT_MONITOR_MODEL
        from ..prognostics.thresholds import (MIN_PEAKS, calibrate_thresholds,
                                              healthy_peaks, monitor_cal_flights)
        model = args.monitor_model or DEFAULT_MONITOR_MODEL
        get_monitor_model(model)
        for name, value in (('--units', args.units), ('--far-error', args.far_error),
                            ('--far-warn', args.far_warn)):
            if not (value > 0) or (name != '--units' and not value < 1):
                raise TwinError(f'{name} {value!r}: allowed ' + ('>= 1' if name == '--units'
                                                                  else '(0, 1)'))
        if not args.far_error <= args.far_warn:
            raise TwinError('--far-error must not exceed --far-warn (ERROR is the rarer level)')
        if args.units > MAX_UNITS:
            raise TwinError(f'--units {args.units}: allowed 1 to {MAX_UNITS} per flight')
        if not 0 <= args.reveal_units <= MAX_UNITS:
            raise TwinError(f'--reveal-units {args.reveal_units}: allowed 0 to {MAX_UNITS} '
                            'per fault and flight')
        out = Path(args.out)
        if out.exists() or out.is_symlink():
            raise TwinError(f'--out {args.out!r} exists; monitor-thresholds writes a new file '
                            'only')
        flights = ({Path(s).stem: s for s in args.scenario} if args.scenario
                   else monitor_cal_flights())
        if args.units * len(flights) < MIN_PEAKS:
            raise TwinError(f'--units {args.units} on {len(flights)} flight(s): the thresholds '
                            f'need at least {MIN_PEAKS} healthy units in all')
        peaks = healthy_peaks((model,), flights, args.units, args.seed)[model]
        th = calibrate_thresholds(peaks, rates={'warn': args.far_warn, 'error': args.far_error})
        text = (f'# monitor thresholds for {model}: healthy HD units ({args.units} per flight, '
                f'seed {args.seed}) on {", ".join(flights)};\n# per-flight false-alarm rates '
                f'ERROR {args.far_error:g}, WARN {args.far_warn:g}. Use: ros2 run '
                'servovalve_twin monitor --ros-args --params-file THIS\n'
                + yaml.safe_dump({'monitor': {'ros__parameters': dict(monitor_model=model,
                                                                      **th)}},
                                 sort_keys=False))
        write_new(out, text)
        print(text, end='')
        if args.reveal_units:
            from ..prognostics.monitor import HealthConfig
            from ..prognostics.thresholds import format_revealed, revealed
            print(format_revealed(revealed(model, flights, HealthConfig(**th),
                                           args.reveal_units, args.seed + 1)))
        return 0


#: the most healthy units per flight monitor-thresholds flies (1e7 ran for ever)
MAX_UNITS = 1000


class Bit(Command):
    name = 'bit'
    help = 'design a pre-flight built-in test that reveals every catalog fault at its mild ' \
           'severity'

    def add_arguments(self, p):
        p.add_argument('--out', required=True, metavar='FILE.yaml',
                       help='the scenario (a new file)')
        p.add_argument('--duration', type=float, default=2.0, metavar='S',
                       help='length of the test [s] (default 2)')
        p.add_argument('--max-stroke', type=float, default=0.04, metavar='M',
                       help='largest absolute Com the rig allows [m] (default 0.04)')
        p.add_argument('--max-load', type=float, default=6000.0, metavar='N',
                       help='largest absolute FR the rig applies [N] (default 6000; 0: no load '
                            'rig)')
        p.add_argument('--max-rate', type=float, metavar='M/S',
                       help='largest command rate [m/s] (default: steps)')
        p.add_argument('--seed', type=int, default=0, help='seed of the design search')
        add_param_options(p)
        p.add_argument('--json', metavar='FILE', help='the limits on the paper scenario and on '
                       'the test, as JSON')

    def main(self, args):
        import yaml
        from ..outputs import write_json
        from ..physics.params import DEFAULTS
        from ..prognostics.excitation import (RigLimits, design_bit, detection_limits,
                                              format_limits)
        out = Path(args.out)
        if out.suffix not in ('.yaml', '.yml'):
            raise TwinError(f'--out {args.out!r}: expected a new .yaml file')
        if out.exists() or out.is_symlink():
            raise TwinError(f'--out {args.out!r} exists; bit writes a new file only')
        design = DEFAULTS.replace(**overrides(args))
        rig = RigLimits(stroke=args.max_stroke, load=args.max_load, rate=args.max_rate)
        scn, crit = design_bit(args.duration, rig, design=design, seed=args.seed)
        write_new(out, '# A pre-flight built-in test designed by `servovalve-twin bit` (see '
                  'servovalve_twin.prognostics.excitation):\n# fly it, record it, and '
                  '`servovalve-twin diagnose` the bag.\n'
                  + yaml.safe_dump(scn, sort_keys=False, default_flow_style=None, width=100))
        lims = {'paper': detection_limits('paper', design),
                out.stem: detection_limits(scn, design)}
        if args.json:
            write_json(args.json, dict(criterion=crit, scenario=str(out), limits={
                k: [x.to_json() for x in v] for k, v in lims.items()}))
        print(format_limits(lims))
        met = all(x.detects_mild for x in lims[out.stem])
        print(f'{out}: {scn["duration"]:g} s; design criterion {crit:+.3f} (>= 0: every fault '
              f'detected and told apart at its mild severity, linearised); mild severities '
              f'{"all" if met else "not all"} above the limits on it')
        return 0


class Prognose(Command):
    name = 'prognose'
    help = 'trend a fault over flights (bags) and predict the remaining useful life'

    def add_arguments(self, p):
        p.add_argument('bags', nargs='+', metavar='BAG', help='one bag per flight, in order')
        p.add_argument('--cycles', metavar='N1,N2,...', help="each flight's cycle count "
                       '(default 0, 1, 2, ...)')
        p.add_argument('--threshold', required=True, metavar='FAULT[=S]',
                       help='the fault and the severity at which it must be fixed (default: '
                            "the catalog's alarm severity)")
        p.add_argument('--model', default='SQ', help='the simplified model fitted (default SQ)')
        p.add_argument('--window', metavar='T0:T1', help='fit window of every flight')
        p.add_argument('--json', required=True, metavar='FILE', help='the prognosis as JSON')
        p.add_argument('--plot', metavar='FILE.png', help='history, trend, threshold, RUL')

    def main(self, args):
        from ..outputs import write_json
        from ..apps.diagnose import parse_window, plot_prognosis, prognose_bags
        fault, sep, value = (args.threshold or '').partition('=')
        if not fault:
            raise TwinError('--threshold FAULT=S names the fault to trend (S: the severity to '
                            'fix it at; FAULT alone: the catalog alarm severity)')
        try:
            threshold = float(value) if sep and value else None
        except ValueError:
            raise TwinError(f'--threshold {args.threshold!r}: S must be a number') from None
        cycles = None
        if args.cycles:
            try:
                cycles = [float(c) for c in args.cycles.split(',')]
            except ValueError:
                raise TwinError(f'--cycles {args.cycles!r}: expected N1,N2,... numbers'
                                ) from None
        p = prognose_bags(args.bags, fault, threshold, cycles=cycles, model=args.model,
                          window=parse_window(args.window))
        write_json(args.json, p.to_json())
        if args.plot:
            plot_prognosis(p, args.plot)
        print(f'{fault} over {len(p.history)} flights: {_prognosis_line(p)} -> {args.json}')
        return 0


def _prognosis_line(p) -> str:
    r = p.rul
    if p.status == 'trend':
        return (f'{p.trend.kind} trend; threshold {p.threshold:g} in {r["median"]:.1f} cycles '
                f'(90 %: {r["p05"]:.1f} to {r["p95"]:.1f})')
    if p.status == 'step change':
        return (f'step change at cycle {p.trend.n0:g} to {p.trend.coef[1]:.4g}; '
                + ('past the threshold: RUL 0' if r['median'] == 0 else
                   f'below the threshold {p.threshold:g}, no trend since: no finite RUL'))
    if p.status == 'past threshold':
        return f'past the threshold {p.threshold:g} already: RUL 0'
    if p.status == 'too few flights':
        return 'too few distinct flights for a trend: no RUL'
    return (f'no degradation trend (slope {p.slope_z:.1f} standard errors toward the '
            f'threshold {p.threshold:g}): no finite RUL')
