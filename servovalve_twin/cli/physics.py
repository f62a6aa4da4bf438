"""Commands on the physics alone (no ROS): simulate, characteristic, calibrate, params,
faults, report, fmu."""

from __future__ import annotations

import argparse
import sys

from ..errors import TwinError
from .common import (Command, add_param_options, add_scenario_options, float_list, overrides,
                     positive_float, seed_int)


class Simulate(Command):
    name = 'simulate'
    help = 'ROS-free run of a scenario to CSV'

    def add_arguments(self, p):
        add_scenario_options(p)
        p.add_argument('--ecu-period', type=positive_float, metavar='S',
                       help='sample the ECU with this period (a multiple of DT); default '
                            'continuous')
        p.add_argument('--sensor-seed', type=seed_int, metavar='N',
                       help="the noise realisation of the scenario's sensors (default their "
                            'seed)')
        p.add_argument('--out', required=True, metavar='FILE.csv',
                       help="the 1 ms rows t,com,fr,psr,cor,xs,xj,dxj,p12,qj (HD adds p1,p2), "
                            'SI -- with sensors, what they read, and the truth of each sensed '
                            "signal as xj_true, ...; CSV, or Parquet for a .parquet name; '-' "
                            'writes CSV to standard output')

    def main(self, args):
        from ..config import load_scenario
        from ..runs import simulate, write_table
        scenario = load_scenario(args.scenario)
        result = simulate(args.valve_model, scenario, overrides(args),
                          ecu_period=args.ecu_period, sensor_seed=args.sensor_seed)
        write_table(args.out, {**result.signals,
                               **{f'{k}_true': v for k, v in result.truth.items()}})
        info = ', '.join(f'{k}={v}' for k, v in result.info.items() if k != 'wall_s')
        print(f'{result.valve_model} on {result.scenario.name}: {len(result["t"])} rows -> '
              f'{"stdout" if args.out == "-" else args.out} '
              f'({result.info["wall_s"] * 1e3:.1f} ms; {info})',
              file=sys.stderr if args.out == '-' else sys.stdout)
        return 0


class Characteristic(Command):
    name = 'characteristic'
    help = "the paper's Fig. 3: P12 against XS per QJ"

    def add_arguments(self, p):
        p.add_argument('--valve-model', required=True, metavar='NAME',
                       help='a registered valve model (servovalve-twin --help lists them)')
        p.add_argument('--psr', type=positive_float, metavar='PA', help='default PSRN')
        p.add_argument('--qj', type=float_list, metavar='Q1,Q2,...',
                       help='working flows [m^3/s] (default 0,4e-5,8e-5,1.2e-4)')
        p.add_argument('--points', type=int, default=401, help='XS samples over [-XSM, XSM]')
        add_param_options(p)
        p.add_argument('--out', required=True, metavar='FILE.csv',
                       help='columns xs,qj,p12 (HD: p1,p2)')
        p.add_argument('--plot', metavar='FILE.png', help='also draw the curves (paper Fig. 3)')

    def main(self, args):
        import numpy as np
        from ..apps.plots import plot_characteristic
        from ..physics.characteristic import characteristic
        from ..physics.params import make_params
        from ..runs import write_csv
        params = make_params(overrides(args))
        psr = params.PSRN if args.psr is None else args.psr
        qj = args.qj if args.qj is not None else [0.0, 4.0e-5, 8.0e-5, 1.2e-4]
        curves = characteristic(args.valve_model, params, psr, qj, n_points=args.points)
        write_csv(args.out, curves)
        if args.plot:
            plot_characteristic({args.valve_model: curves}, args.plot, psr)
        blank = int(np.isnan(curves['p12']).sum())
        print(f'{args.valve_model}: P12(XS) at PSR={psr:g} Pa for QJ={qj} -> {args.out}'
              + (f'; {blank} of {len(curves["p12"])} points have no steady state (nan, left '
                 'blank in the plot)' if blank else ''))
        return 0


