"""The step loops compiled ahead of time (servovalve_twin.aot) against the JIT's: the same bytes
out, used only for the physics they were built from."""

from __future__ import annotations

import importlib
import sys
from pathlib import Path

import pytest

from servovalve_twin import aot, jitcache
from servovalve_twin.config import load_scenario
from servovalve_twin.physics.fleet import simulate_many
from servovalve_twin.physics.params import DEFAULTS
from servovalve_twin.physics.scenario import scenario_from_dict
from servovalve_twin.physics.valves import get_valve_model
from servovalve_twin.runs import simulate

MODELS = ('C2', 'SQ', 'HD')


@pytest.fixture(scope='module')
def built(tmp_path_factory):
    """A module of three models' loops, built apart from the package's."""
    dest = tmp_path_factory.mktemp('aot')
    aot.build(dest, [get_valve_model(m).id for m in MODELS])
    sys.path.insert(0, str(dest))
    try:
        yield importlib.import_module(aot.module_name())
    finally:
        sys.path.remove(str(dest))


@pytest.mark.slow
@pytest.mark.parametrize('model', MODELS)
def test_the_compiled_loops_give_the_jits_bytes(built, model, monkeypatch):
    """Every signal (and with sensors every truth column) of the paper flight, with a
    continuous ECU, the twin's 1 ms ECU and noisy sensors: the compiled loop's equal the
    JIT's bit for bit -- and the compiled loop is the one that ran."""
    paper = load_scenario('paper')
    noisy = scenario_from_dict(dict(paper.to_dict(), sensors=dict(
        seed=5, xj=dict(noise=1e-5, bias=2e-6), p12=dict(noise=5e4, period=0.002))))
    used = []

    def compiled(kind, model_id, sensed=False):
        used.append((kind, model_id, sensed))
        return getattr(built, aot.export_name(kind, model_id, sensed))

    for scn, ecu in ((paper, None), (paper, 1e-3), (noisy, 1e-3)):
        monkeypatch.setattr(jitcache, 'aot_loop', lambda *a, **k: None)
        want = simulate(model, scn, ecu_period=ecu)
        monkeypatch.setattr(jitcache, 'aot_loop', compiled)
        got = simulate(model, scn, ecu_period=ecu)
        for name in want.signals:
            assert got.signals[name].tobytes() == want.signals[name].tobytes(), name
        for name in want.truth:
            assert got.truth[name].tobytes() == want.truth[name].tobytes(), name
    # a fleet of three units of their own (parameters, a fault from 0.4 s)
    units = [DEFAULTS, DEFAULTS.replace(M=1.1 * DEFAULTS.M), DEFAULTS.replace(CJ=0.8 * DEFAULTS.CJ)]
    faults = [(), (dict(at=0.4, fault='leakage_growth', severity=3.0),), ()]
    monkeypatch.setattr(jitcache, 'aot_loop', lambda *a, **k: None)
    want = simulate_many(model, paper, units, ecu_period=1e-3, faults=faults)
    monkeypatch.setattr(jitcache, 'aot_loop', compiled)
    got = simulate_many(model, paper, units, ecu_period=1e-3, faults=faults)
    for a, b in zip(want, got):
        for name in a.signals:
            assert b.signals[name].tobytes() == a.signals[name].tobytes(), name
    mid = get_valve_model(model).id
    assert used == [('steps', mid, False), ('steps', mid, False), ('steps', mid, True),
                    ('fleet', mid, False)]


@pytest.mark.slow
@pytest.mark.parametrize('model', MODELS)
def test_the_compiled_tick_and_monitor_give_the_jits_bytes(built, model, monkeypatch):
    """The ROS plant's tick (200 control periods of a swinging current, a load from the 100th)
    and the monitor's rows (the monitor of this model -- SQ for HD -- over the packaged HD
    flight): the compiled functions' outputs equal the JIT's bit for bit, and ran."""
    import numpy as np
    from servovalve_twin.physics.simulate import EhaPlant
    from servovalve_twin.prognostics.monitor import monitor_run
    from servovalve_twin.runs import simulate as run
    used = []

    def compiled(kind, model_id, sensed=False):
        used.append(kind)
        return getattr(built, aot.export_name(kind, model_id, sensed))

    def ticks():
        plant = EhaPlant(model)
        rows = []
        for k in range(200):
            cor = 0.004 * np.sin(k / 20.0)
            rows.append(plant.tick(cor, 2000.0 * (k > 100), 2e7, 100).copy())
            rows.append(plant.s.copy())
        return np.concatenate(rows)

    hd = run('HD', 'paper', ecu_period=1e-3)
    monitor = model if model != 'HD' else 'SQ'      # (HD is no monitor model)
    monkeypatch.setattr(jitcache, 'aot_loop', lambda *a, **k: None)
    want_tick, want_mon = ticks(), monitor_run(hd, monitor)
    monkeypatch.setattr(jitcache, 'aot_loop', compiled)
    got_tick, got_mon = ticks(), monitor_run(hd, monitor)
    assert got_tick.tobytes() == want_tick.tobytes()
    for name in want_mon.indicators:
        assert got_mon.indicators[name].tobytes() == want_mon.indicators[name].tobytes()
        assert got_mon.residuals[name].tobytes() == want_mon.residuals[name].tobytes()
    assert got_mon.level.tobytes() == want_mon.level.tobytes()
    assert 'tick' in used and 'monitor' in used


