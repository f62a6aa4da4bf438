"""A first hour without surprises: the reference bag is safe, nothing is
deleted that is not the bag's own, a refused start leaves nothing, corruption is detected."""

import random
import shutil

import numpy as np
import pytest

from servovalve_twin.bag.reader import read_bag
from servovalve_twin.bag.writer import BagWriter
from servovalve_twin.cli import main
from servovalve_twin.config import default_bag_dir, resolve_bag
from servovalve_twin.errors import BagError, TwinError
from servovalve_twin.twin import Twin, TwinConfig, run_twin
from cases import BAD_COMMANDS, BAD_EXECUTABLES, EXAMPLE, listing, make_files, short
from conftest import ROOT

REF = ROOT / 'servovalve_twin' / 'data' / 'paper_HD'
SHORT = short(0.05, load_at=0.02)


def _snapshot(d):
    return {p.name: p.read_bytes() for p in sorted(d.iterdir())}


def test_the_reference_bag_is_read_only_to_every_command(ros_context, tmp_path, capsys):
    before = _snapshot(REF)
    assert resolve_bag('@paper_HD') == REF
    with pytest.raises(BagError, match='packaged reference'):
        BagWriter(REF, overwrite=True)
    with pytest.raises(BagError, match='packaged reference'):
        run_twin(TwinConfig('C2', SHORT, bag=REF / 'inner', overwrite=True), context=ros_context,
                 handle_signals=False)
    assert main(['reindex', '@paper_HD']) == 2
    assert main(['run', '--valve-model', 'HD', '--bag', str(REF), '--overwrite']) == 2
    err = capsys.readouterr().err
    assert 'packaged reference' in err
    # compare and replay read it; the replay's default output is a new bag under bags/
    assert main(['compare', '@paper_HD', '@paper_HD']) == 0
    assert _snapshot(REF) == before


def test_overwrite_replaces_only_the_bags_own_files(tmp_path):
    d = tmp_path / 'run'
    BagWriter(d).close()
    assert sorted(p.name for p in d.iterdir()) == ['metadata.yaml', 'run_0.mcap']
    (d / 'notes.yaml').write_text('mine\n')
    (d / 'other.mcap').write_bytes(b'mine')
    (d / 'run_7.mcap.bak').write_bytes(b'mine')
    with pytest.raises(BagError, match='--overwrite'):
        BagWriter(d)
    w = BagWriter(d, overwrite=True)
    w.add_topic('/x', 'std_msgs/msg/Float64')
    w.write('/x', b'\x00\x01\x00\x00' + b'\x00' * 8, 0)
    w.close()
    assert (d / 'notes.yaml').read_text() == 'mine\n'
    assert (d / 'other.mcap').read_bytes() == b'mine' and (d / 'run_7.mcap.bak').exists()
    # a planted link is never followed: not as the temporary metadata file, nor as a bag file
    victim = tmp_path / 'victim.txt'
    victim.write_text('precious\n')
    (d / 'metadata.yaml.tmp').symlink_to(victim)
    w = BagWriter(d, overwrite=True)
    w.close()
    assert victim.read_text() == 'precious\n'
    (d / 'metadata.yaml').unlink()
    (d / 'metadata.yaml').symlink_to(victim)
    with pytest.raises(BagError, match='symbolic link'):
        BagWriter(d, overwrite=True)
    assert victim.read_text() == 'precious\n'


def test_default_bag_names_never_collide_and_stay_under_bags(tmp_path):
    a = default_bag_dir('../../x', 'C2', root=tmp_path / 'bags')
    assert a.parent == tmp_path / 'bags' and a.name.startswith('x_C2_')
    a.mkdir(parents=True)
    b = default_bag_dir('../../x', 'C2', root=tmp_path / 'bags')
    assert b != a and b.parent == a.parent


