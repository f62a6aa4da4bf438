"""The command-line front door: ``servovalve-twin <command> ...``.

A thin layer over plain functions: each command parses its options, calls the library and
prints. Exit codes: 0 success; 1 a ``--tolerance`` was exceeded (``compare``); 2 bad input, with
a one-line message on stderr (never a traceback); 130 interrupted.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import sys
from pathlib import Path
from typing import Any, Sequence

from .errors import TwinError


class _Parser(argparse.ArgumentParser):
    """argparse that reports a usage error as one line and exit code 2."""

    def error(self, message: str):  # noqa: D401 -- argparse's hook
        self.exit(2, f'{self.prog}: error: {message}\n')


def _add_param_options(p: argparse.ArgumentParser) -> None:
    p.add_argument('--param', action='append', metavar='NAME=VALUE', default=[],
                   help='override a parameter of config/eha.yaml (repeatable); '
                        '`servovalve-twin params` lists them')


def _add_foxglove_option(p: argparse.ArgumentParser) -> None:
    p.add_argument('--foxglove', type=int, nargs='?', const=8765, default=None, metavar='PORT',
                   help='serve the topics live to the Foxglove app (Foxglove WebSocket on '
                        'ws://127.0.0.1:PORT, default 8765; layout: config/foxglove_layout.json)')


def _add_algorithm_options(p: argparse.ArgumentParser, many: bool) -> None:
    if many:
        p.add_argument('--algorithm', action='append', default=[], metavar='MOD:CLASS',
                       help='host this Algorithm in the lockstep (repeatable); its outputs '
                            'are published and recorded')
    else:
        p.add_argument('--algorithm', required=True, metavar='MOD:CLASS',
                       help='the Algorithm, package.module:ClassName')
    p.add_argument('--algorithm-param', action='append', default=[], metavar='NAME=VALUE',
                   help="set a parameter of the algorithm (repeatable)")


def _add_run_options(p: argparse.ArgumentParser) -> None:
    from .physics.valves import VALVE_MODEL_NAMES
    p.add_argument('--valve-model', required=True, metavar='NAME',
                   help='valve model: ' + ', '.join(VALVE_MODEL_NAMES))
    p.add_argument('--scenario', default='paper', metavar='paper|FILE.yaml',
                   help='built-in scenario name or YAML file (default: paper)')
    _add_param_options(p)


def _positive_float(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f'expected a number, got {text!r}') from None
    if not v > 0 or v != v or v == float('inf'):
        raise argparse.ArgumentTypeError(f'expected a positive finite number, got {text!r}')
    return v


def _float_list(text: str) -> list[float]:
    try:
        vals = [float(v) for v in text.split(',') if v.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f'expected comma-separated numbers, got {text!r}'
                                         ) from None
    if not vals or any(v != v or abs(v) == float('inf') for v in vals):
        raise argparse.ArgumentTypeError(f'expected comma-separated finite numbers, got {text!r}')
    return vals


def _overrides(args: argparse.Namespace) -> dict[str, Any]:
    from .physics.params import parse_assignments
    return parse_assignments(args.param)


# -- commands -------------------------------------------------------------------------------

def cmd_simulate(args: argparse.Namespace) -> int:
    from .runs import simulate, write_table
    result = simulate(args.valve_model, args.scenario, _overrides(args),
                      ecu_period=args.ecu_period)
    write_table(args.out, result.signals)
    info = ', '.join(f'{k}={v}' for k, v in result.info.items() if k != 'wall_s')
    print(f'{result.valve_model} on {result.scenario.name}: {len(result["t"])} rows -> '
          f'{"stdout" if args.out == "-" else args.out} ({result.info["wall_s"] * 1e3:.1f} ms; '
          f'{info})', file=sys.stderr if args.out == '-' else sys.stdout)
    return 0


def cmd_characteristic(args: argparse.Namespace) -> int:
    from .apps.plots import plot_characteristic
    from .physics.characteristic import characteristic
    from .physics.params import make_params
    from .runs import write_csv
    params = make_params(_overrides(args))
    psr = params.PSRN if args.psr is None else args.psr
    qj = args.qj if args.qj is not None else [0.0, 4.0e-5, 8.0e-5, 1.2e-4]
    curves = characteristic(args.valve_model, params, psr, qj, n_points=args.points)
    write_csv(args.out, curves)
    if args.plot:
        plot_characteristic({args.valve_model: curves}, args.plot, psr)
    import numpy as np
    blank = int(np.isnan(curves['p12']).sum())
    print(f'{args.valve_model}: P12(XS) at PSR={psr:g} Pa for QJ={qj} -> {args.out}'
          + (f'; {blank} of {len(curves["p12"])} points have no steady state (nan, left blank '
             'in the plot)' if blank else ''))
    return 0


def cmd_calibrate(args: argparse.Namespace) -> int:
    from .physics.valves.calibration import calibrate
    from .physics.params import make_params
    params = make_params(_overrides(args))
    cal = calibrate(params)
    units = dict(XSS='m', GPN='Pa/m', GQN='m^2/s', GPQ='Pa*s/m^3', k='-')
    for name, value in cal.items():
        print(f'{name:4s} = {value!r:24s} [{units[name]}]')
    print('# config/eha.yaml holds XSS and GPQ; set them with --param XSS=... --param GPQ=...')
    return 0


def cmd_params(args: argparse.Namespace) -> int:
    from .physics.params import param_table
    for row in param_table():
        left = '(' if row['lo_open'] else '['
        derived = ' (derived)' if row['derived'] else ''
        print(f'{row["name"]:12s} {row["default"]!r:>24} {row["unit"]:12s} '
              f'{left}{row["lo"]:g}, {row["hi"]:g}]  {row["doc"]}{derived}')
    return 0


def cmd_faults(args: argparse.Namespace) -> int:
    from .physics.faults import FAULTS
    for f in FAULTS.values():
        print(f'{f.name:24s} {f.param:10s} [{f.lo:g}, {f.hi:g}] {f.unit:18s} alarm at '
              f'{f.demo:g}: {f.meaning}')
    return 0


def cmd_fmu(args: argparse.Namespace) -> int:
    import time
    try:
        import pythonfmu  # noqa: F401
    except ImportError:
        raise TwinError("the fmu command needs pythonfmu: pip install 'servovalve_twin[fmu]'"
                        ) from None
    from .fmu import build_fmu
    t = time.perf_counter()
    out = build_fmu(args.valve_model, args.out, control_period=args.control_period)
    print(f'{out}: FMI 2.0 co-simulation FMU of the EHA with {args.valve_model}, ECU every '
          f'{args.control_period:g} s ({out.stat().st_size / 1e3:.0f} kB, '
          f'{time.perf_counter() - t:.1f} s)')
    return 0


def cmd_report(args: argparse.Namespace) -> int:
    from .apps.report import make_report
    text = make_report(out_dir=Path(args.out_dir), readme=Path(args.readme) if args.readme
                       else None, overrides=_overrides(args))
    print(text)
    return 0


@contextlib.contextmanager
def _discovery_off(enabled: bool = True):
    """A single-process twin needs no DDS discovery; without it no other graph on the same
    ROS_DOMAIN_ID can cross-talk with the lockstep. rcl reads the variable when a context is
    initialised, so it is set for the run only and restored after."""
    key = 'ROS_AUTOMATIC_DISCOVERY_RANGE'
    saved = os.environ.get(key)
    if enabled:
        os.environ[key] = 'OFF'
    try:
        yield
    finally:
        if saved is None:
            os.environ.pop(key, None)
        else:
            os.environ[key] = saved


def cmd_run(args: argparse.Namespace) -> int:
    # a namespaced, following or paced twin is there to share a graph with other processes
    shared = (args.namespace or args.clock == 'follow' or args.followers
              or args.real_time_factor is not None)
    with _discovery_off(not (args.discoverable or shared)):
        return _run(args)


def _run(args: argparse.Namespace) -> int:
    from .config import default_bag_dir, load_scenario
    from .runs import write_table
    from .twin import run_twin
    scenario = load_scenario(args.scenario)
    bag = None if args.no_bag else (args.bag or default_bag_dir(scenario.name, args.valve_model))
    if args.out and args.out != '-' and not Path(args.out).resolve().parent.is_dir():
        raise TwinError(f'--out {args.out}: directory {str(Path(args.out).parent)!r} does not '
                        'exist')
    from .progress import enabled, progress
    bar = progress(total=int(round(scenario.duration * 1000)), desc='run', unit='ms') \
        if enabled() and not args.progress else None
    result = run_twin(args.valve_model, scenario, _overrides(args),
                      on_tick=(lambda k, twin: bar.update(twin.period_ns * 1e-6) if k else None)
                      if bar is not None else None,
                      control_period=args.control_period, bag=bag, overwrite=args.overwrite,
                      keep_values=args.out is not None, clock_period=args.clock_period,
                      monitor=args.monitor,
                      algorithms=[(a, _algorithm_params(args)) for a in args.algorithm]
                      + ([('servovalve_twin.prognostics.estimator:Estimator',
                           {'model': args.estimator,
                            'model_form': args.estimator != args.valve_model})]
                         if args.estimator else []),
                      foxglove=args.foxglove, namespace=args.namespace, clock=args.clock,
                      followers=args.followers,
                      real_time_factor=args.real_time_factor,
                      on_flush=(lambda t: print(f'flushed up to {t:.3f} s', flush=True))
                      if args.progress else None)
    if bar is not None:
        bar.close()
    if args.out:
        write_table(args.out, result.signals)
    sim_s = result.simulated_s
    print(f'{result.valve_model} on {scenario.name}: {sim_s:.3f} s simulated in '
          f'{result.wall_s:.3f} s (real-time factor {sim_s / max(result.wall_s, 1e-9):.1f})'
          + (f'; bag {result.bag}' if result.bag else '') + (f'; CSV {args.out}' if args.out
                                                              else '')
          + ('; INTERRUPTED' if result.interrupted else ''))
    for line in result.verdicts:
        print(line)
    return 130 if result.interrupted else 0


def _algorithm_params(args: argparse.Namespace) -> dict[str, str]:
    """``--algorithm-param NAME=VALUE`` (typed by the algorithm from its defaults)."""
    out = {}
    for item in getattr(args, 'algorithm_param', None) or []:
        name, sep, value = item.partition('=')
        if not sep or not name.strip():
            raise TwinError(f'--algorithm-param expects NAME=VALUE, got {item!r}')
        out[name.strip()] = value.strip()
    return out


def cmd_evaluate(args: argparse.Namespace) -> int:
    from .apps.compare import write_json
    from .apps.evaluate import evaluate, run_to_json
    run = evaluate(args.bag, args.algorithm, _algorithm_params(args))
    payload = run_to_json(run, args.bag)
    if args.json:
        write_json(args.json, payload)
    first = payload['first_error']
    print(f'{run.title} on {args.bag}: {payload["ticks"]} ticks; first WARN '
          f'{payload["first_warn"]} s, first ERROR {first} s'
          + ''.join(f'; peak {k} {max(v):.6g}' for k, v in payload['outputs'].items()))
    return 0


def cmd_diagnose(args: argparse.Namespace) -> int:
    import time
    from .apps.compare import write_json
    from .apps.diagnose import diagnose_bag, parse_faults, parse_window, plot_diagnosis
    free = tuple(n.strip() for n in (args.free or '').split(',') if n.strip())
    if args.limits is not None:
        if args.bag is not None:
            raise TwinError('diagnose takes BAG or --limits SCENARIO, not both')
        return _print_limits(args, free, parse_faults(args.faults))
    if args.bag is None or args.json is None:
        raise TwinError('diagnose needs BAG and --json FILE (or --limits SCENARIO for the '
                        'detection limits of an excitation)')
    if args.bootstrap < 0 or 0 < args.bootstrap < MIN_BOOTSTRAP:
        # the 2.5 and 97.5 % percentiles of fewer refits are a refit or two, not an interval
        # (one refit gave an interval that excluded its own estimate)
        raise TwinError(f'--bootstrap {args.bootstrap}: allowed 0 (the Jacobian interval) or '
                        f'at least {MIN_BOOTSTRAP} refits')
    t = time.perf_counter()
    d = diagnose_bag(args.bag, model=args.model, faults=parse_faults(args.faults),
                     window=parse_window(args.window), free=free, bootstrap=args.bootstrap,
                     pairs=args.pairs, nominal=_overrides(args),
                     control_period=args.control_period, onset=args.onset)
    wall = time.perf_counter() - t
    write_json(args.json, d.to_json())
    for w in d.warnings:
        print(f'servovalve-twin diagnose: warning: {w}', file=sys.stderr)
    if args.plot:
        plot_diagnosis(d, args.plot)
    b = d.best
    conf = f'{d.confidence:.0%}'.replace('%', ' %')
    what = 'healthy' if b.severity is None else ', '.join(
        f'{f}, severity {s:.4g} ({conf} [{i[0]:.4g}, {i[1]:.4g}])'
        for f, s, i in zip(b.faults, b.severities, b.intervals))
    if d.onset and not d.verdict:
        what += (f', from t = {d.onset["t"]:.3f} s ([{d.onset["interval"][0]:.3f}, '
                 f'{d.onset["interval"][1]:.3f}])')
    if d.verdict:
        what = f'{d.verdict} (best candidate: {b.fault})'
    print(f'{args.bag}: {what} -- {len(d.candidates)} hypotheses, {d.evaluations} model runs '
          f'with {d.model} in {wall:.2f} s -> {args.json}')
    for c in d.candidates:
        sev = ' ' + '/'.join(f'{s:.4g}' for s in c.severities) if c.severities else ''
        extra = ''.join(f' {k}x{v:.3f}' for k, v in c.free.items())
        print(f'  {c.fault:24s}{sev:>10s}  score {c.score:10.1f}{extra}')
    return 0


#: the fewest block-bootstrap refits whose percentiles make an interval
MIN_BOOTSTRAP = 20


def _print_limits(args: argparse.Namespace, free: tuple[str, ...],
                  faults: Sequence[str]) -> int:
    """``diagnose --limits SCENARIO``: each fault's detection limit and resolution."""
    from .apps.compare import write_json
    from .config import load_scenario
    from .physics.simulate import effective_params
    from .prognostics.excitation import detection_limits, format_limits
    scn = load_scenario(args.limits)
    design = effective_params(scn, _overrides(args))
    lims = detection_limits(scn, design, model=args.model, free=free, faults=faults,
                            control_period=args.control_period or 1e-3)
    if args.json:
        write_json(args.json, dict(scenario=scn.name, model=args.model, free=list(free),
                                   limits=[x.to_json() for x in lims]))
    print(format_limits({scn.name: lims}))
    return 0