def test_a_module_of_other_physics_or_the_jit_asked_for_is_not_used(monkeypatch):
    """The module is named after the physics stamp: after an edit of the physics (another
    stamp) its loops are not those of the source any more and must not be loaded; nor on
    another processor (compiled for this one's instructions); nor with SERVOVALVE_TWIN_JIT
    set."""
    name = aot.module_name()
    monkeypatch.setattr(jitcache, 'physics_stamp', lambda: b'\x01' * 32)
    assert aot.module_name() != name and aot.module_name().startswith(aot.PREFIX)
    aot._module.cache_clear()
    assert aot.aot_loop('steps', get_valve_model('C2').id) is None
    monkeypatch.undo()
    if aot.cpu_tag():
        assert name.endswith('_' + aot.cpu_tag())
        monkeypatch.setattr(jitcache, 'cpu_tag', lambda: 'ffffffff')
        assert aot.module_name() != name
        aot._module.cache_clear()
        assert aot.aot_loop('steps', get_valve_model('C2').id) is None
        monkeypatch.undo()
    monkeypatch.setenv('SERVOVALVE_TWIN_JIT', '1')
    aot._module.cache_clear()
    assert aot.aot_loop('steps', get_valve_model('C2').id) is None
    monkeypatch.delenv('SERVOVALVE_TWIN_JIT')
    aot._module.cache_clear()


def test_the_signature_is_the_one_simulate_calls_with(monkeypatch):
    """The compiled loop's argument types are those the JIT's loop is dispatched with by
    simulate() (a mismatch would make the compiled loop refuse the call), with and without
    sensors."""
    from servovalve_twin.physics.plant import jit_run_steps_for
    from servovalve_twin.physics.fleet import jit_run_fleet_for
    monkeypatch.setattr(jitcache, 'aot_loop', lambda *a, **k: None)
    paper = load_scenario('paper')
    noisy = scenario_from_dict(dict(paper.to_dict(), sensors=dict(xj=dict(noise=1e-5))))
    mid = get_valve_model('C2').id
    for scn, sensed in ((paper, False), (noisy, True)):
        simulate('C2', scn, ecu_period=1e-3)
        sigs = jit_run_steps_for(mid, sensed).signatures
        assert sigs and all(tuple(sig) == aot.loop_signature('steps', mid, sensed).args
                            for sig in sigs)
    simulate_many('C2', paper, [DEFAULTS, DEFAULTS], ecu_period=1e-3)
    sigs = jit_run_fleet_for(mid).signatures
    assert sigs and all(tuple(sig) == aot.loop_signature('fleet', mid).args for sig in sigs)


@pytest.mark.slow
def test_a_run_on_the_compiled_loops_imports_no_numba(built):
    """A process that simulates on the compiled loops never imports numba (its import alone
    is ~0.1 s of start-up) and gives the JIT's bytes: a decorator that made its dispatcher at
    import, or a loop still dispatched through the JIT, would import it."""
    import hashlib
    import subprocess
    script = f'''
import hashlib, importlib, sys
sys.path.insert(0, {str(Path(built.__file__).parent)!r})
from servovalve_twin import jitcache
mod = importlib.import_module(jitcache.module_name())
jitcache._module = lambda: mod
from servovalve_twin.runs import simulate
r = simulate('C2', 'paper', ecu_period=1e-3)
print('numba' in sys.modules, hashlib.sha256(r['xj'].tobytes() + r['p12'].tobytes()).hexdigest())
'''
    out = subprocess.run([sys.executable, '-c', script], capture_output=True, text=True,
                         check=True).stdout.split()
    want = simulate('C2', 'paper', ecu_period=1e-3)
    assert out == ['False', hashlib.sha256(want['xj'].tobytes() + want['p12'].tobytes())
                   .hexdigest()]