def test_a_refused_start_leaves_nothing_behind(ros_context, tmp_path, monkeypatch):
    bag = tmp_path / 'refused'
    with pytest.raises(TwinError, match='simplified'):
        Twin(TwinConfig('C2', SHORT, bag=bag, monitor='HD'), context=ros_context)
    assert not bag.exists()
    bag.mkdir()
    (bag / 'keep.txt').write_text('x')
    with pytest.raises(TwinError):
        Twin(TwinConfig('C2', SHORT, bag=bag, overwrite=True, algorithm=['nope_module:X']),
             context=ros_context)
    assert sorted(p.name for p in bag.iterdir()) == ['keep.txt']
    # an output path that cannot be written is refused before the run, leaving no bag
    monkeypatch.chdir(tmp_path)
    assert main(['run', '--valve-model', 'C2', '--scenario', 'defaults', '--out',
                 'missing_dir/run.csv']) == 2
    assert not (tmp_path / 'bags').exists()


@pytest.mark.slow
def test_byte_flips_are_detected_never_read_silently(ros_context, tmp_path):
    """Every chunk, the data section and the summary carry a CRC: a flipped byte anywhere
    either fails with one line or changes nothing that is read."""
    bag = tmp_path / 'b'
    run_twin(TwinConfig('C2', SHORT, bag=bag), context=ros_context, handle_signals=False)
    good = read_bag(bag)
    data = (bag / 'b_0.mcap').read_bytes()
    rng = random.Random(7)
    detected = unchanged = 0
    for pos in rng.sample(range(len(data)), 150):
        flipped = bytearray(data)
        flipped[pos] ^= 0xA5
        d = tmp_path / f'f{pos}'
        shutil.copytree(bag, d)
        (d / 'b_0.mcap').write_bytes(bytes(flipped))
        try:
            run = read_bag(d)
        except BagError:
            detected += 1
            continue
        assert run.provenance == good.provenance and run.topics == good.topics, pos
        for k in good.signals:
            np.testing.assert_array_equal(run.signals[k], good.signals[k], err_msg=f'{pos} {k}')
        unchanged += 1
        shutil.rmtree(d)
    print(f'{len(data)} bytes, 150 flips: {detected} detected, {unchanged} harmless')
    assert detected > 100


