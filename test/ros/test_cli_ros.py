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
    assert code == 0 and 'overstall' in out and 'phase4' in out
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
