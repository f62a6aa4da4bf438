"""The command-line front door: outputs, exit codes and one-line errors."""

import subprocess
import sys

import numpy as np
import pytest

from servovalve_twin.cli import main
from servovalve_twin.physics.simulate import CSV_COLUMNS
from servovalve_twin.runs import read_csv, simulate


def test_simulate_writes_the_csv(tmp_path, capsys):
    out = tmp_path / 'c2.csv'
    assert main(['simulate', '--valve-model', 'C2', '--out', str(out)]) == 0
    header = out.read_text().splitlines()[0]
    assert header == ','.join(CSV_COLUMNS)
    data = read_csv(out)
    assert len(data['t']) == 1001 and data['t'][-1] == 1.0
    ref = simulate('C2', 'paper')
    np.testing.assert_array_equal(data['xj'], ref['xj'])      # CSV round-trips exactly


def test_simulate_hd_adds_port_pressures_and_params_apply(tmp_path):
    out = tmp_path / 'hd.csv'
    assert main(['simulate', '--valve-model', 'HD', '--param', 'M=400', '--ecu-period', '0.001',
                 '--out', str(out)]) == 0
    data = read_csv(out)
    assert {'p1', 'p2'} <= set(data)
    ref = simulate('HD', 'paper', {'M': 400.0}, ecu_period=1e-3)
    np.testing.assert_array_equal(data['xj'], ref['xj'])


def test_simulate_with_sensors_writes_readings_and_truth(tmp_path):
    """A scenario file with sensors: the CSV's xj is what the XJ sensor read, xj_true the
    truth beside it (simulate()'s), and --sensor-seed another realisation of the same
    sensors (the truth moves too: the ECU closes its loop on the reading)."""
    import yaml
    scn = tmp_path / 's.yaml'
    scn.write_text(yaml.safe_dump({'duration': 0.1, 'com': [[0.0, 0.01]],
                                   'sensors': {'seed': 3, 'xj': {'noise': 2.0e-5}}}))
    rows = {}
    for seed in (None, 4):
        out = tmp_path / f'run{seed}.csv'
        args = ['simulate', '--valve-model', 'C2', '--scenario', str(scn), '--out', str(out)]
        assert main(args + ([] if seed is None else ['--sensor-seed', str(seed)])) == 0
        rows[seed] = read_csv(out)
        ref = simulate('C2', str(scn), sensor_seed=seed)
        assert list(rows[seed]) == list(CSV_COLUMNS) + ['xj_true']
        assert np.array_equal(rows[seed]['xj'], ref['xj'])
        assert np.array_equal(rows[seed]['xj_true'], ref.truth['xj'])
    assert not np.array_equal(rows[None]['xj'], rows[None]['xj_true'])
    assert not np.array_equal(rows[None]['xj'], rows[4]['xj'])


def test_characteristic(tmp_path):
    out, png = tmp_path / 'ch.csv', tmp_path / 'ch.png'
    assert main(['characteristic', '--valve-model', 'HD', '--qj', '0,8e-5', '--points', '41',
                 '--out', str(out), '--plot', str(png)]) == 0
    data = read_csv(out)
    assert list(data) == ['xs', 'qj', 'p12', 'p1', 'p2'] and len(data['xs']) == 82
    assert png.stat().st_size > 1000
    assert main(['characteristic', '--valve-model', 'C2', '--psr', '1.2e7', '--out',
                 str(out)]) == 0
    data = read_csv(out)
    assert list(data) == ['xs', 'qj', 'p12'] and np.max(np.abs(data['p12'])) <= 1.2e7


def test_calibrate_prints_the_gains(capsys):
    from servovalve_twin.physics.valves.calibration import calibrate
    from servovalve_twin.physics.params import DEFAULTS
    assert main(['calibrate', '--param', 'c=8e-6']) == 0
    printed = {}
    for line in capsys.readouterr().out.splitlines():
        if '=' in line and not line.startswith('#'):
            name, value = line.split('=', 1)
            printed[name.strip()] = float(value.split()[0])
    expected = calibrate(DEFAULTS.replace(c=8e-6))
    assert printed == pytest.approx(expected, rel=1e-12)


def test_console_script_exit_code():
    # the installed entry point behaves like main(): a subprocess sees exit code 2
    r = subprocess.run([sys.executable, '-m', 'servovalve_twin.cli', 'simulate',
                        '--valve-model', 'X', '--out', '/dev/null'], capture_output=True,
                       text=True)
    assert r.returncode == 2 and r.stderr.startswith('servovalve-twin simulate: error:')
    assert 'Traceback' not in r.stderr


