"""servovalve_twin.outputs: a command's output file is whole or absent -- written beside the
target and renamed -- whatever stops the writing; a symbolic link is never written through."""

import os
import subprocess
import sys

import pytest

from servovalve_twin.cli import main
from servovalve_twin.errors import TwinError
from servovalve_twin.outputs import output_file, place_new
from conftest import ROOT


def test_an_error_midway_leaves_the_old_file_and_no_temporary(tmp_path):
    target = tmp_path / 'run.csv'
    target.write_text('the old content\n')
    with pytest.raises(RuntimeError):
        with output_file(target) as fh:
            fh.write('half of a new')
            raise RuntimeError('the disk is full')
    assert target.read_text() == 'the old content\n'
    assert sorted(p.name for p in tmp_path.iterdir()) == ['run.csv']
    with output_file(target) as fh:
        fh.write('new\n')
    assert target.read_text() == 'new\n' and len(list(tmp_path.iterdir())) == 1


def test_a_full_disk_leaves_no_partial_csv(tmp_path):
    """simulate --out under a file-size limit of 20 kB (the CSV is ~200 kB): one line, exit 2,
    neither the CSV nor a temporary file left."""
    code = ('import resource, signal, sys\n'
            'signal.signal(signal.SIGXFSZ, signal.SIG_IGN)\n'
            'resource.setrlimit(resource.RLIMIT_FSIZE, (20000, 20000))\n'
            'from servovalve_twin.cli import main\n'
            'sys.exit(main(["simulate", "--valve-model", "C2", "--out", "run.csv"]))\n')
    r = subprocess.run([sys.executable, '-c', code], cwd=tmp_path, capture_output=True,
                       text=True, timeout=300, env=dict(os.environ, PYTHONPATH=str(ROOT)))
    print(r.stderr)
    assert r.returncode == 2 and r.stderr.count('\n') == 1 and 'Traceback' not in r.stderr
    assert 'run.csv: the file size limit is reached (nothing of it was written)' in r.stderr
    assert list(tmp_path.iterdir()) == []


_MONITOR = 'servovalve_twin.prognostics.monitor:MonitorAlgorithm'


@pytest.mark.parametrize('argv, left', [
    (['evaluate', '@paper_HD', '--algorithm', _MONITOR, '--json', 'e.json'], []),
    (['sweep', '--fault', 'leakage_growth:5', '--nominal', '1', '--traces', '--workers', '1',
      '--out', 'sw'], []),
    pytest.param(['report', '--out-dir', 'rep'], [], marks=pytest.mark.slow),
    (['fmu', '--valve-model', 'C2', 'x.fmu'], []),
    pytest.param(['run', '--valve-model', 'C2', '--bag', 'b'], ['b', 'b/b_0.mcap'],
                 marks=pytest.mark.ros),
    pytest.param(['replay', '@paper_HD', '--valve-model', 'C2', '--out', 'r'],
                 ['r', 'r/r_0.mcap'], marks=pytest.mark.ros),
], ids=['evaluate', 'sweep', 'report', 'fmu', 'run', 'replay'])
def test_a_full_disk_is_one_line_and_leaves_nothing_partial(tmp_path, argv, left):
    """Each writing command under a 20 kB file-size limit (what a full disk does to a write):
    one line saying so, exit 2, and nothing partial -- no output at all, or a bag's storage
    file with the line naming the command that rebuilds it (never a temporary's name)."""
    code = ('import resource, signal, sys\n'
            'signal.signal(signal.SIGXFSZ, signal.SIG_IGN)\n'
            'resource.setrlimit(resource.RLIMIT_FSIZE, (20000, 20000))\n'
            'from servovalve_twin.cli import main\n'
            f'sys.exit(main({argv!r}))\n')
    r = subprocess.run([sys.executable, '-c', code], cwd=tmp_path, capture_output=True,
                       text=True, timeout=600, env=dict(os.environ, PYTHONPATH=str(ROOT)))
    print(r.stderr)
    assert r.returncode == 2 and r.stderr.count('\n') == 1 and 'Traceback' not in r.stderr
    assert 'the file size limit is reached' in r.stderr and '.part' not in r.stderr
    assert sorted(str(p.relative_to(tmp_path)) for p in tmp_path.rglob('*')) == left
    if left:
        assert f'servovalve-twin reindex {left[0]}' in r.stderr


