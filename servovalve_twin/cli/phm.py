"""The PHM commands beside diagnosis (:mod:`.diagnosis`): evaluate (your Algorithm on a bag),
prognose, bit (a designed built-in test), monitor-thresholds."""

from __future__ import annotations

from pathlib import Path

from ..errors import TwinError
from ..outputs import write_new
from .common import (Command, add_algorithm_options, add_param_options, algorithm_params,
                     overrides)


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
