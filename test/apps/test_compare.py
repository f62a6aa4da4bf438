"""servovalve_twin.apps.compare: two bags compared block by block give the errors a hand
computation gives (a known offset), the whole-array path's counts and maxima, its windows (from
the provenance or, for a foreign bag, from the inputs), and refuse runs with other inputs."""

from __future__ import annotations

import struct

import pytest

from bagmaker import f64, reference_messages, write_bag, write_long_bag
from servovalve_twin.apps.compare import compare_bags, error_metrics
from servovalve_twin.apps.windows import bag_windows, load_run
from servovalve_twin.bag import reader
from servovalve_twin.errors import TwinError

END_NS = 400_000_000
OFFSET = {'/xj': 1e-6, '/p12': 250.0}


def _bags(tmp_path, provenance=True, change=None):
    """The packaged run cut to 0.4 s, and a copy whose /xj and /p12 carry a known offset
    (``change``: a topic whose value is also changed from 0.2 s on)."""
    msgs, record = reference_messages(END_NS)
    out = []
    for t, typ, ns, d in msgs:
        if t in OFFSET:
            d = f64(struct.unpack('<d', d[4:12])[0] + OFFSET[t])
        if t == change and ns >= 200_000_000:
            d = f64(struct.unpack('<d', d[4:12])[0] + 1.0)
        out.append((t, typ, ns, d))
    # the run also carries an algorithm's output every tick: its blocks end elsewhere than
    # the reference's, so rows wait for the other side across block seams
    out += [('/health/score', 'std_msgs/msg/Float64', ns, f64(0.0))
            for t, _, ns, _ in msgs if t == '/xj']
    out.sort(key=lambda m: m[2])
    rec = record if provenance else None
    write_bag(tmp_path / 'ref', msgs=msgs, provenance=rec)
    write_bag(tmp_path / 'run', msgs=out, provenance=rec)
    return tmp_path / 'ref', tmp_path / 'run'


@pytest.mark.parametrize('provenance', [True, False])
def test_two_bags_compared_in_blocks(tmp_path, monkeypatch, provenance):
    """In blocks of 300 messages: the offset comes back as every window's RMS and max error
    (hand value), XS and DXJ with none; counts and maxima equal the whole-array path's, the
    RMS within rounding; the windows are load_run's (the scenario's, or the inputs' steps)."""
    ref, run = _bags(tmp_path, provenance)
    monkeypatch.setattr(reader, 'BLOCK_MESSAGES', 300)
    a, windows = load_run(ref)
    b, _ = load_run(run)
    assert bag_windows(ref) == windows and len(windows) >= 3
    got = compare_bags(ref, run, windows)
    want = error_metrics(a, b, windows)
    assert list(got) == list(want)
    for w, row in want.items():
        assert list(got[w]) == list(row)
        for sig, m in row.items():
            assert got[w][sig]['n'] == m['n'] and got[w][sig]['max'] == m['max'], (w, sig)
            assert got[w][sig]['rms'] == pytest.approx(m['rms'], rel=1e-12, abs=1e-300)
        if row:                         # (a phase of the scenario after the cut: none)
            assert got[w]['xj']['rms'] == pytest.approx(1e-6, rel=1e-9)
            assert got[w]['p12']['max'] == pytest.approx(250.0, rel=1e-9)
            assert got[w]['xs']['max'] == 0.0
    assert got['all']['xj']['n'] == 401 and sum(1 for r in got.values() if r) >= 3


def test_a_window_ending_at_the_end_holds_the_last_row(tmp_path, monkeypatch):
    """[t0, t1) except the window that ends at the last row, which holds it: 100 rows from
    0.1 to 0.2 s, 101 from 0.3 s to the end (0.4 s)."""
    ref, run = _bags(tmp_path)
    monkeypatch.setattr(reader, 'BLOCK_MESSAGES', 250)
    got = compare_bags(ref, run, {'mid': (0.1, 0.2), 'tail': (0.3, 0.4)})
    assert got['mid']['xj']['n'] == 100 and got['tail']['xj']['n'] == 101


def test_runs_with_other_inputs_are_refused(tmp_path, monkeypatch):
    ref, run = _bags(tmp_path, change='/fr')
    monkeypatch.setattr(reader, 'BLOCK_MESSAGES', 300)
    with pytest.raises(TwinError, match=r'fr differs at t = 0\.200 s'):
        compare_bags(ref, run, {})


@pytest.mark.slow
def test_memory_does_not_grow_with_the_bags(tmp_path, monkeypatch):
    """Two bags of 4 and of 16 s (48 k and 194 k messages) compared with themselves in blocks
    of 5 000 messages: the peak of Python allocations (tracemalloc) the same within 1.5 MiB
    (what is read in blocks of 1 MiB, the CRCs' and the blocks' own) -- where holding the rows
    (~5 MB more) or the mcap library's summary (an object per 512-byte chunk: 32 MB more)
    grew it. A first compare warms the process up (imports, caches)."""
    import tracemalloc
    monkeypatch.setattr(reader, 'BLOCK_MESSAGES', 5000)
    peaks = []
    bags = {s: write_long_bag(tmp_path / f'b{s}', s) for s in (4, 16)}
    compare_bags(bags[4], bags[4], {})
    for s, bag in bags.items():
        tracemalloc.start()
        got = compare_bags(bag, bag, {})
        peaks.append(tracemalloc.get_traced_memory()[1])
        tracemalloc.stop()
        assert got['all']['xj']['n'] == 1001 * s and got['all']['xj']['max'] == 0.0
    assert peaks[1] - peaks[0] < 1.5 * (1 << 20), peaks