def test_reindex_reports_what_it_skipped(ros_context, tmp_path, capsys):
    bag = tmp_path / 'cut'
    run_twin(TwinConfig('C2', dict(SHORT, duration=0.3), bag=bag), context=ros_context,
             handle_signals=False)
    f = bag / 'cut_0.mcap'
    data = f.read_bytes()
    (bag / 'metadata.yaml').unlink()
    f.write_bytes(data[: len(data) * 2 // 3])
    assert main(['reindex', str(bag)]) == 0
    out, err = capsys.readouterr()
    assert 'rebuilt' in out and 'skipped' in err and 'bytes from byte' in err
    run = read_bag(bag)
    assert run.valve_model == 'C2' and 0.0 < run.signals['t'][-1] < 0.3


def test_compare_warns_when_the_runs_differ_in_more_than_the_model(ros_context, tmp_path,
                                                                   capsys):
    run_twin(TwinConfig('C2', SHORT, bag=tmp_path / 'a'), context=ros_context, handle_signals=False)
    run_twin(TwinConfig('C3', SHORT, bag=tmp_path / 'b'), {'M': 400.0}, context=ros_context,
             handle_signals=False)
    run_twin(TwinConfig('C3', SHORT, bag=tmp_path / 'c'), context=ros_context, handle_signals=False)
    assert main(['compare', str(tmp_path / 'a'), str(tmp_path / 'b')]) == 0
    err = capsys.readouterr().err
    assert 'warning: the runs were made with different parameters: M 500.0 vs 400.0' in err
    assert main(['compare', str(tmp_path / 'a'), str(tmp_path / 'c')]) == 0
    assert 'warning' not in capsys.readouterr().err


@pytest.mark.parametrize('args, fragment', BAD_COMMANDS)
def test_bad_input_is_one_line_and_exit_2(tmp_path, monkeypatch, capsys, args, fragment):
    """Every row of the bad-input table (test/cases.py)."""
    monkeypatch.chdir(tmp_path)
    monkeypatch.syspath_prepend(str(EXAMPLE))
    make_files(tmp_path)
    before = listing(tmp_path)
    try:
        rc = main(args)
    except SystemExit as exc:             # argparse's own refusals
        rc = exc.code
    assert rc == 2
    err = capsys.readouterr().err
    print(err.strip())
    assert fragment in err and err.count('\n') == 1 and 'Traceback' not in err, err
    assert len(err) < 700
    assert listing(tmp_path) == before      # nothing left behind, nothing written elsewhere


@pytest.mark.ros
@pytest.mark.parametrize('executable, args, fragment', BAD_EXECUTABLES)
def test_an_executables_bad_parameter_is_one_line_and_exit_2(tmp_path, executable, args,
                                                              fragment):
    """The ROS executables' rows of the bad-input table: rcl hands a ``-p`` value over as
    whatever YAML makes of it (``rate:=fast`` a string, ``topics:=xj`` not a list)."""
    import subprocess
    from conftest import console_script
    r = subprocess.run([console_script(executable), '--ros-args', *args], capture_output=True,
                       text=True, timeout=120, cwd=tmp_path)
    print(r.stderr.strip())
    assert r.returncode == 2 and fragment in r.stderr and 'Traceback' not in r.stderr
    assert r.stderr.strip().count('\n') == 0
    assert not any(tmp_path.iterdir())


@pytest.mark.ros
def test_nodes_refuse_misspelt_parameters_and_accept_integers_for_doubles(tmp_path):
    import subprocess
    from conftest import console_script
    r = subprocess.run([console_script('plant'), '--ros-args', '-p', 'valve_modle:=HD'],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 2 and "no parameter 'valve_modle'" in r.stderr
    r = subprocess.run([console_script('plant'), '--ros-args', '--params-file',
                        str(tmp_path / 'missing.yaml')], capture_output=True, text=True,
                       timeout=120)
    assert r.returncode == 2 and "Couldn't parse params file" in r.stderr
    assert 'Traceback' not in r.stderr
    r = subprocess.run([console_script('plant'), '--help'], capture_output=True, text=True,
                       timeout=120)
    assert r.returncode == 0 and r.stdout.startswith('usage: plant') and 'valve_model' in r.stdout
    latin = tmp_path / 'latin1.yaml'
    latin.write_bytes('name: caf\xe9\n'.encode('latin-1'))
    r = subprocess.run([console_script('load_supply'), '--ros-args', '-p',
                        f'scenario:={latin}'], capture_output=True, text=True, timeout=120)
    assert r.returncode == 2 and 'not UTF-8' in r.stderr and 'Traceback' not in r.stderr


def test_integer_for_a_double_and_out_of_range_supply(ros_context):
    from rclpy.parameter import Parameter
    from servovalve_twin.nodes.plant import Plant
    node = Plant(context=ros_context, parameter_overrides=[Parameter('M', value=400)])
    try:
        assert node.plant.params.M == 400.0
        # ... and stored as the double it means: it reads back as one
        m = node.get_parameter('M')
        assert m.type_ == Parameter.Type.DOUBLE and m.value == 400.0
        assert node.set_parameters([Parameter('CJ', value=2500)])[0].successful
        assert node.plant.params.CJ == 2500.0
        cj = node.get_parameter('CJ')
        assert cj.type_ == Parameter.Type.DOUBLE and cj.value == 2500.0
        for bad in (-1.0, 1e300):
            node.io.push('psr', bad)
            assert node.io.latest['psr'] == node.params.PSRN        # dropped, not integrated
        # /p1, /p2 exist only while a model with port pressures is in force
        assert 'p1' not in node.pubs
        assert node.set_parameters([Parameter('valve_model', value='HD')])[0].successful
        assert {'p1', 'p2'} <= set(node.pubs)
        node.set_parameters([Parameter('valve_model', value='C2')])
        assert 'p1' not in node.pubs
    finally:
        node.destroy_node()


def test_every_subcommand_and_option_explains_itself(capsys):
    import argparse
    import subprocess
    import sys
    from servovalve_twin import __version__
    from servovalve_twin.cli import build_parser
    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    for name, sp in sub.choices.items():
        assert sp.description, name
        missing = [a.dest for a in sp._actions if not a.help and a.dest != 'help']
        assert not missing, (name, missing)
    r = subprocess.run([sys.executable, '-m', 'servovalve_twin', '--version'],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0 and r.stdout.strip() == f'servovalve-twin {__version__}'


def test_csv_to_stdout_and_a_closed_pipe_is_quiet(tmp_path):
    import subprocess
    import sys
    cmd = [sys.executable, '-m', 'servovalve_twin', 'simulate', '--valve-model', 'C2',
           '--out', '-']
    full = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert full.returncode == 0 and full.stdout.splitlines()[0].startswith('t,com,fr,psr')
    assert len(full.stdout.splitlines()) == 1002 and 'rows -> stdout' in full.stderr
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    proc.stdout.readline()
    proc.stdout.close()                                # the reader goes away (| head -1)
    err = proc.stderr.read().decode()
    assert proc.wait(timeout=300) == 0 and 'Traceback' not in err and 'error' not in err, err


def test_a_ros1_bag_is_named_as_such(tmp_path, capsys):
    ros1 = tmp_path / 'old.bag'
    ros1.write_bytes(b'#ROSBAG V2.0\n' + b'\x00' * 64)
    assert main(['compare', '@paper_HD', str(ros1)]) == 2
    err = capsys.readouterr().err
    assert 'is a ROS 1 bag, not a rosbag2 bag' in err and 'reindex' not in err


def test_a_standalone_plant_that_falls_behind_says_so(ros_context):
    from servovalve_twin.nodes.plant import Plant
    node = Plant(context=ros_context)
    try:
        node._count_overruns(1_000_000_000)
        node._count_overruns(1_001_000_000)            # on time: nothing missed
        assert getattr(node, 'overruns', 0) == 0
        node._count_overruns(1_005_000_000)            # 4 ms later: 3 periods missed
        assert node.overruns == 3
    finally:
        node.destroy_node()


def test_parquet_outputs(tmp_path, monkeypatch):
    import pyarrow.parquet as pq
    from servovalve_twin.runs import read_csv, read_table
    monkeypatch.chdir(tmp_path)
    assert main(['simulate', '--valve-model', 'HD', '--out', 'r.parquet']) == 0
    assert main(['simulate', '--valve-model', 'HD', '--out', 'r.csv']) == 0
    a, b = read_table('r.parquet'), read_csv('r.csv')
    assert list(a) == list(b)
    for k in b:
        np.testing.assert_array_equal(a[k], b[k])            # exact doubles, both ways
    assert main(['compare', 'r.csv', 'r.parquet', '--tolerance', 'xj=0']) == 0
    assert main(['sweep', '--fault', 'null_bias:-0.005', '--nominal', '1', '--workers', '1',
                 '--out', 's']) == 0
    table = pq.read_table(tmp_path / 's' / 'dataset.parquet').to_pydict()
    assert table['fault'] == ['none', 'null_bias'] and table['alarm'] == [0, 1]


def test_ctrl_c_while_a_console_script_starts_is_one_line(monkeypatch, capsys):
    """The executables import rclpy and numba before anything can handle a signal: the entry
    points catch Ctrl-C during that import, and between it and the executable's own handlers
    (one line, no traceback; exit 130 for the command line, 0 for the ROS executables, which
    launch stops with SIGINT), and ignore a second one from then on (it killed the process by
    its signal, -2, in the interpreter's teardown)."""
    import importlib
    import signal
    from types import SimpleNamespace
    from servovalve_twin import entry
    ignored = []
    monkeypatch.setattr(signal, 'signal', lambda sig, how: ignored.append((sig, how)))

    def leave(code):
        raise SystemExit(code)
    monkeypatch.setattr(entry, '_leave', leave)

    def interrupted(*_):
        raise KeyboardInterrupt
    real_import = importlib.import_module
    for when in ('import', 'main'):
        monkeypatch.setattr(importlib, 'import_module', interrupted if when == 'import' else
                            lambda name: SimpleNamespace(**{a: interrupted for a in (
                                'main', 'main_command_generator')}))
        for script in ('cli', 'plant', 'twin', 'player', 'command_generator'):
            if when == 'main' and script == 'cli':
                continue                    # the command line's main handles its own
            ignored.clear()
            with pytest.raises(SystemExit) as stop:
                getattr(entry, script)()
            assert stop.value.code == (130 if script == 'cli' else 0), (when, script)
            assert capsys.readouterr().err == 'interrupted while starting\n'
            assert (signal.SIGINT, signal.SIG_IGN) in ignored
    monkeypatch.setattr(importlib, 'import_module', real_import)


def test_ctrl_c_inside_a_c_extensions_import_is_the_same_one_line(monkeypatch, capsys):
    """A SIGINT while rclpy's C extension initialises comes out of the import as an
    ImportError ('initialization failed', measured at 0.32 s of an ecu start): with a Ctrl-C
    asked it is 'interrupted while starting', exit 0; without one the ImportError stands."""
    import importlib
    import signal
    from servovalve_twin import entry, stopping
    monkeypatch.setattr(signal, 'signal', lambda *a: None)
    monkeypatch.setattr(stopping, '_ASKED', [])

    def leave(code):
        raise SystemExit(code)
    monkeypatch.setattr(entry, '_leave', leave)

    def failing(name):
        raise ImportError('initialization failed')
    monkeypatch.setattr(importlib, 'import_module', failing)
    with pytest.raises(ImportError):
        entry.ecu()
    stopping._ASKED.append(signal.SIGINT)
    with pytest.raises(SystemExit) as stop:
        entry.ecu()
    assert stop.value.code == 0 and capsys.readouterr().err == 'interrupted while starting\n'


def test_characteristic_leaves_points_without_steady_state_blank(tmp_path, capsys,
                                                                monkeypatch):
    """A point where HD finds no steady state is left blank (NaN) and counted; the rest of the
    curve is drawn, the sweep going on from rest. (XS = 0 with a 0.2 nm clearance under a
    forced flow of 4e-5 m^3/s was such a point until HD's start extrapolated the sweep: it
    has one, P12 = -110 MPa, in line with -210 and -310 MPa at twice and three times the
    flow. No HD point fails now, so the failure is made here, at that point.)"""
    import dataclasses
    from servovalve_twin.physics import valves
    from servovalve_twin.physics.valve_state import V_FAIL
    from servovalve_twin.runs import read_csv
    hd = valves.VALVE_MODELS['HD']

    def failing_at_null(xs, qj, psr, P, vs):
        p12 = hd.fn(xs, qj, psr, P, vs)
        if xs == 0.0 and qj == 4e-5:
            vs[V_FAIL] = 1.0
        return p12
    monkeypatch.setitem(valves.VALVE_MODELS, 'HD', dataclasses.replace(hd, fn=failing_at_null))
    assert main(['characteristic', '--valve-model', 'HD', '--param', 'c=2e-10', '--points',
                 '41', '--out', str(tmp_path / 'c.csv'), '--plot', str(tmp_path / 'c.png')]) == 0
    assert '1 of 164 points have no steady state' in capsys.readouterr().out
    curve = read_csv(tmp_path / 'c.csv')
    assert np.isnan(curve['p12']).sum() == 1 and np.isfinite(curve['p12']).sum() == 163
    assert (tmp_path / 'c.png').stat().st_size > 1000


@pytest.mark.ros
def test_run_with_a_monitor_prints_its_verdict(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(['run', '--valve-model', 'HD', '--monitor', 'SQ', '--no-bag']) == 0
    out = capsys.readouterr().out
    assert 'EHA monitor: no WARN, no ERROR; peak health_xj 0.0003279' in out
    (tmp_path / 'leak.yaml').write_text(
        'faults: [{at: 0.1, fault: leakage_growth, severity: 10.0}]\n'
        'com: [[0.0, 0.02], [0.3, 0.03], [0.75, 0.02]]\nfr: [[0.0, 0.0], [0.2, 10400.0]]\n')
    assert main(['run', '--valve-model', 'HD', '--monitor', 'SQ', '--no-bag', '--scenario',
                 'leak.yaml']) == 0
    assert 'EHA monitor: first WARN at 0.' in capsys.readouterr().out


def test_the_launch_file_ends_with_an_essential_node_and_lists_the_registry():
    """launch is not on PyPI: the launch description is checked as source -- the ECU and the
    plant end the launch when they exit, the model choices come from the registry, and every
    executable it starts is a console script of the package."""
    import ast
    tree = ast.parse((ROOT / 'launch' / 'twin.launch.py').read_text())
    nodes = [c for c in ast.walk(tree) if isinstance(c, ast.Call)
             and getattr(c.func, 'id', None) == 'Node']
    kw = [{k.arg: k.value for k in c.keywords} for c in nodes]
    execs = {ast.literal_eval(k['executable']): k for k in kw}
    assert set(execs) == {'clock', 'command_generator', 'load_supply', 'ecu', 'plant',
                          'monitor'}
    for essential in ('ecu', 'plant'):
        on_exit = execs[essential].get('on_exit')
        assert on_exit is not None and on_exit.func.id == 'Shutdown', essential
    setup = (ROOT / 'setup.py').read_text()
    assert all(f"'{e} = servovalve_twin.entry:{e}'" in setup for e in execs)
    assert 'VALVE_MODEL_NAMES' in ast.unparse(tree)
    # several actuators: every node but the clock in the launch's namespace; the clock (the one
    # /clock owner) only when asked; the unit's parameters from the params_file argument
    declared = {ast.literal_eval(c.args[0]) for c in ast.walk(tree) if isinstance(c, ast.Call)
                and getattr(c.func, 'id', None) == 'DeclareLaunchArgument'}
    assert {'namespace', 'params_file', 'clock', 'valve_model'} <= declared
    for name, k in execs.items():
        assert ('namespace' in k) == (name != 'clock'), name
        if 'namespace' in k:
            assert ast.unparse(k['namespace']) == 'namespace'
    assert ast.unparse(execs['clock']['condition']) == "IfCondition(LaunchConfiguration('clock'))"
    for name in ('ecu', 'plant', 'monitor'):
        assert ast.unparse(execs[name]['parameters']).startswith('[params_file,'), name
    assert "params_file = LaunchConfiguration('params_file')" in ast.unparse(tree)


def test_progress_shows_on_a_terminal_only():
    import os
    import pty
    import subprocess
    import sys
    code = ('import time\nfrom servovalve_twin.progress import progress\n'
            'for _ in progress(range(3), desc="sweep", unit="run"): time.sleep(0.01)\n')
    piped = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                           timeout=120)
    assert piped.returncode == 0 and piped.stderr == ''          # quiet when not a terminal
    import fcntl
    import struct
    import termios
    master, slave = pty.openpty()
    fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack('HHHH', 24, 100, 0, 0))   # 100 columns
    proc = subprocess.Popen([sys.executable, '-c', code], stderr=slave, stdout=subprocess.DEVNULL)
    os.close(slave)
    out = b''
    while True:
        try:
            chunk = os.read(master, 4096)
        except OSError:
            break
        if not chunk:
            break
        out += chunk
    assert proc.wait(timeout=120) == 0
    os.close(master)
    assert b'sweep' in out and b'run' in out


@pytest.mark.ros
def test_replay_into_an_existing_directory_needs_overwrite(tmp_path, capsys):
    out = tmp_path / 'r'
    assert main(['replay', '@paper_HD', '--valve-model', 'C2', '--out', str(out)]) == 0
    assert main(['replay', '@paper_HD', '--valve-model', 'C2', '--out', str(out)]) == 2
    assert '--overwrite' in capsys.readouterr().err
    (out / 'mine.txt').write_text('keep')
    assert main(['replay', '@paper_HD', '--valve-model', 'C2', '--out', str(out),
                 '--overwrite']) == 0
    assert (out / 'mine.txt').read_text() == 'keep'


def test_the_command_line_runs_openblas_on_one_thread_unless_told():
    """``servovalve-twin`` sets OpenBLAS to one thread before numpy starts its pool (a thread
    per core, 0.16 s of CPU per process for a fit's few-column matrices); a user's own
    OPENBLAS_NUM_THREADS is kept. Counted as the process's threads after a command ran."""
    import os
    import subprocess
    import sys
    code = '''
import contextlib, io, os, sys
from servovalve_twin import entry
sys.argv = ['servovalve-twin', 'params']
with contextlib.redirect_stdout(io.StringIO()):
    entry.cli()
print(len(os.listdir('/proc/self/task')), os.environ.get('OPENBLAS_NUM_THREADS'))
'''
    env = {k: v for k, v in os.environ.items() if k != 'OPENBLAS_NUM_THREADS'}

    def threads(**extra):
        out = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                             env={**env, **extra}, check=True).stdout.split()
        return int(out[0]), out[1]
    assert threads() == (1, '1')
    if (os.cpu_count() or 1) > 1:
        assert threads(OPENBLAS_NUM_THREADS='2') == (2, '2')