def _write_new(path: Path, text: str) -> None:
    """``text`` into a new file (never an existing one, nor through a symbolic link); on
    any failure the half-written file, ours, is removed."""
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, 'O_NOFOLLOW', 0),
                 0o644)
    try:
        with os.fdopen(fd, 'w', encoding='utf-8') as fh:
            fh.write(text)
    except BaseException:
        path.unlink(missing_ok=True)
        raise


def cmd_bit(args: argparse.Namespace) -> int:
    import yaml
    from .apps.compare import write_json
    from .prognostics.excitation import RigLimits, design_bit, detection_limits, format_limits
    out = Path(args.out)
    if out.suffix not in ('.yaml', '.yml'):
        raise TwinError(f'--out {args.out!r}: expected a new .yaml file')
    if out.exists() or out.is_symlink():
        raise TwinError(f'--out {args.out!r} exists; bit writes a new file only')
    from .physics.params import DEFAULTS
    design = DEFAULTS.replace(**_overrides(args))
    rig = RigLimits(stroke=args.max_stroke, load=args.max_load, rate=args.max_rate)
    scn, crit = design_bit(args.duration, rig, design=design, seed=args.seed)
    _write_new(out, '# A pre-flight built-in test designed by `servovalve-twin bit` (see '
               'servovalve_twin.prognostics.excitation):\n# fly it, record it, and '
               '`servovalve-twin diagnose` the bag.\n'
               + yaml.safe_dump(scn, sort_keys=False, default_flow_style=None, width=100))
    lims = {'paper': detection_limits('paper', design),
            out.stem: detection_limits(scn, design)}
    if args.json:
        write_json(args.json, dict(criterion=crit, scenario=str(out),
                                   limits={k: [x.to_json() for x in v] for k, v in lims.items()}))
    print(format_limits(lims))
    met = all(x.detects_mild for x in lims[out.stem])
    print(f'{out}: {scn["duration"]:g} s; design criterion {crit:+.3f} (>= 0: every fault '
          f'detected and told apart at its mild severity, linearised); mild severities '
          f'{"all" if met else "not all"} above the limits on it')
    return 0


