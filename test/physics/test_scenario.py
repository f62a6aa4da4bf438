"""Scenario loading: the paper scenario, defaults, every feature, and rejected input."""

import numpy as np
import pytest

from servovalve_twin.errors import ScenarioError
from servovalve_twin.config import builtin_scenarios, load_scenario
from servovalve_twin.runs import simulate


def test_paper_scenario_is_models_md_section_6():
    s = load_scenario('paper')
    t = np.array([0, 0.1999, 0.2, 0.3, 0.35, 0.45, 0.75, 1.0])
    t_ns = np.rint(t * 1e9).astype(np.int64)
    com, fr, psr = s.inputs(t_ns)
    assert list(com) == [0.02, 0.02, 0.02, 0.03, 0.03, 0.03, 0.02, 0.02]
    assert list(fr) == [0, 0, 10400, 10400, 10400, 10400, 10400, 10400]
    assert list(psr) == [20e6, 20e6, 20e6, 20e6, 12e6, 20e6, 20e6, 20e6]
    assert s.duration == 1.0
    assert s.windows['overstall'] == (0.35, 0.50)
    assert s.phases()[0] == (0.0, 0.2) and len(s.phases()) == 6


def test_breakpoint_applies_from_integer_nanoseconds():
    # 0.35/1e-5 is not an integer in floating point: the step starting at 35000*DT must see it
    s = load_scenario('paper')
    t_ns = np.arange(34999, 35002, dtype=np.int64) * 10_000
    assert list(s.psr.values(t_ns)) == [20e6, 12e6, 12e6]


@pytest.mark.parametrize('name', sorted(builtin_scenarios()))
def test_builtin_scenarios_load_and_run(name):
    r = simulate('C2', name)
    assert np.all(np.isfinite(r['xj']))
    print(name, 'final XJ', r['xj'][-1])


def test_schema_of_the_issue_loads(tmp_path):
    f = tmp_path / 's.yaml'
    f.write_text('duration: 1.0\ncom: [[0.0, 0.02], [0.30, 0.03], [0.75, 0.02]]\n'
                 'fr:  [[0.0, 0.0], [0.20, 10400.0]]\n'
                 'psr: [[0.0, 20.0e6], [0.35, 12.0e6], [0.45, 20.0e6]]\n')
    s = load_scenario(f)
    assert s.psr.points[1] == (0.35, 12.0e6)     # 12.0e6 (a YAML 1.1 string) became a number


def test_ramp_and_sine():
    s = load_scenario({'duration': 1.0, 'com': {'ramp': [[0, 0], [0.5, 1.0]]},
                       'fr': {'sine': {'offset': 1.0, 'amplitude': 2.0, 'frequency': 1.0,
                                       'start': 0.25}}})
    t_ns = np.rint(np.array([0.0, 0.25, 0.5, 0.75]) * 1e9).astype(np.int64)
    assert np.allclose(s.com.values(t_ns), [0, 0.5, 1.0, 1.0])
    assert np.allclose(s.fr.values(t_ns), [1.0, 1.0, 3.0, 1.0], atol=1e-12)


@pytest.mark.parametrize('raw,fragment', [
    ({'duratoin': 1.0}, "unknown scenario key 'duratoin'"),
    ({'com': [[0.1, 0.0]]}, 'first breakpoint must be at t = 0'),
    ({'com': [[0.0, 0.0], [0.5, 'x']]}, 'expected a number'),
    ({'com': [[0.0, 0.0], [0.5, 1.0], [0.4, 0.0]]},
     'must increase strictly, got 0.5 then 0.4 (breakpoints 1 and 2)'),
    # (a bag's provenance may carry any scenario: 10^6 breakpoints took over 90 s)
    ({'duration': 3600.0, 'com': [[i * 1e-3, 0.0] for i in range(100_001)]},
     '100001 breakpoints; at most 100000'),
    ({'duration': 0.5, 'com': [[0.0, 0.0], [0.6, 1.0]]}, 'after the duration'),
    ({'duration': 0.0005}, 'whole number of milliseconds'),
    ({'fr': {'sawtooth': []}}, 'expected a list'),
    ({'psr': {'sine': {'offset': 1.0, 'freq': 2.0}}}, "unknown key 'freq'"),
    ({'params': {'M': -5.0}}, 'scenario.params: parameter M'),
    ({'com': [[0.0, float('nan')]]}, 'finite'),
])
def test_bad_scenarios_rejected(raw, fragment):
    with pytest.raises(ScenarioError) as err:
        load_scenario(raw)
    assert fragment in str(err.value)


def test_unknown_scenario_name():
    with pytest.raises(ScenarioError, match="unknown scenario 'papr'"):
        load_scenario('papr')


def test_builtin_scenario_parsed_once_but_never_shared():
    """Built-in scenarios are parsed once per process (YAML was most of a short simulate());
    each load still gets its own data: a caller changing its copy changes no later load."""
    from servovalve_twin.config import load_scenario
    first = load_scenario('paper')
    first.params['M'] = 1.0
    first.windows.clear()
    again = load_scenario('paper')
    assert 'M' not in again.params and again.windows
    assert again == load_scenario('paper')


