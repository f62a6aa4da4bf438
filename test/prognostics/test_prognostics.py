"""Prognostics workbench: fault injection, the monitor model, health levels, sweeps."""

import csv
import json

import numpy as np
import pytest

from servovalve_twin.cli import main
from servovalve_twin.errors import ScenarioError, TwinError
from servovalve_twin.physics.faults import FAULTS, resolve
from servovalve_twin.prognostics.monitor import (ERROR, OK, RESIDUALS, WARN, HealthConfig,
                                                 monitor_run)
from servovalve_twin.physics.params import DEFAULTS
from servovalve_twin.config import load_scenario
from servovalve_twin.runs import simulate
from servovalve_twin.prognostics.dataset import write_dataset
from servovalve_twin.prognostics.sweep import make_cases, run_case, run_cases
from cases import PAPER



def faulted(fault, severity, at=0.0, model='HD'):
    return simulate(model, dict(PAPER, faults=[{'at': at, 'fault': fault,
                                                'severity': severity}]), ecu_period=1e-3)


def mean(r, a, b, sig):
    return float(np.mean(r[sig][r.window(a, b)]))


NOMINAL = {}
#: the longest detection delay of the catalog at its documented severities (measured 0.67 s,
#: first-stage flow loss), with margin
MAX_DELAY = 0.75


def nominal():
    if 'hd' not in NOMINAL:
        NOMINAL['hd'] = simulate('HD', 'paper', ecu_period=1e-3)
    return NOMINAL['hd']


# fault -> (measure, expected direction): each fault moves what its physics says it moves
EFFECTS = {
    'leakage_growth': (lambda r: mean(r, 0.25, 0.30, 'xs'), +1),     # opening to hold the load
    'supply_loss': (lambda r: r['dxj'][:200].max(), -1),              # unloaded top speed
    'static_friction': (lambda r: mean(r, 0.30, 0.35, 'dxj'), -1),    # sticks against the load
    'dynamic_friction': (lambda r: r['dxj'][:200].max(), -1),
    'torque_motor_gain_loss': (lambda r: mean(r, 0.05, 0.051, 'xj'), -1),   # slower response
    'null_bias': (lambda r: mean(r, 0.15, 0.20, 'xj'), -1),          # negative bias: offset
    'first_stage_flow_loss': (lambda r: mean(r, 0.05, 0.051, 'xj'), -1),    # slower spool
    'clearance_growth': (lambda r: mean(r, 0.25, 0.30, 'xs'), +1),    # leakier null
}


def test_every_fault_is_documented_and_tested():
    assert set(EFFECTS) == set(FAULTS)
    for f in FAULTS.values():
        assert f.meaning and f.unit and f.lo <= f.demo <= f.hi


@pytest.mark.parametrize('fault', sorted(FAULTS))
def test_fault_effect_direction(fault):
    measure, direction = EFFECTS[fault]
    base, with_fault = measure(nominal()), measure(faulted(fault, FAULTS[fault].demo))
    print(f'{fault} at {FAULTS[fault].demo:g}: {base:.6g} -> {with_fault:.6g}')
    assert np.sign(with_fault - base) == direction
    assert abs(with_fault - base) > 0.05 * max(abs(base), 1e-9)


def test_null_bias_offset_is_the_proportional_loop_error():
    r = faulted('null_bias', -5e-3)
    offset = mean(nominal(), 0.15, 0.20, 'xj') - mean(r, 0.15, 0.20, 'xj')
    assert offset == pytest.approx(5e-3 / DEFAULTS.GAP, rel=0.2)      # CorB/GAP = 2.96 mm


def test_fault_severity_semantics_and_errors():
    assert resolve('leakage_growth', 10, DEFAULTS) == {'CLk': pytest.approx(2e-12)}
    assert resolve('supply_loss', 0.3, DEFAULTS) == {'PSR_scale': pytest.approx(0.7)}
    assert resolve('torque_motor_gain_loss', 0.5, DEFAULTS) == {'GM': pytest.approx(7.5)}
    assert resolve('dynamic_friction', 2.0, DEFAULTS) == {'FDJ': 400.0, 'FSJ': 400.0}
    with pytest.raises(TwinError, match="unknown fault 'wear'"):
        resolve('wear', 1.0, DEFAULTS)
    with pytest.raises(TwinError, match='out of range'):
        resolve('supply_loss', 1.5, DEFAULTS)
    for bad, fragment in (([{'at': 0.5, 'fault': 'leakage_growth'}], 'expected keys'),
                          ([{'at': 2.0, 'fault': 'leakage_growth', 'severity': 2}], 'outside'),
                          ([{'at': 0.5, 'param': 'M', 'value': -1.0}], 'parameter M'),
                          ([{'at': 0.5, 'fault': 'x', 'severity': 1}], "unknown fault 'x'")):
        with pytest.raises(ScenarioError, match=fragment):
            load_scenario(dict(PAPER, faults=bad))


