"""Commands on recorded runs: compare, reindex."""

from __future__ import annotations

import sys
from pathlib import Path

from .common import Command


class Compare(Command):
    name = 'compare'
    help = 'errors of a run against a reference (bags or CSVs)'

    def add_arguments(self, p):
        p.add_argument('ref', metavar='REF',
                       help='the reference: a bag, a simulate CSV, or @paper_HD')
        p.add_argument('run', metavar='RUN', help='the run compared with it (bag or CSV)')
        p.add_argument('--plot', metavar='FILE.png',
                       help='overlay of both runs (paper Figs. 19-23)')
        p.add_argument('--json', metavar='FILE', help='the metrics as JSON')
        p.add_argument('--tolerance', action='append', default=[], metavar='SIGNAL=MAX',
                       help='exit 1 when the whole-run max error of SIGNAL (xj, dxj, p12, xs, '
                            'cor; SI units) exceeds MAX, or the run covers less than the '
                            'reference (repeatable)')

    def main(self, args):
        from ..apps.compare import (PlotRows, compare_bags, coverage, coverage_warning,
                                    exceeded, format_table, parse_tolerances,
                                    provenance_differences)
        from ..apps.windows import run_span_ms, run_windows
        from ..apps.plots import plot_overlay
        from ..outputs import write_json
        tolerances = parse_tolerances(args.tolerance)
        # block by block, in memory that does not grow with the bags (a table is held whole);
        # a plot keeps at most PLOT_ROWS rows a run
        windows = run_windows(args.ref)
        for line in provenance_differences(args.ref, args.run):
            print(f'servovalve-twin compare: warning: {line}', file=sys.stderr)
        span_ms = run_span_ms(args.ref)
        rows = PlotRows(span_ms) if args.plot else None
        metrics = compare_bags(args.ref, args.run, windows, plot=rows)
        cov = coverage(metrics, span_ms)
        short = coverage_warning(cov)
        if short:
            print(f'servovalve-twin compare: warning: {short}', file=sys.stderr)
        print(f'{args.run} against {args.ref} (errors run - ref, RMS / max):')
        print(format_table(metrics))
        if args.json:
            write_json(args.json, dict(ref=str(args.ref), run=str(args.run), windows=windows,
                                       metrics=metrics, tolerances=tolerances, coverage=cov))
        if args.plot:
            named = {k: v for k, v in windows.items() if not k.startswith('phase')}
            ref, run = rows.runs()
            a, b = Path(args.ref).stem, Path(args.run).stem
            if a == b:                   # one name for both: the run's line had no label
                a, b = f'{a} (reference)', f'{b} (run)'
            plot_overlay({a: ref, b: run}, args.plot, reference=a, title=f'{b} against {a}',
                         windows=named, inputs=True)
        bad = exceeded(metrics, tolerances)
        if tolerances and short:
            bad.append(short)            # a tolerance holds over the reference, not a part
        for line in bad:
            print(f'tolerance exceeded: {line}')
        return 1 if bad else 0


class Reindex(Command):
    name = 'reindex'
    help = 'rebuild a bag (and metadata.yaml) cut short by a kill'

    def add_arguments(self, p):
        p.add_argument('bag', metavar='BAG', help='the bag directory or its .mcap file')

    def main(self, args):
        from ..bag.reindex import reindex
        meta = reindex(args.bag)
        print(f'{args.bag}: rebuilt, {meta["message_count"]} messages over '
              f'{meta["duration"]["nanoseconds"] * 1e-9:.3f} s in '
              f'{len(meta["topics_with_message_count"])} topics')
        for rep in meta['report']['files']:
            for d in rep['damaged']:
                print(f'{args.bag}: {rep["file"]}: skipped {d["bytes"]} bytes from byte '
                      f'{d["at"]} ({d["reason"]})', file=sys.stderr)
            if rep['dropped_messages']:
                print(f'{args.bag}: {rep["file"]}: dropped {rep["dropped_messages"]} messages '
                      'of channels it does not describe', file=sys.stderr)
            if rep.get('indexed_missing'):
                print(f'{args.bag}: {rep["file"]}: its own index counts {rep["indexed"]} '
                      f'messages; {rep["indexed_missing"]} of them were not found (lost in '
                      'the damage)', file=sys.stderr)
            if rep.get('original_kept_as'):
                print(f'{args.bag}: {rep["file"]}: the damaged original is kept as '
                      f'{rep["original_kept_as"]}', file=sys.stderr)
        return 0