def cmd_monitor_thresholds(args: argparse.Namespace) -> int:
    import yaml
    from .prognostics.monitor import (DEFAULT_MONITOR_MODEL, calibrate_thresholds,
                                      healthy_peaks, monitor_cal_flights)
    from .physics.valves import get_monitor_model
    model = args.monitor_model or DEFAULT_MONITOR_MODEL
    get_monitor_model(model)
    for name, value in (('--units', args.units), ('--far-error', args.far_error),
                        ('--far-warn', args.far_warn)):
        if not (value > 0) or (name != '--units' and not value < 1):
            raise TwinError(f'{name} {value!r}: allowed ' + ('>= 1' if name == '--units'
                                                              else '(0, 1)'))
    if not args.far_error <= args.far_warn:
        raise TwinError('--far-error must not exceed --far-warn (ERROR is the rarer level)')
    out = Path(args.out)
    if out.exists() or out.is_symlink():
        raise TwinError(f'--out {args.out!r} exists; monitor-thresholds writes a new file only')
    flights = ({Path(s).stem: s for s in args.scenario} if args.scenario
               else monitor_cal_flights())
    peaks = healthy_peaks((model,), flights, args.units, args.seed)[model]
    th = calibrate_thresholds(peaks, rates={'warn': args.far_warn, 'error': args.far_error})
    text = (f'# monitor thresholds for {model}: healthy HD units ({args.units} per flight, seed '
            f'{args.seed}) on {", ".join(flights)};\n# per-flight false-alarm rates ERROR '
            f'{args.far_error:g}, WARN {args.far_warn:g}. Use: ros2 run servovalve_twin monitor '
            '--ros-args --params-file THIS\n'
            + yaml.safe_dump({'monitor': {'ros__parameters': dict(monitor_model=model, **th)}},
                             sort_keys=False))
    _write_new(out, text)
    print(text, end='')
    return 0