@pytest.mark.slow
def test_report_writes_a_new_directory_and_edits_nothing(tmp_path, monkeypatch, capsys):
    """``report`` writes report.md (the tables, the machine and its load) and the figures into
    a new directory -- by default out/report under the working directory -- and refuses one
    that holds anything: it never overwrites, and never edits a page of the repository."""
    monkeypatch.chdir(tmp_path)
    assert main(['report']) == 0
    out = tmp_path / 'out' / 'report'
    page = (out / 'report.md').read_text()
    assert 'load average' in page and 'CPUs' in page
    assert '| SQ |' in page and '| C2 |' in page and 'step cost' in page
    assert (out / 'characteristic.png').stat().st_size > 1000
    assert len(list(out.glob('*.png'))) >= 12
    before = page
    capsys.readouterr()
    assert main(['report', '--out-dir', str(out)]) == 2
    err = capsys.readouterr().err
    assert 'not an empty directory' in err and err.count('\n') == 1
    assert (out / 'report.md').read_text() == before


def test_the_verdict_line_states_the_onset_and_its_confidence():
    """`diagnose`'s line: the severity with the verdict's confidence, and the onset with its
    own (a pinned onset as a point and interval, an unpinned one as the span it began in)."""
    from servovalve_twin.cli.diagnosis import _verdict_line
    from servovalve_twin.prognostics.verdict import Candidate, Diagnosis
    cand = Candidate('leakage_growth', 1.8, (1.7, 1.9), 0.0, 1.0, {}, {})
    d = Diagnosis(model='SQ', window=(0.0, 1.0), candidates=[cand], n_eff=100.0,
                  evaluations=1, recorded={}, confidence=0.9,
                  onset=dict(t=0.3, interval=[0.298, 0.302], identifiable=True,
                             confidence=0.9))
    assert _verdict_line(d) == ('leakage_growth, severity 1.8 x CLk (90 % [1.7, 1.9]), from t = '
                                '0.300 s (90 % [0.298, 0.302])')
    d.onset = dict(t=0.0, interval=[0.0, 0.36], identifiable=False, confidence=0.95)
    assert _verdict_line(d).endswith('begun between 0.000 and 0.360 s (the run cannot tell '
                                     'when)')


def test_the_diagnosis_line_names_rivals_and_a_poor_fit():
    """diagnose's one line: a 10 x leak read as a supply loss with RMS 30 and two rivals in
    the JSON showed neither on the line."""
    from types import SimpleNamespace
    from servovalve_twin.cli.diagnosis import _verdict_line
    best = SimpleNamespace(fault='supply_loss', faults=('supply_loss',), severity=0.7492,
                           severities=(0.7492,), intervals=((0.7333, 0.7652),))
    d = SimpleNamespace(best=best, verdict=None, confidence=0.95, onset=None,
                        rivals=['clearance_growth', 'leakage_growth'], p_value=0.004,
                        fit_rms=30.0)
    line = _verdict_line(d)
    assert line.startswith('supply_loss, severity 0.7492 of PSR (95 % [0.7333, 0.7652])')
    assert '; also consistent with clearance_growth, leakage_growth' in line
    assert '; poor fit: RMS 30 of the residual scales, worse than 99.6% of right fits' in line
    d.rivals, d.p_value = [], 0.5
    assert _verdict_line(d) == 'supply_loss, severity 0.7492 of PSR (95 % [0.7333, 0.7652])'
    d.p_value = 0.049                   # POOR_FIT_P = 0.05
    assert 'poor fit' in _verdict_line(d)


def test_severities_are_printed_with_their_units():
    """A null bias of -1.214e-3 A read '-0.001214' (amperes, unsaid): mA now; a multiplier
    and a fraction name what they multiply or take from."""
    from servovalve_twin.physics.faults import FAULTS
    assert FAULTS['null_bias'].show(-1.2137e-3) == '-1.214 mA'
    assert FAULTS['null_bias'].show(-1.2137e-3, False) == '-1.214'
    assert FAULTS['leakage_growth'].show(6.01234) == '6.012 x CLk'
    assert FAULTS['supply_loss'].show(0.28171) == '0.2817 of PSR'


def test_every_command_shows_an_example_that_parses(capsys):
    """Each --help ends with an example (none had one); each example is a command line the
    parser takes as written."""
    import shlex
    from servovalve_twin.cli import COMMANDS, EXAMPLES, build_parser
    assert set(EXAMPLES) == {c.name for c in COMMANDS}
    parser = build_parser()
    for name, line in EXAMPLES.items():
        argv = shlex.split(line)
        assert argv[0] == 'servovalve-twin' and argv[1] == name
        parser.parse_args(argv[1:])
        with pytest.raises(SystemExit) as done:
            parser.parse_args([name, '--help'])
        assert done.value.code == 0
        assert f'example: {line}' in ' '.join(capsys.readouterr().out.split())