def test_fault_event_applies_from_its_time():
    r = faulted('supply_loss', 0.5, at=0.5)
    before = nominal()
    w = r.window(0.0, 0.5)
    np.testing.assert_array_equal(r['xj'][w], before['xj'][w])
    assert np.max(np.abs(r['xj'] - before['xj'])) > 1e-3


@pytest.mark.parametrize('model', ['C2', 'SQ'])
def test_monitor_is_silent_on_the_nominal_paper_scenario(model):
    m = monitor_run(nominal(), model)
    peaks = {s: float(v.max()) for s, v in m.indicators.items()}
    print(f'{model} monitor, healthy HD plant: peak indicators {peaks}')
    assert m.level.max() == OK


@pytest.mark.parametrize('fault', sorted(FAULTS))
def test_monitor_alarms_on_each_fault_at_its_documented_severity(fault):
    onset = 0.1
    r = faulted(fault, FAULTS[fault].demo, at=onset)
    m = monitor_run(r, nominal=DEFAULTS)          # the default monitor, calibrated thresholds
    alarm = m.first_alarm(ERROR)
    warn = m.first_alarm(WARN)
    cfg = m.config
    margin = max(float(m.indicators[sig].max()) / cfg.thresholds(sig)[1] for sig in RESIDUALS)
    print(f'{fault} = {FAULTS[fault].demo:g} from {onset} s: WARN at {warn} s, ERROR at '
          f'{alarm} s (delay {None if alarm is None else round((alarm - onset) * 1e3)} ms), '
          f'peak indicator {margin:.3f} x its ERROR threshold')
    assert alarm is not None and onset <= alarm <= onset + MAX_DELAY
    # the documented severity alarms with margin: a legitimate change of the plant must not
    # flip it (clearance growth sat 0.08 % above its threshold at 3.0)
    assert margin >= 1.05
    # WARN comes first, on its own rows: with thresholds swapped (warn above error) no row
    # could be WARN without being ERROR
    assert warn is not None and warn < alarm
    assert m.level[np.argmin(np.abs(m.t - warn))] == WARN
    # the level is the worst threshold crossed, from the indicators themselves
    first_error = min(float(m.t[np.argmax(m.indicators[sig] > cfg.thresholds(sig)[1])])
                      for sig in RESIDUALS if np.any(m.indicators[sig] > cfg.thresholds(sig)[1]))
    assert alarm == first_error


def test_health_thresholds_are_ordered():
    with pytest.raises(TwinError, match='warn_xj'):
        HealthConfig(warn_xj=1e-2, error_xj=5e-3)
    with pytest.raises(TwinError, match='window'):
        HealthConfig(window=0.0)


def moving_rms(x, n):
    """RMS over the last n samples (fewer at the start), by cumulative sums: a reference that
    shares nothing with the monitor's ring of squares."""
    c = np.concatenate([[0.0], np.cumsum(np.asarray(x) ** 2)])
    i = np.arange(1, len(x) + 1)
    lo = np.maximum(i - n, 0)
    return np.sqrt((c[i] - c[lo]) / (i - lo))


def test_monitor_against_an_independent_reference():
    """The monitor's residuals are the plant's rows minus the monitor model simulated on the
    scenario by simulate's own loop (the paper's inputs change on whole milliseconds, so the
    monitor's inputs held over each tick are the scenario's); its indicators the moving RMS
    of those over the window; its level the worst threshold they cross."""
    r = faulted('leakage_growth', 10.0, at=0.1)
    m = monitor_run(r, nominal=DEFAULTS)
    ref = simulate('SQ', dict(PAPER), params=DEFAULTS, ecu_period=1e-3)
    n = int(round(m.config.window / 1e-3))
    level = np.zeros(len(m.t), dtype=int)
    for s in RESIDUALS:
        res = r[s] - ref[s]
        scale = float(np.max(np.abs(res)))
        np.testing.assert_allclose(m.residuals[s], res, rtol=0, atol=1e-9 * scale)
        np.testing.assert_allclose(m.indicators[s], moving_rms(res, n), rtol=1e-9,
                                   atol=1e-12 * scale)
        warn, err = m.config.thresholds(s)
        level = np.maximum(level, np.where(m.indicators[s] > err, ERROR,
                                           np.where(m.indicators[s] > warn, WARN, OK)))
    assert {OK, WARN, ERROR} <= set(m.level.tolist())
    np.testing.assert_array_equal(m.level, level)


