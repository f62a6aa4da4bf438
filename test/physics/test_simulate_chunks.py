"""What the speed work must not change, and what makes it fast must hold: simulate()
runs chunk by chunk with the same result as one pass, and its compiled loop is loaded from
numba's disk cache by a second process instead of being compiled again."""

import json
import os
import subprocess
import sys

import numpy as np
import pytest

from servovalve_twin.config import load_scenario
from servovalve_twin.physics import simulate as sim_mod
from servovalve_twin.runs import simulate

# faults at times that are not multiples of any chunk or ECU period, every input kind
SEAMS = dict(load_scenario('one_of_everything').to_dict(), faults=[
    {'at': 0.10001, 'param': 'GAP', 'value': 0.5},
    {'at': 0.1234, 'fault': 'leakage_growth', 'severity': 8.0},
    {'at': 0.2, 'param': 'CorB', 'value': 1e-3}])


@pytest.mark.parametrize('model', ['C4', 'HD'])
@pytest.mark.parametrize('ecu_period', [None, 1e-3])
def test_chunk_seams_do_not_show(monkeypatch, model, ecu_period):
    """Cor held across a chunk boundary, the fault segment in force, the valve state (C4's warm
    start, HD's ports) and the output row index must all carry over: runs cut into chunks of
    997 steps (a prime: the seams fall everywhere) equal the run in one chunk, bit for bit. A
    lost carry (Cor reset to 0, the first parameter row again) changes XJ at the next seam."""
    monkeypatch.setattr(sim_mod, 'CHUNK_STEPS', 1 << 30)
    whole = simulate(model, SEAMS, ecu_period=ecu_period)
    monkeypatch.setattr(sim_mod, 'CHUNK_STEPS', 997)
    cut = simulate(model, SEAMS, ecu_period=ecu_period)
    assert {k: v for k, v in whole.info.items() if k != 'wall_s'} == {
        k: v for k, v in cut.info.items() if k != 'wall_s'}
    for col in whole.columns:
        np.testing.assert_array_equal(cut[col], whole[col], err_msg=col)


def test_fault_applies_from_the_first_step_at_or_after_its_time():
    """A hand-computed case: an event at t = 0.10001 s applies from step ceil(0.10001/DT) =
    10001 (DT = 1e-5); the ECU row at t = 0.1 s (step 10000) still uses the old GAP."""
    from servovalve_twin.physics.params import DEFAULTS
    from servovalve_twin.physics.valves import get_valve_model
    scn = sim_mod.as_scenario(SEAMS)
    _, start = sim_mod._fault_segments(get_valve_model('C2'), scn, DEFAULTS)
    assert start.tolist() == [0, 10001, 12340, 20000]


_PROBE = r'''
import hashlib, json, sys
from servovalve_twin.runs import simulate
from servovalve_twin.physics.plant import jit_run_steps_for as run_steps_for
from servovalve_twin.physics.valves import get_valve_model
r = simulate(sys.argv[1], 'defaults')
loop = run_steps_for(get_valve_model(sys.argv[1]).id, False)    # the loop without sensors
print(json.dumps(dict(hits=sum(loop.stats.cache_hits.values()),
                      misses=sum(loop.stats.cache_misses.values()),
                      p12=hashlib.sha256(r['p12'].tobytes()).hexdigest())))
'''


@pytest.mark.slow
def test_a_second_process_loads_each_models_step_loop_from_the_disk_cache(tmp_path):
    """Each model has its own loop (the id a closure constant, :func:`run_steps_for`): it is
    compiled once and the next process loads it, no cache miss. Run in the order C2, HD, C2,
    HD on one cache directory, so that a cache keyed without the id (the closures share their
    name and code) would hand C2's machine code to HD: each process's P12 must be that of
    this process's own run of the model."""
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / 'numba'), SERVOVALVE_TWIN_JIT='1')
    runs = []
    for model in ('C2', 'HD', 'C2', 'HD'):
        out = subprocess.run([sys.executable, '-c', _PROBE, model], env=env, check=True,
                             capture_output=True, text=True).stdout
        runs.append((model, json.loads(out)))
    for model, run in runs[:2]:
        assert run['misses'] == 1 or run['hits'] == 1, (model, run)
    for model, run in runs[2:]:
        assert (run['hits'], run['misses']) == (1, 0), (model, run)
    import hashlib
    for model, run in runs:
        want = hashlib.sha256(simulate(model, 'defaults')['p12'].tobytes()).hexdigest()
        assert run['p12'] == want, model


def test_physics_stamp_changes_with_any_physics_source(tmp_path, monkeypatch):
    """The cache stamp covers every file the loops inline, not only the loop's own: an edit
    of a valve model alone changes it (numba's own stamp would miss it and load stale code);
    so does an edit of jitcache.py, which holds the compile options."""
    import shutil
    from servovalve_twin import jitcache
    copy = tmp_path / 'physics'
    shutil.copytree(jitcache._PHYSICS_DIR, copy, ignore=shutil.ignore_patterns('__pycache__'))
    monkeypatch.setattr(jitcache, '_PHYSICS_DIR', str(copy))
    jitcache.physics_stamp.cache_clear()
    before = jitcache.physics_stamp()
    (copy / '__pycache__').mkdir(exist_ok=True)
    (copy / '__pycache__' / 'x.nbi').write_bytes(b'not source')
    jitcache.physics_stamp.cache_clear()
    assert jitcache.physics_stamp() == before          # caches themselves do not count
    hd = copy / 'valves' / 'hd.py'
    hd.write_text(hd.read_text() + '\n# edited\n')
    jitcache.physics_stamp.cache_clear()
    after_hd = jitcache.physics_stamp()
    assert after_hd != before
    # the compile options live in jitcache.py: editing them recompiles too
    options = tmp_path / 'jitcache.py'
    options.write_text(open(jitcache._THIS_FILE).read() + '\n# error_model changed\n')
    monkeypatch.setattr(jitcache, '_THIS_FILE', str(options))
    jitcache.physics_stamp.cache_clear()
    assert jitcache.physics_stamp() != after_hd
    monkeypatch.undo()
    jitcache.physics_stamp.cache_clear()


def test_each_loop_has_its_own_cache_files():
    """Every model's loop, its variant with sensors and its fleet loop keep their machine
    code in files of their own: sharing one index, two processes compiling two of them at
    once could give both codes one data file, and the index one loop another's code (numba
    names the data file from the index it read and checks nothing on loading)."""
    from servovalve_twin.physics.fleet import jit_run_fleet_for as run_fleet_for
    from servovalve_twin.physics.plant import jit_run_steps_for as run_steps_for
    from servovalve_twin.physics.valves import VALVE_MODELS
    loops = [run_steps_for(m.id, sensed) for m in VALVE_MODELS.values()
             for sensed in (False, True)] + [run_fleet_for(m.id) for m in VALVE_MODELS.values()]
    names = {d._cache._cache_file._index_name for d in loops}
    assert len(names) == len(loops)
