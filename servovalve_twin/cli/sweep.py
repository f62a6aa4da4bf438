"""``servovalve-twin sweep``: fault sweeps with a monitor (or your Algorithm), a labelled
dataset for prognostics."""

from __future__ import annotations

import sys
from pathlib import Path

from ..errors import TwinError
from .common import Command, add_param_options, algorithm_params, overrides


class Sweep(Command):
    name = 'sweep'
    help = 'fault sweeps (grid or Monte-Carlo) with a monitor model: a labelled dataset for ' \
           'prognostics'

    def add_arguments(self, p):
        p.add_argument('--plant-model', default='HD', metavar='NAME',
                       help='the valve model of the simulated actuators (default HD)')
        p.add_argument('--monitor-model', metavar='NAME',
                       help='the simplified model of the monitor (default SQ, whose calibrated '
                            'thresholds still see the catalog faults; C2 misses most)')
        p.add_argument('--algorithm', metavar='MOD:CLASS',
                       help='score your Algorithm (its ERROR health = detection) instead of '
                            'the monitor')
        p.add_argument('--algorithm-param', action='append', default=[], metavar='NAME=VALUE',
                       help='set a parameter of the algorithm (repeatable)')
        p.add_argument('--scenario', default='paper', metavar='paper|FILE.yaml',
                       help='the scenario every run flies (default paper)')
        p.add_argument('--fault', action='append', default=[],
                       metavar='NAME:S1,S2|NAME:LO~HI',
                       help='fault and severities (repeatable); `servovalve-twin faults` lists '
                            'them')
        p.add_argument('--draws', type=int, default=0, help='Monte-Carlo runs per fault range')
        p.add_argument('--repeats', type=int, default=1, help='runs per grid severity')
        p.add_argument('--nominal', type=int, default=5, help='fault-free runs (default 5)')
        p.add_argument('--vary', action='append', default=[], metavar='PARAM=SPREAD',
                       help='draw PARAM uniformly within +-SPREAD (relative) in every run')
        p.add_argument('--onset', type=float, default=0.1, help='fault onset [s] (default 0.1)')
        p.add_argument('--seed', type=int, default=0,
                       help='random seed of the draws (default 0)')
        p.add_argument('--workers', type=int, help='local processes (default: one per core)')
        p.add_argument('--scheduler', metavar='ADDRESS', help='run on this Dask scheduler')
        add_param_options(p)
        p.add_argument('--traces', action='store_true',
                       help="also write every run's residuals, indicators and level per 1 ms "
                            '(traces.npz, ~90 kB per run)')
        p.add_argument('--out', required=True, metavar='DIR',
                       help='dataset.csv and .parquet, summary.json, signature.png (and '
                            'traces.npz with --traces)')

    def main(self, args):
        import time
        from ..prognostics.monitor import DEFAULT_MONITOR_MODEL
        from ..prognostics.dataset import SweepStopped, write_dataset
        from ..prognostics.parallel import restore_signals, stop_on_signals
        from ..prognostics.sweep import iter_results, make_cases, parse_fault_specs, parse_vary
        grid, ranges = parse_fault_specs(args.fault)
        if ranges and not args.draws:
            raise TwinError('a fault range NAME:LO~HI needs --draws N')
        for opt in ('draws', 'nominal'):
            if getattr(args, opt) < 0:
                raise TwinError(f'--{opt} must be >= 0, got {getattr(args, opt)}')
        if args.repeats < 1:
            raise TwinError(f'--repeats must be >= 1, got {args.repeats}')
        if args.workers is not None and args.workers < 1:
            raise TwinError(f'--workers must be >= 1, got {args.workers}')
        if not 0 <= args.seed < 2 ** 63:
            raise TwinError(f'--seed must be an integer in [0, 2**63 - 1], got {args.seed}')
        if args.scheduler:
            from ..prognostics.parallel import check_scheduler
            check_scheduler(args.scheduler)
        cases = make_cases(plant_model=args.plant_model,
                           monitor_model=args.monitor_model or DEFAULT_MONITOR_MODEL,
                           scenario=args.scenario, faults=grid, ranges=ranges,
                           draws=args.draws, nominal_runs=args.nominal, repeats=args.repeats,
                           vary=parse_vary(args.vary), onset=args.onset, seed=args.seed,
                           base=overrides(args), algorithm=args.algorithm,
                           algorithm_params=algorithm_params(args))
        t0 = time.perf_counter()
        # streamed: each run's row (and traces) goes to the dataset as it arrives; SIGTERM
        # and SIGHUP stop it as Ctrl-C does
        old = stop_on_signals()
        try:
            summary = write_dataset(Path(args.out), iter_results(
                cases, workers=args.workers, scheduler=args.scheduler, traces=args.traces),
                total=len(cases))
        except SweepStopped as exc:
            print(f'servovalve-twin sweep: {exc}', file=sys.stderr)
            return exc.code
        finally:
            restore_signals(old)
        wall = time.perf_counter() - t0
        files = 'dataset.csv, dataset.parquet, ' + ('traces.npz, ' if args.traces else '')
        print(f'{len(cases)} runs in {wall:.1f} s ({len(cases) / wall:.1f} runs/s) -> '
              f'{args.out}/{{{files}summary.json, signature.png}}')
        print(f'false alarms on nominal runs: {summary["false_alarms"]}/'
              f'{summary["nominal_runs"]}')
        for fault, rows in summary['faults'].items():
            for r in rows:
                delay = f'{r["mean_delay"] * 1e3:.0f} ms' if r['mean_delay'] is not None else '-'
                print(f'{fault:24s} severity {r["severity"]:<10g} detected '
                      f'{r["detection_rate"]:.0%} of {r["runs"]}, mean delay {delay}')
        return 0