def test_the_monitor_in_one_call_equals_the_monitor_tick_by_tick():
    """``steps`` (a whole run, stopping at each change of level) gives the outputs, levels and
    messages of ``step`` and ``health`` called tick after tick -- a sample dropped on the way."""
    from servovalve_twin.prognostics.algorithm import AlgorithmRunner, _step_by_step
    from servovalve_twin.prognostics.monitor import MonitorAlgorithm
    r = faulted('leakage_growth', 10.0, at=0.1)
    table = np.column_stack([r[s] for s in MonitorAlgorithm.inputs])
    table[300, 3] = 1e300                                  # xj: dropped
    t_ns = np.arange(len(table), dtype=np.int64) * 1_000_000
    one = AlgorithmRunner(MonitorAlgorithm(), 1e-3, DEFAULTS)
    many = AlgorithmRunner(MonitorAlgorithm(), 1e-3, DEFAULTS)
    out_1, level_1, msg_1 = _step_by_step(one, t_ns, table, 0)       # from level OK
    out_n, level_n, msg_n = many.steps(t_ns, table)
    np.testing.assert_array_equal(out_n, out_1)
    np.testing.assert_array_equal(level_n, level_1)
    assert msg_n == msg_1 and len(msg_1) >= 2
    assert one.alg.dropped == many.alg.dropped == 1
    assert one.alg.last_dropped == many.alg.last_dropped == 'xj = 1e+300 at t = 0.300 s'


def same_rows(a, b):
    """Rows equal, NaN included (a missing delay is NaN in both)."""
    return [json.dumps(r['row'], sort_keys=True) for r in a] == \
        [json.dumps(r['row'], sort_keys=True) for r in b]


def test_sweep_dataset(tmp_path):
    cases = make_cases(faults={'leakage_growth': [5.0, 20.0], 'null_bias': [-5e-3]},
                       nominal_runs=2, vary={'M': 0.1}, seed=3)
    assert [c.fault for c in cases] == ['none', 'none', 'leakage_growth', 'leakage_growth',
                                        'null_bias']
    assert len({c.params['M'] for c in cases}) == 5
    results = run_cases(cases, workers=2)
    serial = [run_case(c) for c in cases[:2]]
    assert same_rows(results[:2], serial)                      # deterministic, any executor
    summary = write_dataset(tmp_path, results)
    rows = list(csv.DictReader(open(tmp_path / 'dataset.csv')))
    assert len(rows) == 5
    for col in ('run_id', 'fault', 'severity', 'faulty', 'alarm', 'detection_delay',
                'param_M', 'peak_rms_xj', 'peak_rms_p12', 'max_level'):
        assert col in rows[0]
    assert rows[3]['fault'] == 'leakage_growth' and float(rows[3]['severity']) == 20.0
    traces = np.load(tmp_path / 'traces.npz')
    assert traces['run3_res_xj'].shape == (1001,) and 'run0_level' in traces
    assert json.loads((tmp_path / 'summary.json').read_text())['nominal_runs'] == 2
    assert summary['false_alarms'] == 0
    assert (tmp_path / 'signature.png').stat().st_size > 1000
    print(summary)


def test_monte_carlo_draws_and_cli(tmp_path, capsys):
    cases = make_cases(ranges={'supply_loss': (0.1, 0.4)}, draws=4, nominal_runs=0, seed=1)
    sev = [c.severity for c in cases]
    assert len(sev) == 4 and all(0.1 <= s <= 0.4 for s in sev) and len(set(sev)) == 4
    assert main(['sweep', '--fault', 'leakage_growth:20', '--nominal', '1', '--workers', '1',
                 '--out', str(tmp_path / 's')]) == 0
    out = capsys.readouterr().out
    assert 'runs/s' in out and 'leakage_growth' in out
    assert main(['sweep', '--fault', 'wear:1', '--out', str(tmp_path / 'x')]) == 2
    assert main(['sweep', '--fault', 'supply_loss:0.1~0.2', '--out', str(tmp_path / 'x')]) == 2
    assert "unknown fault 'wear'" in capsys.readouterr().err


@pytest.mark.slow
def test_sweep_on_a_dask_cluster(tmp_path):
    import distributed                                # installed by requirements.txt
    cases = make_cases(faults={'leakage_growth': [20.0]}, nominal_runs=1)
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=True,
                                  dashboard_address=None) as cluster:
        results = run_cases(cases, scheduler=cluster.scheduler_address)
    local = [run_case(c) for c in cases]
    assert same_rows(results, local)


