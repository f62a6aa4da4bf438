"""Seeded random mutations of real files through the loaders that read what others wrote: the
bag reader (MCAP and sqlite3 storage files, ``metadata.yaml``) and the scenario loader. Each
mutated file must give one error line and exit code 2, or a correct result -- for a bag, the
table of the intact bag (MCAP's CRCs leave nothing else possible; sqlite3, which has none, may
read a changed value, never a changed shape) -- and never a traceback or another exception."""

from __future__ import annotations

import shutil

import numpy as np
import pytest

from bagmaker import reference_messages, write_bag
from servovalve_twin.bag.reader import read_bag
from servovalve_twin.cli import main
from servovalve_twin.config import load_scenario
from servovalve_twin.errors import BagError, TwinError

pytestmark = pytest.mark.slow

END_NS = 60_000_000
TRIALS = 150


@pytest.fixture(scope='module')
def intact(tmp_path_factory):
    """The packaged HD bag's first 60 ms, as an MCAP (zstd) and a sqlite3 bag with the
    twin's provenance, and each one's table."""
    msgs, record = reference_messages(END_NS)
    assert record                                   # the twin's provenance, tick grid checked
    root = tmp_path_factory.mktemp('intact')
    out = {}
    for storage, kw in (('mcap', dict(compression='zstd')), ('sqlite3', {})):
        write_bag(root / storage, storage=storage, msgs=msgs, provenance=record, **kw)
        out[storage] = (root / storage, read_bag(root / storage).signals)
    return out


def _mutate(data: bytes, rng: np.random.Generator) -> bytes:
    """One of: 1-8 bytes flipped, the file cut short, a span zeroed, a span repeated."""
    b = bytearray(data)
    kind = rng.integers(4)
    if kind == 0:
        for i in rng.integers(0, len(b), rng.integers(1, 9)):
            b[i] ^= int(rng.integers(1, 256))
    elif kind == 1:
        del b[int(rng.integers(0, len(b))):]
    else:
        i = int(rng.integers(0, len(b)))
        n = int(rng.integers(1, 257))
        b[i:i + n] = bytes(len(b[i:i + n])) if kind == 2 else b[i:i + n] * 2
    return bytes(b)


def _same_shape(got, want, exact: bool) -> None:
    assert list(got) == list(want)
    for k in want:
        assert got[k].shape == want[k].shape, k
        if exact or k == 't':
            np.testing.assert_array_equal(got[k], want[k])


def _read_right_or_refused(path, table, exact: bool) -> None:
    """The table builder on every topic (evaluate reads only its inputs'): a BagError, or
    the intact table."""
    try:
        got = read_bag(path).signals
    except BagError:
        return
    _same_shape(got, table, exact)


def _outcome(path, capsys) -> int:
    """The one-line contract of a bag-taking command: 0, or 2 with one line."""
    rc = main(['evaluate', str(path), '--algorithm',
               'servovalve_twin.prognostics.monitor:MonitorAlgorithm'])
    err = capsys.readouterr().err
    assert rc in (0, 2), err
    if rc == 2:
        assert err.count('\n') == 1 and 'Traceback' not in err, err
    return rc


@pytest.mark.parametrize('storage', ['mcap', 'sqlite3'])
def test_a_mutated_storage_file_is_refused_in_one_line_or_read_right(intact, tmp_path, capsys,
                                                                      storage):
    bag, table = intact[storage]
    (f,) = bag.glob('*.mcap' if storage == 'mcap' else '*.db3')
    data = f.read_bytes()
    rng = np.random.default_rng(1234 if storage == 'mcap' else 4321)
    outcomes = {0: 0, 2: 0}
    for trial in range(TRIALS):
        d = tmp_path / f'{trial}'
        shutil.copytree(bag, d)
        (d / f.name).write_bytes(_mutate(data, rng))
        outcomes[_outcome(d, capsys)] += 1
        _read_right_or_refused(d, table, exact=storage == 'mcap')
        shutil.rmtree(d)
    print(f'{storage}: {outcomes[2]} refused in one line, {outcomes[0]} read right')
    assert outcomes[2] >= TRIALS // 2        # the mutations do damage: most are refused


@pytest.mark.parametrize('storage', ['mcap', 'sqlite3'])
def test_a_mutated_metadata_file_is_refused_in_one_line_or_read_right(intact, tmp_path, capsys,
                                                                      storage):
    bag, table = intact[storage]
    text = (bag / 'metadata.yaml').read_bytes()
    rng = np.random.default_rng(99)
    outcomes = {0: 0, 2: 0}
    for trial in range(TRIALS):
        d = tmp_path / f'{trial}'
        shutil.copytree(bag, d)
        (d / 'metadata.yaml').write_bytes(_mutate(text, rng))
        outcomes[_outcome(d, capsys)] += 1
        # metadata describes the bag; what is read comes from the storage files
        _read_right_or_refused(d, table, exact=True)
        shutil.rmtree(d)
    print(f'{storage} metadata.yaml: {outcomes[2]} refused in one line, {outcomes[0]} read right')


def test_a_mutated_scenario_file_is_refused_in_one_line_or_loaded_valid(tmp_path, capsys):
    """A scenario is the other file users hand over: a mutated paper.yaml loads as a valid
    scenario (every schedule within its bounds) or is one ScenarioError line through
    ``simulate``."""
    from servovalve_twin.config import builtin_scenarios
    text = builtin_scenarios()['paper'].read_bytes()
    rng = np.random.default_rng(7)
    loaded = refused = 0
    for trial in range(4 * TRIALS):
        f = tmp_path / f's{trial}.yaml'
        f.write_bytes(_mutate(text, rng))
        try:
            scn = load_scenario(f)
        except TwinError:
            refused += 1
            continue
        loaded += 1
        assert 0 < scn.duration <= 3600 and scn.name
        load_scenario(scn.to_dict())                         # what it holds is valid again
    # through the command line: the one-line contract on a few of them
    for trial in range(0, 4 * TRIALS, 16):
        rc = main(['simulate', '--valve-model', 'C2', '--scenario', str(tmp_path /
                                                                        f's{trial}.yaml'),
                   '--out', str(tmp_path / f'o{trial}.csv')])
        err = capsys.readouterr().err
        assert rc in (0, 2) and 'Traceback' not in err
        assert rc == 0 or (err.count('\n') == 1 and not (tmp_path / f'o{trial}.csv').exists())
    print(f'scenarios: {refused} refused, {loaded} loaded valid')
    assert refused and loaded
