"""The front door's ROS commands: run (bag + CSV from the ROS run's own messages), compare."""

import json

import numpy as np

from servovalve_twin.bag.reader import read_bag
from servovalve_twin.cli import main
from servovalve_twin.runs import read_csv, simulate
from conftest import ROOT


def test_run_writes_bag_and_the_csv_of_simulate(tmp_path, capsys):
    out = tmp_path / 'run.csv'
    assert main(['run', '--valve-model', 'C4', '--bag', str(tmp_path / 'b'), '--out', str(out),
                 '--param', 'CLk=4e-13']) == 0
    print(capsys.readouterr().out)
    data = read_csv(out)
    ref = simulate('C4', 'paper', {'CLk': 4e-13}, ecu_period=1e-3)
    assert list(data) == list(ref.columns)
    for c in ref.columns:
        np.testing.assert_array_equal(data[c], ref[c])
    assert read_bag(tmp_path / 'b').params()['CLk'] == 4e-13


def test_run_bad_input_exit_2(tmp_path, capsys):
    assert main(['run', '--valve-model', 'C9', '--no-bag']) == 2
    assert "unknown valve model 'C9'" in capsys.readouterr().err
    assert main(['run', '--valve-model', 'C2', '--control-period', '0.0015', '--no-bag']) == 2
    assert 'must divide the 1 ms' in capsys.readouterr().err
    for extra, fragment in ((['--clock', 'follow', '--real-time-factor', '1'],
                             'paced by the clock owner'),
                            (['--namespace', 'left wing'], "namespace 'left wing'"),
                            (['--clock', 'follow', '--followers', '1'], 'only the clock owner'),
                            (['--followers', '-2'], 'expected a count in [0, 1000]')):
        assert main(['run', '--valve-model', 'C2', '--no-bag', *extra]) == 2
        err = capsys.readouterr().err
        assert fragment in err and len(err.strip().splitlines()) == 1, err


def test_compare_tables_json_plot_and_tolerance(tmp_path, capsys):
    hd = ROOT / 'servovalve_twin' / 'data' / 'paper_HD'
    csv = tmp_path / 'c2.csv'
    assert main(['simulate', '--valve-model', 'C2', '--ecu-period', '0.001', '--out',
                 str(csv)]) == 0
    js, png = tmp_path / 'm.json', tmp_path / 'm.png'
    code = main(['compare', str(hd), str(csv), '--json', str(js), '--plot', str(png),
                 '--tolerance', 'xj=1.0'])
    out = capsys.readouterr().out
    print(out)
    assert code == 0 and 'overstall' in out and 'recovery' in out
    metrics = json.loads(js.read_text())['metrics']
    assert metrics['all']['xj']['max'] > 1e-3 and png.stat().st_size > 1000
    assert main(['compare', str(hd), str(csv), '--tolerance', 'xj=1e-4']) == 1
    assert main(['compare', str(hd), str(csv), '--tolerance', 'speed=1']) == 2
    # mismatched inputs: another scenario
    other = tmp_path / 'other.csv'
    assert main(['simulate', '--valve-model', 'C2', '--scenario', 'defaults', '--out',
                 str(other)]) == 0
    assert main(['compare', str(hd), str(other)]) == 2
    assert 'different inputs' in capsys.readouterr().err


def _scenario(tmp_path, seconds):
    import yaml
    path = tmp_path / f'{seconds:g}s.yaml'
    path.write_text(yaml.safe_dump({'duration': float(seconds), 'com': [[0.0, 0.0],
                                                                        [0.05, 0.02]]}))
    return str(path)


def test_pacing_divides_the_simulated_time_by_the_factor(tmp_path):
    """2 s simulated at a real-time factor of 8 take at least 0.25 s of wall time (pacing
    never runs ahead) and far less than the 16 s a factor applied the wrong way round gives."""
    import re
    import subprocess
    import sys
    r = subprocess.run([sys.executable, '-m', 'servovalve_twin.cli', 'run', '--valve-model',
                        'C2', '--scenario', _scenario(tmp_path, 2), '--no-bag',
                        '--real-time-factor', '8'], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    wall = float(re.search(r'2\.000 s simulated in ([0-9.]+) s', r.stdout).group(1))
    assert 0.25 * 0.98 <= wall < 4.0, r.stdout


def test_run_interrupted_exits_130_with_a_finished_bag(tmp_path):
    """SIGINT to a paced run once its bag has begun: exit 130 (what a shell's Ctrl-C means),
    INTERRUPTED in its line, the bag closed with its metadata."""
    import signal
    import subprocess
    import sys
    import time
    bag = tmp_path / 'b'
    proc = subprocess.Popen([sys.executable, '-m', 'servovalve_twin.cli', 'run', '--valve-model',
                             'C2', '--scenario', _scenario(tmp_path, 30), '--bag', str(bag),
                             '--real-time-factor', '1'], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    # running: the bag has grown past its first chunks (a SIGINT while the twin is still
    # starting removes the bag it began: a run that never started records nothing)
    mcap = bag / 'b_0.mcap'
    deadline = time.monotonic() + 120
    while not (mcap.exists() and mcap.stat().st_size > 20_000) and time.monotonic() < deadline:
        time.sleep(0.05)
    proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, (out, err)
    assert 'INTERRUPTED' in out and 'Traceback' not in err
    assert (bag / 'metadata.yaml').is_file() and len(read_bag(bag).signals['t']) > 0