def test_monitor_knows_the_design_not_each_units_draw():
    """Plant and monitor both C2: the residual is exactly zero for the design unit, and not
    zero for a unit whose mass was drawn away from it (the monitor cannot know that mass)."""
    design, drawn = make_cases(plant_model='C2', monitor_model='C2', nominal_runs=1)[0], \
        make_cases(plant_model='C2', monitor_model='C2', nominal_runs=1, vary={'M': 0.3},
                   seed=5)[0]
    assert drawn.params['M'] != DEFAULTS.M and drawn.design == {}
    assert run_case(design)['row']['peak_rms_xj'] == 0.0
    assert run_case(drawn)['row']['peak_rms_xj'] > 1e-5


def test_sweep_streams_rows_without_traces_unless_asked(tmp_path):
    """Without traces a run returns its row only, the same row as with them, from the pool as
    from one process; the dataset written from the stream then has no traces.npz. With
    traces, the streamed traces.npz holds every run's arrays, equal to the results'."""
    from servovalve_twin.prognostics.sweep import iter_results
    cases = make_cases(faults={'leakage_growth': [20.0]}, repeats=3, nominal_runs=1,
                       vary={'M': 0.1}, seed=5)
    full = run_cases(cases, workers=1)
    light = sorted(iter_results(cases, workers=2, traces=False), key=lambda r: r['row']['run_id'])
    assert same_rows(light, full) and all(r['traces'] == {} for r in light)
    write_dataset(tmp_path / 'rows', iter(light))
    assert not (tmp_path / 'rows' / 'traces.npz').exists()
    assert (tmp_path / 'rows' / 'dataset.csv').read_text().count('\n') == 5
    write_dataset(tmp_path / 'full', iter(full))
    with np.load(tmp_path / 'full' / 'traces.npz') as npz:
        assert sorted(npz.files) == sorted(f'run{r["row"]["run_id"]}_{k}' for r in full
                                           for k in r['traces'])
        for r in full:
            for k, v in r['traces'].items():
                np.testing.assert_array_equal(npz[f'run{r["row"]["run_id"]}_{k}'], v)


def _stopped_after(results, k, exc):
    """The first ``k`` of ``results``, last first (as runs finish out of order), then ``exc``."""
    yield from reversed(results[:k])
    raise exc


@pytest.mark.parametrize('exc, code', [(KeyboardInterrupt(), 130), (None, 2)])
def test_a_stopped_sweep_keeps_the_runs_that_finished(tmp_path, exc, code):
    """Ctrl-C, or a worker process lost (BrokenProcessPool), part-way through the stream: the
    dataset holds exactly the runs that had finished, in run order, in every file, and the
    error says how many of how many."""
    import pyarrow.parquet as pq
    from concurrent.futures.process import BrokenProcessPool
    from servovalve_twin.prognostics.dataset import SweepStopped
    cases = make_cases(faults={'leakage_growth': [20.0]}, repeats=4, nominal_runs=2, seed=5)
    results = run_cases(cases, workers=1, traces=True)
    with pytest.raises(SweepStopped, match='after 3 of 6 runs') as info:
        write_dataset(tmp_path / 's', _stopped_after(results, 3, exc or BrokenProcessPool()),
                      total=6)
    assert info.value.code == code
    with open(tmp_path / 's' / 'dataset.csv', newline='') as fh:
        rows = list(csv.DictReader(fh))
    assert [int(r['run_id']) for r in rows] == [0, 1, 2]
    assert pq.read_table(tmp_path / 's' / 'dataset.parquet').column('run_id').to_pylist() == \
        [0, 1, 2]
    summary = json.loads((tmp_path / 's' / 'summary.json').read_text())
    assert summary['runs'] == 3 and summary['nominal_runs'] == 2
    with np.load(tmp_path / 's' / 'traces.npz') as npz:
        assert {f.split('_')[0] for f in npz.files} == {'run0', 'run1', 'run2'}


def test_a_sweep_writes_into_a_new_or_empty_directory_only(tmp_path):
    (tmp_path / 'used').mkdir()
    (tmp_path / 'used' / 'dataset.csv').write_text('mine\n')
    cases = make_cases(faults={}, nominal_runs=1)
    with pytest.raises(TwinError, match='not an empty directory'):
        write_dataset(tmp_path / 'used', iter(run_cases(cases, workers=1)))
    assert (tmp_path / 'used' / 'dataset.csv').read_text() == 'mine\n'