def test_numpy_numbers_in_a_scenario_become_plain_numbers():
    """A scenario built in Python with numpy times (np.arange) goes into a bag's YAML
    provenance: its fault entries must hold Python numbers, or the bag writer's YAML dump
    fails mid-run."""
    import yaml
    from servovalve_twin.physics.scenario import scenario_from_dict
    scn = scenario_from_dict({'duration': 0.1, 'faults': [
        {'at': np.float64(0.05), 'fault': 'leakage_growth', 'severity': np.float64(3.0)}]})
    entry = scn.to_dict()['faults'][0]
    assert type(entry['at']) is float and type(entry['severity']) is float
    assert yaml.safe_load(yaml.safe_dump(scn.to_dict()))['faults'][0]['at'] == 0.05


@pytest.mark.parametrize('n_points', [5, 300])
def test_steps_in_chunks_equal_a_per_sample_lookup(n_points):
    """A steps signal evaluated window by window (as simulate() does, chunk after chunk, each
    looking up only its own breakpoints) equals an independent per-sample lookup: the value of
    the last breakpoint at or before t. Windows that start on, just before and just after a
    breakpoint, and windows with no breakpoint inside, are all covered; a window that took the
    run's first value instead of the one in force at its start, or dropped its last
    breakpoint, differs."""
    from servovalve_twin.physics.scenario import Profile
    rng = np.random.default_rng(3)
    times = np.concatenate([[0], np.sort(rng.choice(np.arange(1, 10_000), n_points - 1,
                                                    replace=False))]) * 1e-4
    values = rng.normal(size=n_points)
    prof = Profile('steps', tuple(zip(times.tolist(), values.tolist())))
    t_ns = np.arange(0, 1_000_000_000, 10_000, dtype=np.int64)     # 1 s at 10 us
    bp_ns = np.array([int(round(t * 1e9)) for t in times])
    want = np.array([values[np.searchsorted(bp_ns, t, side='right') - 1] for t in t_ns])
    for chunk in (1, 7, 997, 100_000):
        got = np.concatenate([prof.values(t_ns[a:a + chunk])
                              for a in range(0, t_ns.shape[0], chunk)])
        np.testing.assert_array_equal(got, want, err_msg=f'chunk {chunk}')


def test_a_builtin_scenario_is_parsed_once_yet_each_caller_owns_its_copy(tmp_path, monkeypatch):
    """Built-in scenarios are read and validated once per file state: a caller's changes to
    what it got stay its own, a file changed in place or added to the folder is read again."""
    import os
    import shutil
    from servovalve_twin import config
    folder = tmp_path / 'scenarios'
    folder.mkdir()
    src = config.config_dir() / 'scenarios'
    shutil.copy(src / 'paper.yaml', folder / 'paper.yaml')
    monkeypatch.setattr(config, 'config_dir', lambda: tmp_path)
    a = load_scenario('paper')
    a.params['M'] = 99.0
    a.windows['mine'] = (0.0, 0.1)
    b = load_scenario('paper')
    assert b == load_scenario(src / 'paper.yaml') and 'M' not in b.params
    assert 'mine' not in b.windows
    # a changed file: its new content (the modification time moved on, the size too)
    text = (folder / 'paper.yaml').read_text()
    (folder / 'paper.yaml').write_text(text + '\nparams: {M: 42.0}\n')
    st = os.stat(folder / 'paper.yaml')
    os.utime(folder / 'paper.yaml', ns=(st.st_atime_ns, st.st_mtime_ns + 10**9))
    assert load_scenario('paper').params == {'M': 42.0}
    # a file added to the folder is a built-in name at once
    with pytest.raises(ScenarioError, match='unknown scenario'):
        load_scenario('extra')
    shutil.copy(src / 'paper.yaml', folder / 'extra.yaml')
    dst = os.stat(folder)
    os.utime(folder, ns=(dst.st_atime_ns, dst.st_mtime_ns + 10**9))
    assert load_scenario('extra').com == b.com
    assert set(config.builtin_scenarios()) == {'paper', 'extra'}


def test_a_profile_keeps_the_grids_asked_for_again_and_no_more():
    """Profile.grid: the values on a time grid (those of values() at those instants). Asked
    for once, a grid is computed into the caller's buffer and not kept (a scenario run once
    must not pay for fresh arrays); asked for again, it is kept and handed out while among
    the last GRID_CACHE grids; an older one is dropped (a long run's chunks must not pile
    up)."""
    from servovalve_twin.physics.scenario import GRID_CACHE, GridBuffers, scenario_from_dict
    s = scenario_from_dict(load_scenario('paper').to_dict())     # profiles of its own
    t_ns = np.arange(50_000, dtype=np.int64) * 10_000
    want = s.psr.values(t_ns)
    assert want[34_999] == 20e6 and want[35_000] == 12e6      # MODELS.md section 9
    buffers = GridBuffers(50_000)
    once = s.psr.grid(0, 10_000, 50_000, buffers)
    assert np.array_equal(once, want) and np.shares_memory(once, buffers.values(0))
    kept = s.psr.grid(0, 10_000, 50_000, buffers)
    assert np.array_equal(kept, want) and not np.shares_memory(kept, once)
    assert s.psr.grid(0, 10_000, 50_000, buffers) is kept
    shifted = s.psr.grid(10_000, 10_000, 50_000, buffers)        # another grid, same buffers
    assert np.array_equal(shifted, s.psr.values(t_ns + 10_000))
    assert np.array_equal(kept, want)                             # the kept one untouched
    for k in range(GRID_CACHE):
        s.psr.grid(k, 10_000, 10)
        s.psr.grid(k, 10_000, 10)
    assert len(s.psr.__dict__['_grids'][0]) == GRID_CACHE
    assert s.psr.grid(0, 10_000, 50_000) is not kept                # dropped, made afresh