def test_the_figure_of_a_short_run_has_every_row(tmp_path, monkeypatch):
    from servovalve_twin.apps.compare import PlotRows
    monkeypatch.setattr(reader, 'BLOCK_MESSAGES', 500)
    ref, run = _bags(tmp_path)
    rows = PlotRows(400)
    compare_bags(ref, run, {}, plot=rows)
    a, b = rows.runs()
    whole_a, whole_b = reader.read_bag(ref).signals, reader.read_bag(run).signals
    for got, want in ((a, whole_a), (b, whole_b)):
        assert set(got) == set(want)
        for c, v in want.items():
            assert got[c].tolist() == v.tolist(), c


def test_the_figure_of_a_long_run_keeps_each_bins_extremes(tmp_path, monkeypatch):
    """Rows beyond the figure's budget: per bin of ms, each column's minimum at the bin's first
    row and maximum at its last, as a hand computation over the whole table gives -- with
    block seams (every 700 messages) inside bins."""
    import numpy as np
    from servovalve_twin.apps.compare import PlotRows
    monkeypatch.setattr(reader, 'BLOCK_MESSAGES', 700)
    bag = write_long_bag(tmp_path / 'b', 2)                 # ticks 0..2001 ms, a seam at 1 s
    rows = PlotRows(2001, max_rows=100)                     # 49 bins of 41 ms
    assert rows.bin_ms == 41
    compare_bags(bag, bag, {}, plot=rows)
    a, b = rows.runs()
    whole = reader.read_bag(bag).signals
    ms = np.rint(whole['t'] * 1000).astype(np.int64)
    bins = ms // 41
    want_t, want = [], {c: [] for c in whole if c != 't'}
    for k in np.unique(bins):
        sel = bins == k
        want_t += [ms[sel][0] * 1e-3, ms[sel][-1] * 1e-3]
        for c in want:
            want[c] += [np.nanmin(whole[c][sel]), np.nanmax(whole[c][sel])]
    assert a['t'].tolist() == want_t and len(want_t) == 2 * 49
    for c, v in want.items():
        assert a[c].tolist() == v and b[c].tolist() == v, c


def test_a_run_that_covers_half_the_reference_says_so(tmp_path, capsys):
    """A run cut to its first half against the whole: a warning line with the rows covered,
    the JSON's coverage, and --tolerance failing on it even where every error is 0 (rc 0,
    'all 0 / 0' before: no word that half the reference was not compared)."""
    import json
    from servovalve_twin.cli import main
    full = tmp_path / 'full.csv'
    assert main(['simulate', '--valve-model', 'C2', '--scenario', 'paper',
                 '--out', str(full)]) == 0
    lines = full.read_text().splitlines(keepends=True)
    half = tmp_path / 'half.csv'
    half.write_text(''.join(lines[:1 + 501]))           # header + rows 0 .. 500 ms
    capsys.readouterr()
    out = tmp_path / 'c.json'
    rc = main(['compare', str(full), str(half), '--json', str(out), '--tolerance', 'xj=1e-9'])
    cap = capsys.readouterr()
    assert "covers 501 of the reference's 1001 1 ms rows (50.0%)" in cap.err
    assert rc == 1 and 'tolerance exceeded: the run covers 501' in cap.out
    cov = json.loads(out.read_text())['coverage']
    assert cov == dict(common_rows=501, reference_rows=1001, fraction=501 / 1001)
    assert main(['compare', str(full), str(full), '--tolerance', 'xj=1e-9']) == 0
    assert 'covers' not in capsys.readouterr().err


def test_a_table_against_a_bag_names_the_ecu_and_phases_are_not_windows_twice(tmp_path,
                                                                              capsys):
    """A simulate table carries no ECU period: compared with the 1 ms bag, one warning says
    how to compare like with like; the paper's phases, each one of its named windows, are
    not printed a second time as phase1..phase6."""
    from servovalve_twin.apps.windows import run_windows
    from servovalve_twin.cli import main
    from servovalve_twin.config import resolve_bag
    out = tmp_path / 'run.csv'
    assert main(['simulate', '--valve-model', 'C2', '--out', str(out)]) == 0
    capsys.readouterr()
    assert main(['compare', '@paper_HD', str(out)]) == 0
    got = capsys.readouterr()
    assert 'records no ECU period' in got.err and '--ecu-period 0.001' in got.err
    assert 'phase' not in got.out and 'overstall' in got.out
    windows = run_windows(resolve_bag('@paper_HD'))
    assert not [k for k in windows if k.startswith('phase')]
    assert windows['run1'] == (0.0, 0.2)