def cmd_prognose(args: argparse.Namespace) -> int:
    from .apps.compare import write_json
    from .apps.diagnose import parse_window, plot_prognosis, prognose_bags
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
            raise TwinError(f'--cycles {args.cycles!r}: expected N1,N2,... numbers') from None
    p = prognose_bags(args.bags, fault, threshold, cycles=cycles, model=args.model,
                      window=parse_window(args.window))
    write_json(args.json, p.to_json())
    if args.plot:
        plot_prognosis(p, args.plot)
    r = p.rul
    if p.status == 'trend':
        what = (f'{p.trend.kind} trend; threshold {p.threshold:g} in {r["median"]:.1f} cycles '
                f'(90 %: {r["p05"]:.1f} to {r["p95"]:.1f})')
    elif p.status == 'step change':
        what = (f'step change at cycle {p.trend.n0:g} to {p.trend.coef[1]:.4g}; '
                + ('past the threshold: RUL 0' if r['median'] == 0 else
                   f'below the threshold {p.threshold:g}, no trend since: no finite RUL'))
    elif p.status == 'past threshold':
        what = f'past the threshold {p.threshold:g} already: RUL 0'
    else:
        what = (f'no degradation trend (slope {p.slope_z:.1f} standard errors toward the '
                f'threshold {p.threshold:g}): no finite RUL')
    print(f'{fault} over {len(p.history)} flights: {what} -> {args.json}')
    return 0


def _parse_tolerances(items: list[str]) -> dict[str, float]:
    from .apps.compare import COMPARED
    out = {}
    for item in items:
        name, sep, value = item.partition('=')
        name = name.strip().lower()
        if name == 'current':
            name = 'cor'
        if not sep or name not in COMPARED:
            raise TwinError(f'--tolerance expects SIGNAL=MAX with SIGNAL one of '
                            f'{sorted(COMPARED)}, got {item!r}')
        try:
            out[name] = float(value)
        except ValueError:
            raise TwinError(f'--tolerance {item!r}: {value!r} is not a number') from None
    return out


def cmd_compare(args: argparse.Namespace) -> int:
    from .apps.compare import (check_same_inputs, error_metrics, exceeded, format_table,
                               load_run, provenance_differences, write_json)
    from .apps.plots import plot_overlay
    tolerances = _parse_tolerances(args.tolerance)
    ref, windows = load_run(args.ref)
    run, _ = load_run(args.run)
    for line in provenance_differences(args.ref, args.run):
        print(f'servovalve-twin compare: warning: {line}', file=sys.stderr)
    check_same_inputs(ref, run)
    metrics = error_metrics(ref, run, windows)
    print(f'{args.run} against {args.ref} (errors run - ref, RMS / max):')
    print(format_table(metrics))
    if args.json:
        write_json(args.json, dict(ref=str(args.ref), run=str(args.run), windows=windows,
                                   metrics=metrics, tolerances=tolerances))
    if args.plot:
        named = {k: v for k, v in windows.items() if not k.startswith('phase')}
        plot_overlay({Path(args.ref).stem: ref, Path(args.run).stem: run}, args.plot,
                     reference=Path(args.ref).stem, title=f'{Path(args.run).stem} against '
                     f'{Path(args.ref).stem}', windows=named, inputs=True)
    bad = exceeded(metrics, tolerances)
    for line in bad:
        print(f'tolerance exceeded: {line}')
    return 1 if bad else 0


def cmd_replay(args: argparse.Namespace) -> int:
    from .apps.replay import replay
    from .apps.compare import format_table
    with _discovery_off():
        _, result, metrics = replay(args.bag, valve_model=args.valve_model, out=args.out,
                                    overrides=_overrides(args), overwrite=args.overwrite)
    print(f'replayed {args.bag} with {result.valve_model} into {result.bag}; new run against '
          'the bag:')
    print(format_table(metrics))
    return 130 if result.interrupted else 0


def cmd_play(args: argparse.Namespace) -> int:
    import signal
    import rclpy
    from rclpy.context import Context
    from rclpy.signals import SignalHandlerOptions
    from .nodes.player import PlayOptions, play
    opts = PlayOptions(rate=args.rate, clock=args.clock, topics=tuple(args.topics),
                       exclude_topics=tuple(args.exclude_topics), loop=args.loop,
                       delay=args.delay, start_offset=args.start_offset,
                       playback_duration=args.playback_duration,
                       start_paused=args.start_paused, remap=tuple(args.remap))
    opts.check()
    stop = []
    old = {sig: signal.signal(sig, lambda *_: stop.append(True))
           for sig in (signal.SIGINT, signal.SIGTERM)}
    context = Context()
    rclpy.init(context=context, signal_handler_options=SignalHandlerOptions.NO)
    try:
        result = play(args.bag, opts, context=context, stop=lambda: bool(stop),
                      foxglove=args.foxglove)
    finally:
        rclpy.try_shutdown(context=context)
        for sig, handler in old.items():
            signal.signal(sig, handler)
    state = 'stopped' if stop else 'done'
    print(f'play: {state}: {result["published"]} messages in {result["wall_s"]:.2f} s '
          f'(bag {result["bag_duration_s"]:.3f} s at rate {args.rate:g})')
    return 0


