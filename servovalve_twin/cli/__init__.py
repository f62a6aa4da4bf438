"""The command-line front door: ``servovalve-twin <command> ...``.

A thin layer over plain functions: each command (a :class:`~.common.Command` in a module of
this package, its options beside its body) parses its options, calls the library and prints.
Exit codes: 0 success; 1 a ``--tolerance`` was exceeded (``compare``); 2 bad input, with a
one-line message on stderr (never a traceback); 130 interrupted.
"""

from __future__ import annotations

import argparse
import os
import sys
from typing import Sequence

from ..errors import TwinError, one_line
from . import bags, diagnosis, phm, physics, ros, sweep
from .common import Command, Parser

#: every command, in the order of ``--help``: a new command is a class and one line here
COMMANDS: list[Command] = [
    physics.Simulate(), physics.Characteristic(), physics.Calibrate(), physics.Params(),
    physics.Report(), ros.Run(), bags.Compare(), ros.Replay(), sweep.Sweep(), ros.Play(),
    phm.Evaluate(), diagnosis.Diagnose(), diagnosis.CalibrateDiagnosis(), phm.MonitorThresholds(),
    phm.Bit(), phm.Prognose(),
    physics.Fmu(), physics.Faults(), bags.Reindex(),
]


#: one example per command, shown at the end of its ``--help`` (a test parses each)
EXAMPLES = {
    'simulate': 'servovalve-twin simulate --valve-model SQ --scenario paper --out run.csv',
    'characteristic': 'servovalve-twin characteristic --valve-model HD --qj 0,1e-4 '
                      '--out ch.csv --plot ch.png',
    'calibrate': 'servovalve-twin calibrate --param c=1e-5',
    'params': 'servovalve-twin params',
    'report': 'servovalve-twin report --out-dir out/report',
    'run': 'servovalve-twin run --valve-model HD --scenario paper --bag bags/hd '
           '--monitor SQ',
    'compare': 'servovalve-twin compare @paper_HD run.csv --plot cmp.png',
    'replay': 'servovalve-twin replay @paper_HD --valve-model SQ --out bags/sq_replay',
    'sweep': 'servovalve-twin sweep --fault leakage_growth:1~20 --draws 40 --nominal 10 '
             '--out sweeps/leak',
    'play': 'servovalve-twin play @paper_HD --rate 4 --wait-for-subscribers 1',
    'evaluate': 'servovalve-twin evaluate @paper_HD --algorithm '
                'servovalve_twin.prognostics.monitor:MonitorAlgorithm --json e.json',
    'diagnose': 'servovalve-twin diagnose bags/hd --free M,CJ --json d.json',
    'calibrate-diagnosis': 'servovalve-twin calibrate-diagnosis bags/hd --free M,CJ',
    'monitor-thresholds': 'servovalve-twin monitor-thresholds --scenario paper --units 8 '
                          '--out thresholds.yaml',
    'bit': 'servovalve-twin bit --out bit.yaml',
    'prognose': 'servovalve-twin prognose bags/f1 bags/f2 bags/f3 --cycles 0,50,100 '
                '--threshold leakage_growth --json p.json',
    'fmu': 'servovalve-twin fmu --valve-model SQ eha.fmu',
    'faults': 'servovalve-twin faults',
    'reindex': 'servovalve-twin reindex bags/killed_run',
}


def build_parser() -> argparse.ArgumentParser:
    from .. import __version__
    parser = Parser(prog='servovalve-twin', description=__doc__.splitlines()[0])
    parser.add_argument('--version', action='version', version=f'servovalve-twin {__version__}')
    sub = parser.add_subparsers(dest='command', required=True, parser_class=Parser)
    for command in COMMANDS:              # every --help opens with the command's purpose
        p = sub.add_parser(command.name, help=command.help, description=command.help,
                           epilog=f'example: {EXAMPLES[command.name]}')
        command.add_arguments(p)
        p.set_defaults(func=command.main)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        from ..config import resolve_bag
        for attr in ('bag', 'ref', 'run', 'bags'):   # @paper_HD: a packaged reference bag
            value = getattr(args, attr, None)
            if isinstance(value, str) and value.startswith('@'):
                setattr(args, attr, str(resolve_bag(value)))
            elif isinstance(value, list):
                setattr(args, attr, [str(resolve_bag(v)) if v.startswith('@') else v
                                     for v in value])
        code = int(args.func(args) or 0)
        for bag in _unverified():
            # (6 of 148 runs on damaged sqlite3 bags gave other numbers with rc 0)
            print(f'servovalve-twin {args.command}: note: {bag} is a sqlite3 bag, which keeps '
                  'no checksums: what was read from it cannot be verified', file=sys.stderr)
        return code
    except TwinError as exc:
        print(f'servovalve-twin {args.command}: error: {one_line(exc)}', file=sys.stderr)
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
    finally:
        _unverified()


def _unverified() -> list[str]:
    """The sqlite3 bags this command read (:data:`..bag.anybag.UNVERIFIED`), forgotten once
    taken (``main`` may run again in the same process)."""
    anybag = sys.modules.get(f'{__package__.rsplit(".", 1)[0]}.bag.anybag')
    if anybag is None:
        return []
    out = list(anybag.UNVERIFIED)
    anybag.UNVERIFIED.clear()
    return out


__all__ = ['COMMANDS', 'EXAMPLES', 'Command', 'build_parser', 'main']
