"""What many tests share: short scenarios, and the one table of bad inputs -- every door's
(the ``servovalve-twin`` commands, the ROS executables) -- each of which must be one line
naming what is wrong and what is allowed, exit code 2, and nothing left behind
(``test/cli/test_cli_safety.py`` runs the table).

A new bad input found is a row here, not a new test.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from servovalve_twin.config import load_scenario

ROOT = Path(__file__).resolve().parents[1]
#: the example package of the docs (``leak_detector:LeakDetector``), importable by the rows
EXAMPLE = ROOT / 'doc' / 'examples' / 'my_detector'

# -- scenarios ---------------------------------------------------------------------------------

#: the paper's scenario as a mapping (1 s: a Com step, a load step, a return)
PAPER = load_scenario('paper').to_dict()


def short(duration: float = 0.2, *, load: float = 5000.0, load_at: float | None = None,
          drop_at: float | None = None, psr_after: float = 1.5e7) -> dict:
    """A short run in which every input moves: a 20 mm command from 0, a ``load`` [N] step at
    ``load_at`` (default half way), the supply dropping from 20 MPa to ``psr_after`` at
    ``drop_at`` (default three quarters of the way)."""
    load_at = duration / 2 if load_at is None else load_at
    drop_at = 0.75 * duration if drop_at is None else drop_at
    return {'duration': duration, 'com': [[0.0, 0.02]], 'fr': [[0.0, 0.0], [load_at, load]],
            'psr': [[0.0, 2.0e7], [drop_at, psr_after]]}


#: the short run of the ROS tests: 0.2 s, load at 0.1 s, supply 15 MPa from 0.15 s
SHORT = short()


def with_fault(scenario: dict, fault: str, severity: float, at: float = 0.0) -> dict:
    """``scenario`` with one fault scheduled from ``at`` [s]."""
    return dict(scenario, faults=[{'at': at, 'fault': fault, 'severity': severity}])


# -- bad inputs --------------------------------------------------------------------------------

ALIAS_BOMB = ('a: &a [x, x, x, x, x, x, x, x, x]\nb: &b [*a, *a, *a, *a, *a, *a, *a, *a, *a]\n'
              'c: &c [*b, *b, *b, *b, *b, *b, *b, *b, *b]\nd: &d [*c, *c, *c, *c, *c, *c, *c]\n'
              'com: [*d, *d, *d, *d, *d, *d, *d, *d, *d]\n')

#: files the rows name, written into the row's working directory first
FILES: dict[str, bytes | str] = {
    'latin1.yaml': 'name: caf\xe9\n'.encode('latin-1'),
    'windows_list.yaml': 'windows: [[0.1, 0.2]]\n',
    'windows_number.yaml': 'windows: 3\n',
    'bomb.yaml': ALIAS_BOMB,
    'deep.yaml': 'duration: 1\ncom: ' + '[' * 100_000 + ']' * 100_000 + '\n',
    'bigcount/metadata.yaml': 'rosbag2_bagfile_information:\n  message_count: 1' + '0' * 5000
                              + '\n',
    'negative_psr.yaml': 'psr: [[0.0, -2.0e+7]]\n',
    'huge_psr.yaml': 'psr: [[0.0, 1.0e+300]]\n',
    'huge_com.yaml': 'com: [[0.0, 1.0e+308]]\n',
    'huge_load.yaml': 'fr: {sine: {offset: 0.0, amplitude: 2.0e+7, frequency: 1.0}}\n',
    'long.yaml': 'duration: 1.0e+6\n',
    'sensor_cor.yaml': 'sensors: {cor: {noise: 1.0}}\n',
    'sensor_period.yaml': 'xj: {noise: 1.0e-6, period: 0.0025}\n',
    'elsewhere/keep.txt': 'not a bag\n',
    'notabag/keep.txt': 'not a bag\n',
}
#: symbolic links the rows name (link -> target), made beside the files
LINKS = {'lnk': 'elsewhere'}


def _row(args, fragment, *marks):
    return pytest.param(args, fragment, marks=list(marks), id=' '.join(args)[:70])


_SIM = ['simulate', '--valve-model', 'C2']
_ROS = pytest.mark.ros
#: (``servovalve-twin`` command line, a fragment of its one error line)
BAD_COMMANDS = [
    # scenarios and parameters
    _row(_SIM + ['--scenario', 'latin1.yaml', '--out', 'x.csv'], 'is not UTF-8 text'),
    _row(_SIM + ['--scenario', 'windows_list.yaml', '--out', 'x.csv'],
         'scenario.windows: expected a mapping'),
    _row(_SIM + ['--scenario', 'windows_number.yaml', '--out', 'x.csv'],
         'scenario.windows: expected a mapping'),
    _row(_SIM + ['--scenario', 'bomb.yaml', '--out', 'x.csv'], 'YAML anchor'),
    _row(_SIM + ['--scenario', 'negative_psr.yaml', '--out', 'x.csv'],
         'PSR = -2e+07 Pa is outside [0, 1e+08] Pa'),
    _row(_SIM + ['--scenario', 'huge_psr.yaml', '--out', 'x.csv'], 'PSR = 1e+300 Pa is outside'),
    _row(_SIM + ['--scenario', 'huge_com.yaml', '--out', 'x.csv'],
         'scenario.com: COM = 1e+308 m is outside [-1, 1] m'),
    _row(['run', '--valve-model', 'C2', '--scenario', 'huge_load.yaml', '--no-bag'],
         'scenario.fr.sine: FR = -2e+07 N is outside [-1e+07, 1e+07] N'),
    _row(['sweep', '--scenario', 'huge_com.yaml', '--fault', 'leakage_growth:5', '--out', 's'],
         'COM = 1e+308 m is outside'),
    _row(_SIM + ['--scenario', 'long.yaml', '--out', 'x.csv'],
         'scenario.duration must be in (0, 3600] s'),
    _row(_SIM + ['--scenario', 'nope.yaml', '--out', 'x.csv'], 'cannot read scenario file'),
    # sensors
    _row(_SIM + ['--scenario', 'sensor_cor.yaml', '--out', 'x.csv'],
         "scenario.sensors: unknown key 'cor'"),
    _row(_SIM + ['--sensor-seed', '3', '--out', 'x.csv'], "'paper' declares no sensors"),
    _row(_SIM + ['--sensor-seed', '-1', '--out', 'x.csv'], 'expected an integer in [0, 2**63'),
    _row(['run', '--valve-model', 'C2', '--sensor-seed', '3', '--no-bag'],
         "sensor_seed: the scenario 'paper' declares no sensors", _ROS),
    _row(['run', '--valve-model', 'C2', '--sensor-seed', '-3', '--no-bag'],
         'sensor_seed = -3: expected an integer in [0, 2**63 - 1]', _ROS),
    _row(['fmu', '--valve-model', 'C2', '--sensors', 'sensor_period.yaml', 'x.fmu'],
         'must be a whole number of control periods'),
    _row(['simulate', '--valve-model', 'C9', '--out', 'x.csv'], "unknown valve model 'C9'"),
    _row(_SIM + ['--param', 'M=-1', '--out', 'x.csv'], 'M = -1.0'),
    _row(_SIM + ['--param', 'Q=1', '--out', 'x.csv'], "unknown parameter 'Q'"),
    _row(_SIM, 'required: --out'),
    # periods
    _row(_SIM + ['--ecu-period', 'abc', '--out', 'x.csv'], 'expected a number'),
    _row(_SIM + ['--ecu-period', '1e-300', '--out', 'x.csv'], 'shorter than DT'),
    _row(_SIM + ['--ecu-period', '1e9', '--out', 'x.csv'],
         'the ECU period = 1e+09 s is longer than 0.1 s'),
    _row(['run', '--valve-model', 'C2', '--control-period', '1e-300', '--no-bag'],
         'shorter than DT', _ROS),
    _row(['run', '--valve-model', 'C2', '--control-period', '5', '--no-bag'],
         'longer than 0.1 s', _ROS),
    _row(['fmu', '--valve-model', 'C2', '--control-period', '1e9', 'x.fmu'],
         'longer than 0.1 s'),
    # outputs
    _row(_SIM + ['--out', 'no_such_dir/x.csv'], 'No such file or directory: no_such_dir/x.csv'),
    _row(['characteristic', '--valve-model', 'C2', '--qj', '0', '--out', 'no_such_dir/c.csv'],
         'No such file or directory: no_such_dir/c.csv'),
    _row(['run', '--valve-model', 'C2', '--bag', 'lnk/b'], "'lnk' is a symbolic link", _ROS),
    # (the files <name>_<n>.mcap would pass the file system's 255 bytes: an empty directory
    # was left)
    _row(['run', '--valve-model', 'C2', '--bag', 'b' * 250], 'is too long: its files are named',
         _ROS),
    _row(['run', '--valve-model', 'C2', '--bag', '.', '--overwrite'],
         'is the working directory or one of its parents', _ROS),
    _row(['run', '--valve-model', 'C2', '--bag', 'notabag', '--overwrite'],
         'holds files but no bag', _ROS),
    # characteristic
    _row(['characteristic', '--valve-model', 'HD', '--qj', '1,x', '--out', 'x.csv'],
         'comma-separated'),
    _row(['characteristic', '--valve-model', 'C2', '--qj', '0,inf', '--out', 'x.csv'],
         'comma-separated finite numbers'),
    _row(['characteristic', '--valve-model', 'C2', '--points', '1000000000', '--out', 'x.csv'],
         'the number of XS points must be in [2, 100001]'),
    # sweeps
    _row(['sweep', '--fault', 'leakage_growth:5~1', '--draws', '2', '--out', 's'], 'LO < HI'),
    _row(['sweep', '--fault', 'leakage_growth:1~inf', '--draws', '2', '--out', 's'],
         'of finite severities'),
    _row(['sweep', '--fault', 'leakage_growth:nan', '--out', 's'], 'of finite severities'),
    _row(['sweep', '--fault', 'leakage_growth:1~5', '--draws', '1000000000', '--out', 's'],
         'a sweep runs 1 to 100000 runs, these options ask for 1000000005'),
    _row(['sweep', '--nominal', '0', '--out', 's'], 'these options ask for 0'),
    _row(['sweep', '--fault', 'leakage_growth:1~5000', '--draws', '2', '--out', 's'],
         'severity 5000.0 x CLk is out of range'),
    _row(['sweep', '--fault', 'leakage_growth:5', '--nominal', '0', '--out', 'notabag'],
         'exists and is not an empty directory'),
    _row(['sweep', '--fault', 'leakage_growth:5', '--workers', '-1', '--out', 's'],
         '--workers must be >= 1'),
    _row(['sweep', '--fault', 'leakage_growth:5', '--nominal', '-1', '--out', 's'],
         '--nominal must be >= 0'),
    _row(['sweep', '--fault', 'leakage_growth:1~5', '--draws', '-1', '--out', 's'],
         '--draws must be >= 0'),
    _row(['sweep', '--fault', 'leakage_growth:5', '--repeats', '-1', '--out', 's'],
         '--repeats must be >= 1'),
    _row(['sweep', '--fault', 'leakage_growth:5', '--seed', '-1', '--out', 's'],
         '--seed must be an integer in [0, 2**63 - 1], got -1'),
    _row(['sweep', '--fault', 'leakage_growth:5', '--scheduler', '::::', '--out', 's'],
         "--scheduler '::::' is not an address"),
    _row(['run', '--valve-model', 'C2', '--clock-period', '1e308', '--no-bag'],
         'clock_period = 1e+308: expected seconds in [1e-06, 1000]', _ROS),
    _row(['run', '--valve-model', 'C2', '--real-time-factor', '1e-300', '--no-bag'],
         'real_time_factor = 1e-300: expected a factor in [0.001, 1e+06]', _ROS),
    _row(['run', '--valve-model', 'C2', '--followers', '100000000000000000000', '--no-bag'],
         'followers = 100000000000000000000: expected a count in [0, 1000]', _ROS),
    _row(_SIM + ['--scenario', 'deep.yaml', '--out', 'x.csv'], 'is nested too deeply'),
    _row(['compare', '@paper_HD', 'bigcount'], 'not readable YAML (a value that cannot be read'),
    # bags
    _row(['compare', '@nope', '@paper_HD'], "unknown reference bag '@nope'"),
    # algorithms
    _row(['evaluate', '@paper_HD', '--algorithm', 'nope_module:X'],
         "cannot import 'nope_module'"),
    _row(['evaluate', '@paper_HD', '--algorithm', 'leak_detector'], 'package.module:ClassName'),
    _row(['evaluate', '@paper_HD', '--algorithm', 'leak_detector:Nope'], "has no 'Nope'"),
    _row(['evaluate', '@paper_HD', '--algorithm', 'leak_detector:LeakDetector',
          '--algorithm-param', 'bogus=1'], "unknown parameter 'bogus'"),
    _row(['evaluate', '@paper_HD', '--algorithm', 'leak_detector:LeakDetector',
          '--algorithm-param', 'min_hold=x'], 'must be a finite int'),
    _row(['evaluate', '@paper_HD', '--algorithm', 'leak_detector:LeakDetector',
          '--algorithm-param', 'tau=nan'], 'parameter tau must be a finite float'),
    _row(['evaluate', '@paper_HD', '--algorithm', 'leak_detector:LeakDetector',
          '--algorithm-param', 'min_hold=inf'], 'parameter min_hold must be a finite int'),
    _row(['compare', '@paper_HD', '@paper_HD', '--tolerance', 'xj=nan'],
         "--tolerance 'xj=nan': the largest error allowed must be a finite number >= 0"),
    _row(['compare', '@paper_HD', '@paper_HD', '--tolerance', 'xj=-1'],
         "--tolerance 'xj=-1': the largest error allowed"),
    _row(['run', '--valve-model', 'C2', '--no-bag', '--monitor', 'SQ', '--algorithm',
          'servovalve_twin.prognostics.monitor:MonitorAlgorithm'],
         'publishes monitor/health_dxj, which another node of the twin publishes already',
         _ROS),
    # the built-in test and detection limits
    _row(['bit', '--out', 'b.yaml', '--duration', '0.2'], 'BIT duration 0.2 s'),
    _row(['bit', '--out', 'b.yaml', '--max-load', '1e6'], 'BIT load'),
    _row(['bit', '--out', 'b.yaml', '--max-rate', '0.001'], 'BIT max rate'),
    _row(['bit', '--out', 'b.txt'], 'expected a new .yaml file'),
    _row(['diagnose', '--limits', 'nope'], 'unknown scenario'),
    _row(['diagnose', '--json', 'x.json'], 'diagnose needs BAG'),
    _row(['diagnose', '@paper_HD', '--limits', 'paper'], 'not both'),
    _row(['diagnose', '--limits', 'paper', '--faults', 'wear'], "unknown fault 'wear'"),
    _row(['diagnose', '--limits', 'paper', '--onset-at', '1.5'], 'outside the flight'),
    _row(['diagnose', '--limits', 'paper', '--onset-at', 'nan'], 'finite number >= 0'),
    _row(['diagnose', '@paper_HD', '--json', 'd.json', '--onset-at', '0.3'],
         'goes with --limits'),
    # playback
    _row(['play', '@paper_HD', '--rate', '1e-300'], 'rate must be a factor in [0.001, 1e+06]',
         _ROS),
    _row(['play', '@paper_HD', '--start-offset', 'inf'], 'start_offset must be in [0, 1e+06] s',
         _ROS),
    _row(['play', '@paper_HD', '--delay', '1e300'], 'delay must be in [0, 1e+06] s', _ROS),
    _row(['play', '@paper_HD', '--playback-duration', 'inf'],
         'playback_duration must be in [0, 1e+06] s', _ROS),
    _row(['play', '@paper_HD', '--clock', '1e9'], 'clock must be in [0, 10000] Hz', _ROS),
    _row(['play', '@paper_HD', '--topics', '/xj', '/nosuch'],
         'topics /nosuch: not in the bag, which has /clock, /com', _ROS),
    _row(['play', '@paper_HD', '--start-offset', '1.5'],
         "start_offset 1.5 s lies at or past the bag's end (1 s long)", _ROS),
    _row(['play', '@paper_HD', '--remap', '/xj:=/clock'], 'a remap onto /clock is not allowed',
         _ROS),
    _row(['play', '@paper_HD', '--remap', '/xj:=/joint_states'],
         'cannot publish /xj (std_msgs/msg/Float64) as /joint_states', _ROS),
]

_REF = str(ROOT / 'servovalve_twin' / 'data' / 'paper_HD')
#: (ROS executable, its arguments, a fragment of its one error line)
BAD_EXECUTABLES = [
    pytest.param('twin', ['-p', 'control_period:=abc'],
                 "control_period = 'abc': expected a positive number", id='twin control_period'),
    pytest.param('twin', ['-p', 'foxglove:=yes'], 'expected a TCP port', id='twin foxglove'),
    pytest.param('twin', ['-p', 'scenario:=@x'], "Couldn't parse parameter override rule",
                 id='twin YAML'),
    pytest.param('player', ['-p', f'bag:={_REF}', '-p', 'rate:=fast'],
                 "rate = 'fast': expected a number", id='player rate'),
    pytest.param('player', ['-p', f'bag:={_REF}', '-p', 'topics:=xj'],
                 "topics = 'xj': expected a list of strings", id='player topics'),
    pytest.param('player', ['-p', f'bag:={_REF}', '-p', 'loop:=maybe'],
                 "loop = 'maybe': expected true or false", id='player loop'),
    pytest.param('player', ['-p', 'bag:=@paper_HD'], "Couldn't parse parameter override rule",
                 id='player YAML'),
    pytest.param('replay', ['-p', 'bag:=@paper_HD'], "Couldn't parse parameter override rule",
                 id='replay YAML'),
    pytest.param('plant', ['-p', 'M:=@x'], "Couldn't parse parameter override rule",
                 id='plant YAML'),
    pytest.param('plant', ['-p', 'sensors:="{xj: {noise: -1.0}}"'],
                 'parameter sensors.xj.noise must be >= 0', id='plant sensors'),
]


def make_files(directory: Path) -> None:
    """:data:`FILES` and :data:`LINKS` in ``directory``."""
    for name, data in FILES.items():
        f = directory / name
        f.parent.mkdir(parents=True, exist_ok=True)
        f.write_bytes(data if isinstance(data, bytes) else data.encode())
    for link, target in LINKS.items():
        (directory / link).symlink_to(target)


def listing(directory: Path) -> list[str]:
    """Every path under ``directory``, relative (links not followed): what a refusal must
    leave as it was."""
    return sorted(str(p.relative_to(directory)) for p in directory.rglob('*'))


#: a user's algorithms that misbehave, as a module's source: a step that never returns (from
#: 5 ms), one that ends the process (os._exit skips every handler), one slow (2 ms a step) but
#: returning -- for the hosts' watchdog and exit guard (evaluate, run)
HOSTILE_ALGORITHMS = '''
import os
import time
from servovalve_twin.prognostics.algorithm import Algorithm


class Stuck(Algorithm):
    inputs = ('xj',)
    outputs = ('x',)

    def step(self, t, u):
        if t >= 0.005:
            time.sleep(1e6)
        return {'x': u['xj']}


class Exiting(Stuck):
    def step(self, t, u):
        if t >= 0.005:
            os._exit(0)
        return {'x': u['xj']}


class Waiting(Stuck):
    def step(self, t, u):
        time.sleep(0.002)
        return {'x': u['xj']}
'''