def cmd_reindex(args: argparse.Namespace) -> int:
    from .bag.reindex import reindex
    meta = reindex(args.bag)
    print(f'{args.bag}: rebuilt, {meta["message_count"]} messages over '
          f'{meta["duration"]["nanoseconds"] * 1e-9:.3f} s in '
          f'{len(meta["topics_with_message_count"])} topics')
    for rep in meta['report']['files']:
        for d in rep['damaged']:
            print(f'{args.bag}: {rep["file"]}: skipped {d["bytes"]} bytes from byte {d["at"]} '
                  f'({d["reason"]})', file=sys.stderr)
        if rep['dropped_messages']:
            print(f'{args.bag}: {rep["file"]}: dropped {rep["dropped_messages"]} messages of '
                  'channels it does not describe', file=sys.stderr)
        if rep.get('original_kept_as'):
            print(f'{args.bag}: {rep["file"]}: the damaged original is kept as '
                  f'{rep["original_kept_as"]}', file=sys.stderr)
    return 0


def _parse_faults(items: list[str]) -> tuple[dict[str, list[float]], dict[str, tuple]]:
    grid: dict[str, list[float]] = {}
    ranges: dict[str, tuple[float, float]] = {}
    for item in items:
        name, sep, spec = item.partition(':')
        try:
            if not sep:
                raise ValueError
            if '~' in spec:
                lo, hi = (float(v) for v in spec.split('~'))
                if not lo < hi:
                    raise TwinError(f'--fault {item}: the range LO~HI needs LO < HI')
                ranges[name] = (lo, hi)
            else:
                grid[name] = [float(v) for v in spec.split(',') if v.strip()]
        except ValueError:
            raise TwinError(f'--fault expects NAME:S1,S2,... (grid) or NAME:LO~HI (with '
                            f'--draws), got {item!r}') from None
    return grid, ranges


def _parse_vary(items: list[str]) -> dict[str, float]:
    out = {}
    for item in items:
        name, sep, value = item.partition('=')
        try:
            if not sep:
                raise ValueError
            out[name] = float(value)
            if not 0.0 <= out[name] < 1.0:
                raise ValueError
        except ValueError:
            raise TwinError(f'--vary expects PARAM=SPREAD with 0 <= SPREAD < 1, got {item!r}'
                            ) from None
    return out


def cmd_sweep(args: argparse.Namespace) -> int:
    import time
    from .prognostics.sweep import iter_results, make_cases, write_dataset
    grid, ranges = _parse_faults(args.fault)
    if ranges and not args.draws:
        raise TwinError('a fault range NAME:LO~HI needs --draws N')
    for opt in ('draws', 'nominal'):
        if getattr(args, opt) < 0:
            raise TwinError(f'--{opt} must be >= 0, got {getattr(args, opt)}')
    if args.repeats < 1:
        raise TwinError(f'--repeats must be >= 1, got {args.repeats}')
    if args.workers is not None and args.workers < 1:
        raise TwinError(f'--workers must be >= 1, got {args.workers}')
    from .prognostics.monitor import DEFAULT_MONITOR_MODEL
    cases = make_cases(plant_model=args.plant_model,
                       monitor_model=args.monitor_model or DEFAULT_MONITOR_MODEL,
                       scenario=args.scenario, faults=grid, ranges=ranges, draws=args.draws,
                       nominal_runs=args.nominal, repeats=args.repeats,
                       vary=_parse_vary(args.vary), onset=args.onset, seed=args.seed,
                       base=_overrides(args), algorithm=args.algorithm,
                       algorithm_params=_algorithm_params(args))
    t0 = time.perf_counter()
    # streamed: each run's row (and traces) goes to the dataset as it arrives
    summary = write_dataset(Path(args.out), iter_results(
        cases, workers=args.workers, scheduler=args.scheduler, traces=args.traces))
    wall = time.perf_counter() - t0
    files = 'dataset.csv, dataset.parquet, ' + ('traces.npz, ' if args.traces else '')
    print(f'{len(cases)} runs in {wall:.1f} s ({len(cases) / wall:.1f} runs/s) -> {args.out}/'
          f'{{{files}summary.json, signature.png}}')
    print(f'false alarms on nominal runs: {summary["false_alarms"]}/{summary["nominal_runs"]}')
    for fault, rows in summary['faults'].items():
        for r in rows:
            delay = f'{r["mean_delay"] * 1e3:.0f} ms' if r['mean_delay'] is not None else '-'
            print(f'{fault:24s} severity {r["severity"]:<10g} detected {r["detection_rate"]:.0%}'
                  f' of {r["runs"]}, mean delay {delay}')
    return 0


# -- parser ---------------------------------------------------------------------------------

