"""The command-line front door: ``servovalve-twin <command> ...``.

A thin layer over plain functions: each command parses its options, calls the library and
prints. Exit codes: 0 success; 1 a ``--tolerance`` was exceeded (``compare``); 2 bad input, with
a one-line message on stderr (never a traceback); 130 interrupted.
"""

from __future__ import annotations

import argparse
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


def _add_run_options(p: argparse.ArgumentParser) -> None:
    p.add_argument('--valve-model', required=True, metavar='NAME',
                   help='valve model: linear, saturated, saturated_downstream, linear_leakage, '
                        'A, B, C1, C2, C3, C4, HD')
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
    from .physics.simulate import simulate
    result = simulate(args.valve_model, args.scenario, _overrides(args),
                      ecu_period=args.ecu_period)
    result.to_csv(args.out)
    info = ', '.join(f'{k}={v}' for k, v in result.info.items() if k != 'wall_s')
    print(f'{result.valve_model} on {result.scenario.name}: {len(result["t"])} rows -> '
          f'{args.out} ({result.info["wall_s"] * 1e3:.1f} ms of physics; {info})')
    return 0


def cmd_characteristic(args: argparse.Namespace) -> int:
    from .physics.characteristic import characteristic, plot_characteristic
    from .physics.params import make_params
    from .physics.simulate import write_csv
    params = make_params(_overrides(args))
    psr = params.PSRN if args.psr is None else args.psr
    qj = args.qj if args.qj is not None else [0.0, 4.0e-5, 8.0e-5, 1.2e-4]
    curves = characteristic(args.valve_model, params, psr, qj, n_points=args.points)
    write_csv(args.out, curves)
    if args.plot:
        plot_characteristic({args.valve_model: curves}, args.plot, psr)
    print(f'{args.valve_model}: P12(XS) at PSR={psr:g} Pa for QJ={qj} -> {args.out}')
    return 0


def cmd_calibrate(args: argparse.Namespace) -> int:
    from .physics.hd import calibrate
    from .physics.params import make_params
    params = make_params(_overrides(args))
    cal = calibrate(params)
    units = dict(XSS='m', GPN='Pa/m', GQN='m^2/s', GPQ='Pa*s/m^3', k='-')
    for name, value in cal.items():
        print(f'{name:4s} = {value!r:24s} [{units[name]}]')
    print(f'# config/eha.yaml holds XSS and GPQ; set them with --param XSS=... --param GPQ=...')
    return 0


def cmd_params(args: argparse.Namespace) -> int:
    from .physics.params import param_table
    for row in param_table():
        left = '(' if row['lo_open'] else '['
        derived = ' (derived)' if row['derived'] else ''
        print(f'{row["name"]:12s} {row["default"]!r:>24} {row["unit"]:12s} '
              f'{left}{row["lo"]:g}, {row["hi"]:g}]  {row["doc"]}{derived}')
    return 0


def cmd_report(args: argparse.Namespace) -> int:
    from .report import make_report
    text = make_report(out_dir=Path(args.out_dir), readme=Path(args.readme) if args.readme
                       else None, overrides=_overrides(args))
    print(text)
    return 0


# -- parser ---------------------------------------------------------------------------------

def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog='servovalve-twin', description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest='command', required=True, parser_class=_Parser)

    p = sub.add_parser('simulate', help='ROS-free run of a scenario to CSV')
    _add_run_options(p)
    p.add_argument('--ecu-period', type=_positive_float, metavar='S',
                   help='sample the ECU with this period (a multiple of DT); default continuous')
    p.add_argument('--out', required=True, metavar='FILE.csv')
    p.set_defaults(func=cmd_simulate)

    p = sub.add_parser('characteristic', help="the paper's Fig. 3: P12 against XS per QJ")
    p.add_argument('--valve-model', required=True, metavar='NAME')
    p.add_argument('--psr', type=_positive_float, metavar='PA', help='default PSRN')
    p.add_argument('--qj', type=_float_list, metavar='Q1,Q2,...',
                   help='working flows [m^3/s] (default 0,4e-5,8e-5,1.2e-4)')
    p.add_argument('--points', type=int, default=401, help='XS samples over [-XSM, XSM]')
    _add_param_options(p)
    p.add_argument('--out', required=True, metavar='FILE.csv')
    p.add_argument('--plot', metavar='FILE.png')
    p.set_defaults(func=cmd_characteristic)

    p = sub.add_parser('calibrate', help='XSS, GPN, GQN, GPQ, k of the simplified models from HD')
    _add_param_options(p)
    p.set_defaults(func=cmd_calibrate)

    p = sub.add_parser('params', help='list every parameter with default, unit and bounds')
    p.set_defaults(func=cmd_params)

    p = sub.add_parser('report', help='every model against HD on the paper scenario: table '
                                      'and figures (optionally into the README)')
    p.add_argument('--out-dir', default='docs/figures', metavar='DIR')
    p.add_argument('--readme', metavar='README.md',
                   help='replace the results section of this README')
    _add_param_options(p)
    p.set_defaults(func=cmd_report)

    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except TwinError as exc:
        print(f'servovalve-twin {args.command}: error: {exc}', file=sys.stderr)
        return 2
    except OSError as exc:
        print(f'servovalve-twin {args.command}: error: {exc.strerror}: '
              f'{exc.filename or ""}'.rstrip(': '), file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f'servovalve-twin {args.command}: interrupted', file=sys.stderr)
        return 130


if __name__ == '__main__':
    sys.exit(main())