class Calibrate(Command):
    name = 'calibrate'
    help = 'XSS, GPN, GQN, GPQ, k of the simplified models from HD'

    def add_arguments(self, p):
        add_param_options(p)

    def main(self, args):
        from ..physics.params import make_params
        from ..physics.valves.calibration import calibrate
        cal = calibrate(make_params(overrides(args)))
        units = dict(XSS='m', GPN='Pa/m', GQN='m^2/s', GPQ='Pa*s/m^3', k='-')
        for name, value in cal.items():
            print(f'{name:4s} = {value!r:24s} [{units[name]}]')
        print('# XSS and GPQ are derived from the design when not given; --param XSS=... --param '
              'GPQ=... overrides them')
        return 0


class Params(Command):
    name = 'params'
    help = 'list every parameter with default, unit and bounds'

    def main(self, args):
        from ..physics.params import param_table
        for row in param_table():
            left = '(' if row['lo_open'] else '['
            derived = ' (derived)' if row['derived'] else ''
            print(f'{row["name"]:12s} {row["default"]!r:>24} {row["unit"]:12s} '
                  f'{left}{row["lo"]:g}, {row["hi"]:g}]  {row["doc"]}{derived}')
        return 0


class Faults(Command):
    name = 'faults'
    help = 'list the injectable faults'

    def main(self, args):
        from ..physics.faults import FAULTS
        for f in FAULTS.values():
            print(f'{f.name:24s} {f.param:10s} [{f.lo:g}, {f.hi:g}] {f.unit:18s} alarm at '
                  f'{f.demo:g}: {f.meaning}')
        return 0


class Report(Command):
    name = 'report'
    help = 'every model against HD on the paper scenario and SQ beyond it: tables and figures ' \
           'into a new directory'

    def add_arguments(self, p):
        p.add_argument('--out-dir', default='out/report', metavar='DIR',
                       help='a new or empty directory for report.md (the tables, the machine '
                            'and its load) and the figures (default out/report); no file of '
                            'the repository is edited')
        add_param_options(p)

    def main(self, args):
        from pathlib import Path
        from ..apps.report import make_report
        print(make_report(out_dir=Path(args.out_dir), overrides=overrides(args)))
        return 0


class Fmu(Command):
    name = 'fmu'
    help = 'an FMI 2.0 co-simulation FMU of the actuator (pythonfmu)'

    def add_arguments(self, p: argparse.ArgumentParser):
        p.add_argument('--valve-model', required=True, metavar='NAME',
                       help='the valve model inside (a name of the registry: C2, SQ, HD, ...)')
        p.add_argument('--control-period', type=float, default=1e-3, metavar='S',
                       help='the ECU sampling period [s], a multiple of DT (default 0.001); a '
                            'communication step must be a whole number of them')
        p.add_argument('--sensors', metavar='FILE.yaml',
                       help="the unit's sensors: a YAML file with a scenario's sensors "
                            'mapping (seed and per signal noise, bias, drift, quantisation, '
                            'period); the FMU then has a sensor_seed parameter')
        p.add_argument('out', metavar='OUT.fmu', help='the FMU file to write (a new one)')

    def main(self, args):
        import time
        import importlib.util
        if importlib.util.find_spec('pythonfmu') is None:
            raise TwinError("the fmu command needs pythonfmu: pip install "
                            "'servovalve_twin[fmu]'")
        from ..fmu import build_fmu
        sensors = None
        if args.sensors:
            from pathlib import Path
            from ..config import read_yaml
            sensors = read_yaml(Path(args.sensors), 'sensors file')
        t = time.perf_counter()
        out = build_fmu(args.valve_model, args.out, control_period=args.control_period,
                        sensors=sensors)
        print(f'{out}: FMI 2.0 co-simulation FMU of the EHA with {args.valve_model}, ECU every '
              f'{args.control_period:g} s ({out.stat().st_size / 1e3:.0f} kB, '
              f'{time.perf_counter() - t:.1f} s)')
        return 0