def build_parser() -> argparse.ArgumentParser:
    from . import __version__
    parser = _Parser(prog='servovalve-twin', description=__doc__.splitlines()[0])
    parser.add_argument('--version', action='version', version=f'servovalve-twin {__version__}')
    sub = parser.add_subparsers(dest='command', required=True, parser_class=_Parser)
    add_parser = sub.add_parser

    def described(name, **kw):              # every subcommand's --help opens with its purpose
        kw.setdefault('description', kw.get('help'))
        return add_parser(name, **kw)
    sub.add_parser = described

    p = sub.add_parser('simulate', help='ROS-free run of a scenario to CSV')
    _add_run_options(p)
    p.add_argument('--ecu-period', type=_positive_float, metavar='S',
                   help='sample the ECU with this period (a multiple of DT); default continuous')
    p.add_argument('--out', required=True, metavar='FILE.csv',
                   help="the 1 ms rows t,com,fr,psr,cor,xs,xj,dxj,p12,qj (HD adds p1,p2), SI; "
                        "CSV, or Parquet for a .parquet name; '-' writes CSV to standard "
                        'output')
    p.set_defaults(func=cmd_simulate)

    p = sub.add_parser('characteristic', help="the paper's Fig. 3: P12 against XS per QJ")
    p.add_argument('--valve-model', required=True, metavar='NAME',
                   help='a registered valve model (servovalve-twin --help lists them)')
    p.add_argument('--psr', type=_positive_float, metavar='PA', help='default PSRN')
    p.add_argument('--qj', type=_float_list, metavar='Q1,Q2,...',
                   help='working flows [m^3/s] (default 0,4e-5,8e-5,1.2e-4)')
    p.add_argument('--points', type=int, default=401, help='XS samples over [-XSM, XSM]')
    _add_param_options(p)
    p.add_argument('--out', required=True, metavar='FILE.csv', help='columns xs,qj,p12 (HD: p1,p2)')
    p.add_argument('--plot', metavar='FILE.png', help='also draw the curves (paper Fig. 3)')
    p.set_defaults(func=cmd_characteristic)

    p = sub.add_parser('calibrate', help='XSS, GPN, GQN, GPQ, k of the simplified models from HD')
    _add_param_options(p)
    p.set_defaults(func=cmd_calibrate)

    p = sub.add_parser('params', help='list every parameter with default, unit and bounds')
    p.set_defaults(func=cmd_params)

    p = sub.add_parser('report', help='every model against HD on the paper scenario: table '
                                      'and figures (optionally into a results page)')
    p.add_argument('--out-dir', default='docs/figures', metavar='DIR',
                   help='where the figures go (default docs/figures)')
    p.add_argument('--readme', metavar='PAGE.md',
                   help='replace the results section (between <!-- results:begin --> and '
                        '<!-- results:end -->) of this page, e.g. doc/results/against-hd.md')
    _add_param_options(p)
    p.set_defaults(func=cmd_report)

    p = sub.add_parser('run', help='the ROS 2 twin (four nodes, one executor, simulated time) '
                                   'on a scenario, recorded as a bag')
    _add_run_options(p)
    p.add_argument('--control-period', type=_positive_float, default=1e-3, metavar='S',
                   help='lockstep period (default 0.001; must divide 1 ms)')
    p.add_argument('--clock-period', type=_positive_float, default=1e-2, metavar='S',
                   help='/clock publication period in simulated time (default 0.01)')
    p.add_argument('--real-time-factor', type=_positive_float, metavar='X',
                   help='pace simulated time to X simulated seconds per wall second (1: real '
                        'time), so that ordinary use_sim_time nodes beside the twin keep up; '
                        'default: as fast as possible')
    p.add_argument('--namespace', metavar='NS',
                   help="the actuator's namespace: its nodes and topics under /NS (/NS/xj), "
                        'so that several actuators share one graph; /clock stays global')
    p.add_argument('--clock', choices=('own', 'follow'), default='own',
                   help="own: publish /clock (the graph's one clock owner, default); follow: "
                        "run each tick once another owner's /clock reaches it")
    p.add_argument('--followers', type=int, default=0, metavar='N',
                   help='the clock owner starts once N twins following its /clock (other '
                        'namespaces) are on the graph (default 0: at once)')
    p.add_argument('--bag', metavar='DIR', help='bag directory (default bags/<scenario>_<model>)')
    p.add_argument('--no-bag', action='store_true', help='do not record')
    p.add_argument('--overwrite', action='store_true', help='replace an existing bag')
    p.add_argument('--out', metavar='FILE.csv', help="the CSV of simulate, from the run's "
                                                    'own messages')
    p.add_argument('--monitor', metavar='MODEL',
                   help='run the monitor node beside the plant with this simplified model')
    p.add_argument('--estimator', metavar='MODEL',
                   help='run the estimator node: diagnosis with this simplified model over '
                        'the last 0.5 s, every 0.25 s (estimator/<fault>_severity, diagnostics)')
    p.add_argument('--progress', action='store_true',
                   help="print 'flushed up to T s' each time the bag is flushed (50 ms)")
    _add_algorithm_options(p, many=True)
    p.add_argument('--discoverable', action='store_true',
                   help='keep DDS discovery on (to watch the topics from other processes); by '
                        'default the run is confined to its process, unless --namespace, '
                        '--clock follow or --real-time-factor is given')
    _add_foxglove_option(p)
    p.set_defaults(func=cmd_run)

    p = sub.add_parser('compare', help='errors of a run against a reference (bags or CSVs)')
    p.add_argument('ref', metavar='REF', help='the reference: a bag, a simulate CSV, or @paper_HD')
    p.add_argument('run', metavar='RUN', help='the run compared with it (bag or CSV)')
    p.add_argument('--plot', metavar='FILE.png', help='overlay of both runs (paper Figs. 19-23)')
    p.add_argument('--json', metavar='FILE', help='the metrics as JSON')
    p.add_argument('--tolerance', action='append', default=[], metavar='SIGNAL=MAX',
                   help='exit 1 when the whole-run max error of SIGNAL (xj, dxj, p12, xs, cor; '
                        'SI units) exceeds MAX (repeatable)')
    p.set_defaults(func=cmd_compare)

    p = sub.add_parser('replay', help="drive the ECU and plant with a bag's inputs, record, "
                                      'compare with the bag')
    p.add_argument('bag', metavar='BAG', help='the recorded bag (or @paper_HD)')
    p.add_argument('--valve-model', metavar='NAME', help="default: the bag's")
    p.add_argument('--out', metavar='DIR',
                   help='new bag (default bags/<BAG>_replay_<model>_<UTC time>)')
    p.add_argument('--overwrite', action='store_true',
                   help="replace the bag in an existing --out directory (only the bag's files)")
    _add_param_options(p)
    p.set_defaults(func=cmd_replay)

    p = sub.add_parser('sweep', help='fault sweeps (grid or Monte-Carlo) with a monitor model: '
                                     'a labelled dataset for prognostics')
    p.add_argument('--plant-model', default='HD', metavar='NAME',
                   help='the valve model of the simulated actuators (default HD)')
    p.add_argument('--monitor-model', metavar='NAME',
                   help='the simplified model of the monitor (default SQ, whose calibrated '
                        'thresholds still see the catalog faults; C2 misses most)')
    p.add_argument('--algorithm', metavar='MOD:CLASS',
                   help='score your Algorithm (its ERROR health = detection) instead of the '
                        'monitor')
    p.add_argument('--algorithm-param', action='append', default=[], metavar='NAME=VALUE',
                   help='set a parameter of the algorithm (repeatable)')
    p.add_argument('--scenario', default='paper', metavar='paper|FILE.yaml',
                   help='the scenario every run flies (default paper)')
    p.add_argument('--fault', action='append', default=[], metavar='NAME:S1,S2|NAME:LO~HI',
                   help='fault and severities (repeatable); `servovalve-twin faults` lists them')
    p.add_argument('--draws', type=int, default=0, help='Monte-Carlo runs per fault range')
    p.add_argument('--repeats', type=int, default=1, help='runs per grid severity')
    p.add_argument('--nominal', type=int, default=5, help='fault-free runs (default 5)')
    p.add_argument('--vary', action='append', default=[], metavar='PARAM=SPREAD',
                   help='draw PARAM uniformly within +-SPREAD (relative) in every run')
    p.add_argument('--onset', type=float, default=0.1, help='fault onset [s] (default 0.1)')
    p.add_argument('--seed', type=int, default=0, help='random seed of the draws (default 0)')
    p.add_argument('--workers', type=int, help='local processes (default: one per core)')
    p.add_argument('--scheduler', metavar='ADDRESS', help='run on this Dask scheduler')
    _add_param_options(p)
    p.add_argument('--traces', action='store_true',
                   help='also write every run\'s residuals, indicators and level per 1 ms '
                        '(traces.npz, ~90 kB per run)')
    p.add_argument('--out', required=True, metavar='DIR',
                   help='dataset.csv and .parquet, summary.json, signature.png (and '
                        'traces.npz with --traces)')
    p.set_defaults(func=cmd_sweep)

    p = sub.add_parser('play', help='put a rosbag2 bag (MCAP or sqlite3, any version) back on '
                                    'the ROS graph, like ros2 bag play')
    p.add_argument('bag', metavar='BAG', help='bag directory, .mcap or .db3 file')
    p.add_argument('-r', '--rate', type=_positive_float, default=1.0, metavar='FACTOR',
                   help='playback rate (wall pacing; default 1.0)')
    p.add_argument('--clock', type=_positive_float, nargs='?', const=40.0, default=0.0,
                   metavar='HZ', help='publish /clock from the bag time (default 40 Hz when '
                   'given); the bag\'s own /clock is then not republished')
    p.add_argument('--topics', nargs='+', default=[], metavar='T', help='play only these')
    p.add_argument('--exclude-topics', nargs='+', default=[], metavar='T',
                   help='do not play these')
    p.add_argument('-l', '--loop', action='store_true', help='play again from the start')
    p.add_argument('-d', '--delay', type=float, default=0.0, metavar='S',
                   help='wall time to wait before playing')
    p.add_argument('--start-offset', type=float, default=0.0, metavar='S',
                   help='start this far into the bag')
    p.add_argument('--playback-duration', type=float, default=0.0, metavar='S',
                   help='play only this much bag time (default: to the end)')
    p.add_argument('-p', '--start-paused', action='store_true',
                   help='start paused (resume with the ~/resume service)')
    p.add_argument('--remap', nargs='+', default=[], metavar='FROM:=TO',
                   help='publish topic FROM as TO')
    _add_foxglove_option(p)
    p.set_defaults(func=cmd_play)

    p = sub.add_parser('evaluate', help='run your Algorithm on a recorded bag, ROS-free (the '
                                        'same outputs as live)')
    p.add_argument('bag', metavar='BAG', help='bag directory, .mcap or .db3 file')
    _add_algorithm_options(p, many=False)
    p.add_argument('--json', metavar='FILE', help='outputs, levels and alarm times as JSON')
    p.set_defaults(func=cmd_evaluate)

    p = sub.add_parser('diagnose', help='which catalog fault, how severe: a simplified model '
                                        'fitted to a recorded bag')
    p.add_argument('bag', metavar='BAG', nargs='?',
                   help='bag directory, .mcap or .db3 file')
    p.add_argument('--model', default='SQ', metavar='SQ|C2|...',
                   help='the simplified model fitted (default SQ)')
    p.add_argument('--limits', metavar='SCENARIO',
                   help="instead of a bag: each fault's detection limit and severity "
                        'resolution on this excitation (a built-in name or a YAML file)')
    p.add_argument('--faults', metavar='NAMES|all', help='comma-separated hypotheses (default '
                   'all the catalog faults a simplified model can see)')
    p.add_argument('--window', metavar='T0:T1', help='fit the rows in [T0, T1] s (default the '
                   'whole bag)')
    p.add_argument('--free', metavar='M,CJ,...', help='nuisance parameters estimated '
                   'alongside (factors on the recorded values, in [0.5, 2])')
    p.add_argument('--bootstrap', type=int, default=0, metavar='N',
                   help='the interval from N >= 20 block-bootstrap refits (default 0: the '
                        'Jacobian)')
    p.add_argument('--pairs', action='store_true',
                   help="also every two faults at once (named 'a+b'; severity and interval "
                        'then list one entry per fault)')
    p.add_argument('--onset', action='store_true',
                   help='also fit when the fault began (a change point over the window; '
                        'about 5 x the cost)')
    _add_param_options(p)
    p.add_argument('--control-period', type=_positive_float, metavar='S',
                   help="the ECU's period of the run (default: the bag's, else 1 ms)")
    p.add_argument('--json', metavar='FILE', help='the diagnosis as JSON (needed with BAG)')
    p.add_argument('--plot', metavar='FILE.png', help='recorded against fitted signals')
    p.set_defaults(func=cmd_diagnose)

    p = sub.add_parser('monitor-thresholds', help="the monitor's thresholds for a stated "
                       'false-alarm rate, from healthy HD units on your flights')
    p.add_argument('--monitor-model', metavar='NAME', help='default SQ')
    p.add_argument('--scenario', action='append', default=[], metavar='NAME|FILE.yaml',
                   help='a flight of the calibration set (repeatable; default the built-in '
                        'set: every built-in scenario, chirps, random steps)')
    p.add_argument('--units', type=int, default=4, help='healthy units per flight (default 4)')
    p.add_argument('--seed', type=int, default=11, help="seed of the units' nuisance and noise")
    p.add_argument('--far-error', type=float, default=1e-3, metavar='P',
                   help='per-flight false-alarm rate of ERROR (default 1e-3)')
    p.add_argument('--far-warn', type=float, default=1e-2, metavar='P',
                   help='per-flight false-alarm rate of WARN (default 1e-2)')
    p.add_argument('--out', required=True, metavar='FILE.yaml',
                   help='a ROS 2 parameters file for the monitor node (a new file)')
    p.set_defaults(func=cmd_monitor_thresholds)

    p = sub.add_parser('bit', help='design a pre-flight built-in test that reveals every '
                                   'catalog fault at its mild severity')
    p.add_argument('--out', required=True, metavar='FILE.yaml', help='the scenario (a new file)')
    p.add_argument('--duration', type=float, default=2.0, metavar='S',
                   help='length of the test [s] (default 2)')
    p.add_argument('--max-stroke', type=float, default=0.04, metavar='M',
                   help='largest absolute Com the rig allows [m] (default 0.04)')
    p.add_argument('--max-load', type=float, default=6000.0, metavar='N',
                   help='largest absolute FR the rig applies [N] (default 6000; 0: no load rig)')
    p.add_argument('--max-rate', type=float, metavar='M/S',
                   help='largest command rate [m/s] (default: steps)')
    p.add_argument('--seed', type=int, default=0, help='seed of the design search')
    _add_param_options(p)
    p.add_argument('--json', metavar='FILE', help='the limits on the paper scenario and on '
                   'the test, as JSON')
    p.set_defaults(func=cmd_bit)

    p = sub.add_parser('prognose', help='trend a fault over flights (bags) and predict the '
                                        'remaining useful life')
    p.add_argument('bags', nargs='+', metavar='BAG', help='one bag per flight, in order')
    p.add_argument('--cycles', metavar='N1,N2,...', help="each flight's cycle count (default "
                   '0, 1, 2, ...)')
    p.add_argument('--threshold', required=True, metavar='FAULT[=S]',
                   help='the fault and the severity at which it must be fixed (default: the '
                        "catalog's alarm severity)")
    p.add_argument('--model', default='SQ', help='the simplified model fitted (default SQ)')
    p.add_argument('--window', metavar='T0:T1', help='fit window of every flight')
    p.add_argument('--json', required=True, metavar='FILE', help='the prognosis as JSON')
    p.add_argument('--plot', metavar='FILE.png', help='history, trend, threshold, RUL')
    p.set_defaults(func=cmd_prognose)

    p = sub.add_parser('fmu', help='an FMI 2.0 co-simulation FMU of the actuator (pythonfmu)')
    p.add_argument('--valve-model', required=True, metavar='NAME',
                   help='the valve model inside (a name of the registry: C2, SQ, HD, ...)')
    p.add_argument('--control-period', type=float, default=1e-3, metavar='S',
                   help='the ECU sampling period [s], a multiple of DT (default 0.001); a '
                        'communication step must be a whole number of them')
    p.add_argument('out', metavar='OUT.fmu', help='the FMU file to write (a new one)')
    p.set_defaults(func=cmd_fmu)

    p = sub.add_parser('faults', help='list the injectable faults')
    p.set_defaults(func=cmd_faults)

    p = sub.add_parser('reindex', help='rebuild a bag (and metadata.yaml) cut short by a kill')
    p.add_argument('bag', metavar='BAG', help='the bag directory or its .mcap file')
    p.set_defaults(func=cmd_reindex)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        from .config import resolve_bag
        for attr in ('bag', 'ref', 'run'):        # @paper_HD: a packaged reference bag
            value = getattr(args, attr, None)
            if isinstance(value, str) and value.startswith('@'):
                setattr(args, attr, str(resolve_bag(value)))
        return int(args.func(args) or 0)
    except TwinError as exc:
        text = ' '.join(str(exc).split())            # one line, whatever the message holds
        if len(text) > 600:
            text = text[:600] + ' ...'
        print(f'servovalve-twin {args.command}: error: {text}', file=sys.stderr)
        return 2
    except BrokenPipeError:
        # the reader went away (`... --out - | head`): quiet, as command-line tools are
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        return 0
    except OSError as exc:
        what = f'{exc.strerror}: {exc.filename}' if exc.strerror and exc.filename else exc
        print(f'servovalve-twin {args.command}: error: {what}', file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f'servovalve-twin {args.command}: interrupted', file=sys.stderr)
        return 130


if __name__ == '__main__':
    sys.exit(main())