def _children(pid: int) -> list[int]:
    """The processes whose parent is ``pid`` (from /proc)."""
    import os
    out = []
    for entry in os.listdir('/proc'):
        if entry.isdigit():
            try:
                with open(f'/proc/{entry}/stat') as fh:
                    if int(fh.read().rsplit(')', 1)[1].split()[1]) == pid:
                        out.append(int(entry))
            except (OSError, IndexError, ValueError):
                pass
    return out


def _alive(pid: int) -> bool:
    """Whether process ``pid`` still runs (a zombie does not)."""
    try:
        with open(f'/proc/{pid}/stat') as fh:
            return fh.read().rsplit(')', 1)[1].split()[0] != 'Z'
    except OSError:
        return False


STOPS = {'SIGINT to the parent': 130, 'SIGTERM to the parent': 143,
         'SIGHUP to the parent': 129, 'SIGKILL to a worker': 2, 'SIGKILL to the parent': -9}


@pytest.mark.slow
@pytest.mark.parametrize('how', list(STOPS))
def test_a_sweep_stopped_by_a_signal_keeps_its_finished_runs(tmp_path, how):
    """The CLI on a 2-worker pool, stopped once runs have streamed in: Ctrl-C, SIGTERM
    (docker stop, systemd, a CI time-out) or SIGHUP to the parent end it with 128 + the
    signal, a killed worker (a BrokenProcessPool traceback) with 2 -- one line each, the
    dataset holding every run that had finished, each once, in run order -- and no worker
    outlives it. SIGTERM ended the parent at once (rc -15, nothing printed) with the workers
    left running under PPID 1 and a traces.npz that was no zip file; a parent killed outright
    (SIGKILL) leaves no worker either (the parent-death signal) and no dataset file that is
    a part of one."""
    import os
    import signal
    import subprocess
    import sys
    import time
    out = tmp_path / 's'
    stream = out / '.dataset.csv.part'
    # Ctrl-C's disposition as a terminal gives it: a shell's background job (`cmd &`, as a
    # CI script may start the suite) inherits SIGINT ignored, and Python then keeps it so
    proc = subprocess.Popen([sys.executable, '-m', 'servovalve_twin.cli', 'sweep', '--fault',
                             'leakage_growth:5', '--repeats', '5000', '--nominal', '0',
                             '--workers', '2', '--traces', '--out', str(out)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    try:
        deadline = time.monotonic() + 300
        while not stream.exists() or stream.read_text().count('\n') < 8:
            assert proc.poll() is None and time.monotonic() < deadline, proc.communicate()
            time.sleep(0.05)
        workers = _children(proc.pid)
        assert len(workers) >= 2
        if how == 'SIGKILL to a worker':
            os.kill(workers[0], signal.SIGKILL)
        else:
            proc.send_signal(getattr(signal, how.split()[0]))
        _, err = proc.communicate(timeout=120)
    finally:
        proc.kill()
    print(err.strip())
    assert proc.returncode == STOPS[how]
    deadline = time.monotonic() + 30
    while any(_alive(w) for w in workers):
        assert time.monotonic() < deadline, f'workers outlived the sweep: {workers}'
        time.sleep(0.05)
    if how == 'SIGKILL to the parent':
        assert not (out / 'dataset.csv').exists() and not (out / 'traces.npz').exists()
        return
    assert err.count('\n') == 1 and 'Traceback' not in err and 'of 5000 runs' in err
    with open(out / 'dataset.csv', newline='') as fh:
        ids = [int(r['run_id']) for r in csv.DictReader(fh)]
    assert 7 <= len(ids) < 5000 and ids == sorted(set(ids))
    assert f'after {len(ids)} of 5000 runs' in err
    with np.load(out / 'traces.npz') as npz:
        assert {int(f.split('_')[0][3:]) for f in npz.files} == set(ids)
    assert not list(out.glob('.*.part'))


def test_a_sweep_gives_each_run_its_own_sensor_noise():
    """A scenario with sensors: two otherwise identical nominal runs of a sweep are two units
    with their own noise realisation (seed + run id), so the monitor's residuals differ; the
    same runs without sensors are identical."""
    from cases import short
    noisy = dict(short(), sensors={'seed': 3, 'xj': {'noise': 2.0e-5}})
    for scenario, differ in ((noisy, True), (short(), False)):
        cases = make_cases(plant_model='C2', scenario=scenario, nominal_runs=2)
        a, b = (run_case(c)['traces']['res_xj'] for c in cases)
        assert (not np.array_equal(a, b)) == differ