def test_a_symbolic_link_is_replaced_not_written_through(tmp_path, capsys):
    elsewhere = tmp_path / 'elsewhere'
    elsewhere.mkdir()
    link = tmp_path / 'run.csv'
    link.symlink_to(elsewhere / 'victim.csv')          # dangling: victim.csv does not exist
    assert main(['simulate', '--valve-model', 'C2', '--out', str(link)]) == 0
    assert not link.is_symlink() and link.read_text().startswith('t,com,fr,psr')
    assert list(elsewhere.iterdir()) == []


def test_a_built_file_never_replaces_an_existing_one(tmp_path):
    built = tmp_path / 'built.fmu'
    built.write_bytes(b'new')
    out = tmp_path / 'EHA.fmu'
    out.symlink_to(tmp_path / 'nowhere.fmu')
    with pytest.raises(TwinError, match='exists'):
        place_new(built, out)
    assert not (tmp_path / 'nowhere.fmu').exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ['EHA.fmu', 'built.fmu']
    out.unlink()
    assert place_new(built, out).read_bytes() == b'new'


def test_an_output_gets_the_umasks_permissions(tmp_path):
    """A finished output has the mode a new file gets (0644 under umask 022), as a file the
    user wrote would -- mkstemp's 0600 made every output its owner's alone; the bag's
    metadata.yaml too."""
    from servovalve_twin.bag.writer import write_metadata_yaml
    old = os.umask(0o022)
    try:
        with output_file(tmp_path / 'a.json') as fh:
            fh.write('{}\n')
        write_metadata_yaml(tmp_path, {'version': 9})
        os.umask(0o077)
        with output_file(tmp_path / 'b.json') as fh:
            fh.write('{}\n')
    finally:
        os.umask(old)
    mode = {p.name: p.stat().st_mode & 0o777 for p in tmp_path.iterdir()}
    assert mode == {'a.json': 0o644, 'metadata.yaml': 0o644, 'b.json': 0o600}


def test_an_output_path_that_is_not_a_regular_file_is_refused(tmp_path, capsys):
    """A FIFO, a directory or a device as ``--out``: one line, exit 2, the path left as it was
    (a rename onto it replaced a FIFO with a regular file, and as root /dev/full with a CSV);
    the library's writers refuse it before writing anything."""
    import stat
    fifo = tmp_path / 'p.csv'
    os.mkfifo(fifo)
    assert main(['simulate', '--valve-model', 'C2', '--scenario', 'paper',
                 '--out', str(fifo)]) == 2
    err = capsys.readouterr().err
    assert 'is a FIFO' in err and len(err.strip().splitlines()) == 1
    assert stat.S_ISFIFO(os.lstat(fifo).st_mode)
    assert sorted(p.name for p in tmp_path.iterdir()) == ['p.csv']
    for path, kind in ((tmp_path, 'a directory'), (os.devnull, 'a character device')):
        with pytest.raises(TwinError, match=kind):
            with output_file(path) as fh:
                fh.write('x')
    assert stat.S_ISCHR(os.lstat(os.devnull).st_mode)


def test_write_json_writes_nan_and_infinities_as_null(tmp_path):
    """JSON has no NaN or infinity: json.dumps would write the non-standard NaN/Infinity that
    strict readers refuse; write_json writes null, nested in dicts, lists and tuples."""
    import json
    import math
    from servovalve_twin.outputs import write_json
    path = tmp_path / 'x.json'
    write_json(path, {'a': math.nan, 'b': [math.inf, 1.5, (-math.inf, 2)], 'c': {'d': 3}})
    text = path.read_text()
    assert 'NaN' not in text and 'Infinity' not in text
    assert json.loads(text) == {'a': None, 'b': [None, 1.5, [None, 2]], 'c': {'d': 3}}
