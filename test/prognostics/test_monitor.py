"""The monitor survives a sensor glitch: one absurd sample on any monitored topic is dropped and
counted, and the monitor goes on -- its residuals and health afterwards those of the run
without the glitch (the independent reference: the same run, clean)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from servovalve_twin.config import load_scenario
from servovalve_twin.physics.params import DEFAULTS
from servovalve_twin.prognostics.algorithm import run_algorithm
from servovalve_twin.prognostics.monitor import MonitorAlgorithm
from servovalve_twin.runs import simulate

INPUTS = MonitorAlgorithm.inputs


@pytest.fixture(scope='module')
def clean():
    r = simulate('HD', 'paper', ecu_period=1e-3)
    t_ns = np.rint(np.asarray(r['t']) * 1e9).astype(np.int64)
    u = {s: np.asarray(r[s], dtype=float) for s in INPUTS}
    return t_ns, u, run_algorithm(MonitorAlgorithm(), t_ns, u, 1e-3, DEFAULTS)


@pytest.mark.parametrize('signal', INPUTS)
@pytest.mark.parametrize('value', [1e300, float('nan'), -float('inf')])
def test_one_absurd_sample_is_dropped_and_the_monitor_goes_on(clean, signal, value):
    t_ns, u, ref = clean
    k = 400
    bad = {s: v.copy() for s, v in u.items()}
    bad[signal][k] = value
    alg = MonitorAlgorithm()
    run = run_algorithm(alg, t_ns, bad, 1e-3, DEFAULTS)
    assert alg.dropped == 1 and f'{signal} = ' in alg.last_dropped and 't = 0.400 s' in \
        alg.last_dropped
    # the dropped tick holds the previous outputs; the levels never differ from the clean run
    np.testing.assert_array_equal(run.level, ref.level)
    for name in ('residual_xj', 'residual_dxj', 'residual_p12'):
        assert run.outputs[name][k] == run.outputs[name][k - 1]
        if signal in ('xj', 'dxj', 'p12'):
            # a measurement glitch leaves the model alone: every other residual is the clean one
            keep = np.arange(len(t_ns)) != k
            np.testing.assert_array_equal(run.outputs[name][keep], ref.outputs[name][keep])
    assert 'implausible samples dropped' in alg.health().message


def test_a_plausible_run_drops_nothing(clean):
    t_ns, u, _ = clean
    alg = MonitorAlgorithm()
    run_algorithm(alg, t_ns, u, 1e-3, DEFAULTS)
    assert alg.dropped == 0 and 'dropped' not in alg.health().message


# -- thresholds set for a stated false-alarm rate --------------------------------------------

def test_gumbel_quantile_against_the_closed_form():
    """Samples of a known Gumbel law: the fitted quantile is the law's own,
    mu - beta*ln(-ln(1 - p))."""
    from servovalve_twin.prognostics.thresholds import gumbel_quantile
    rng = np.random.default_rng(5)
    mu, beta = 2.0, 0.5
    x = rng.gumbel(mu, beta, 200_000)
    for p in (1e-2, 1e-3 / 3):
        exact = mu - beta * np.log(-np.log1p(-p))
        assert gumbel_quantile(x, p) == pytest.approx(exact, rel=0.01)


def test_thresholds_hold_their_false_alarm_rate_on_gumbel_peaks():
    """Peaks of a known Gumbel law: a fresh peak exceeds one residual's ERROR threshold with a
    third of the per-flight rate (the law's own exceedance, 1 - exp(-exp(-(x - mu)/beta)));
    and no threshold lies below a healthy peak it was calibrated on."""
    from servovalve_twin.prognostics.monitor import RESIDUALS
    from servovalve_twin.prognostics.thresholds import calibrate_thresholds
    rng = np.random.default_rng(6)
    mu, beta = 1.0, 0.1
    peaks = {s: rng.gumbel(mu, beta, 200_000) for s in RESIDUALS}
    th = calibrate_thresholds(peaks, rates={'warn': 3e-6, 'error': 3e-7})
    for level, rate in (('warn', 3e-6), ('error', 3e-7)):
        x = th[f'{level}_dxj']
        exceed = -np.expm1(-np.exp(-(x - mu) / beta))
        assert exceed == pytest.approx(rate / 3, rel=0.05)
    assert th['warn_p12'] < th['error_p12']
    few = {s: rng.gumbel(mu, beta, 30) for s in RESIDUALS}
    th = calibrate_thresholds(few, rates={'warn': 0.9, 'error': 0.6})
    assert th['warn_xj'] == th['error_xj'] == few['xj'].max()


def test_the_packaged_thresholds_are_those_the_calibration_gives():
    """bench/calibrate_monitor.py's settings reproduce the packaged file: a model or a flight
    changed without recalibrating fails here."""
    import json
    from servovalve_twin.physics.valves import MONITOR_MODEL_NAMES
    from servovalve_twin.prognostics.monitor import MONITOR_CALIBRATION_FILE
    from servovalve_twin.prognostics.thresholds import (calibrate_thresholds, healthy_peaks,
                                                        monitor_cal_flights)
    packaged = json.loads(MONITOR_CALIBRATION_FILE.read_text())
    about = packaged['about']
    flights = monitor_cal_flights()
    assert sorted(flights) == about['flights']
    peaks = healthy_peaks(('SQ', 'C2'), flights, about['units'], about['seed'],
                          spread=about['spread'])
    for m in ('SQ', 'C2'):
        got = calibrate_thresholds(peaks[m])
        for k, v in packaged['thresholds'][m].items():
            assert got[k] == pytest.approx(v, rel=1e-9), (m, k)
    assert set(packaged['thresholds']) == set(MONITOR_MODEL_NAMES)


def test_no_false_alarm_on_unseen_flights_and_a_3x_leak_is_seen():
    """Healthy HD units with nuisance at 1.5 x the documented spread on flights the
    calibration never flew (another chirp, other random steps under load, noise 2 x): the
    default monitor stays below ERROR; a 3 x leakage on the paper's flight reaches it."""
    from servovalve_twin.config import load_scenario
    from servovalve_twin.prognostics.calibration_set import NOISE, VARY
    from servovalve_twin.prognostics.monitor import ERROR, monitor_run
    from servovalve_twin.prognostics.thresholds import chirp, random_steps
    from servovalve_twin.prognostics.sweep import draw_nuisance, measured
    rng = np.random.default_rng(77)
    noise = {k: 2 * v for k, v in NOISE.items()}
    for flight in (chirp(0.3, 8.0, 0.025, 2.0, -4000.0), random_steps(77), random_steps(78)):
        unit = DEFAULTS.replace(**draw_nuisance(rng, {k: 1.5 * v for k, v in VARY.items()},
                                                DEFAULTS))
        run = simulate('HD', flight, params=unit, ecu_period=1e-3)
        run.signals.update(measured(run.signals, noise, rng))
        assert monitor_run(run, nominal=DEFAULTS).first_alarm(ERROR) is None, flight['name']
    leak = dict(load_scenario('paper').to_dict(),
                faults=[dict(at=0.1, fault='leakage_growth', severity=3.0)])
    leaking = simulate('HD', leak, ecu_period=1e-3)
    assert monitor_run(leaking, nominal=DEFAULTS).first_alarm(ERROR) is not None


def test_monitor_thresholds_command_writes_a_params_file(tmp_path, capsys):
    import yaml
    from servovalve_twin.cli import main
    from servovalve_twin.prognostics.monitor import HealthConfig
    out = tmp_path / 'mt.yaml'
    assert main(['monitor-thresholds', '--scenario', 'paper', '--units', '2',
                 '--out', str(out)]) == 0
    params = yaml.safe_load(out.read_text())['monitor']['ros__parameters']
    assert params.pop('monitor_model') == 'SQ'
    HealthConfig(**params)                               # ordered, positive window
    before = out.read_bytes()
    for args, fragment in ((['--out', str(out)], 'exists'),
                           (['--far-error', 'nan', '--out', str(tmp_path / 'b.yaml')],
                            '--far-error nan'),
                           (['--far-error', '0.1', '--far-warn', '0.01', '--out',
                             str(tmp_path / 'b.yaml')], 'must not exceed'),
                           (['--monitor-model', 'HD', '--out', str(tmp_path / 'b.yaml')],
                            'HD'),
                           # one unit on one flight: a Gumbel law of one peak was NaN
                           (['--scenario', 'paper', '--units', '1', '--out',
                             str(tmp_path / 'b.yaml')], 'at least 2 healthy units'),
                           (['--units', '10000000', '--out', str(tmp_path / 'b.yaml')],
                            'allowed 1 to 1000'),
                           (['--reveal-units', '-1', '--out', str(tmp_path / 'b.yaml')],
                            '--reveal-units -1')):
        capsys.readouterr()
        assert main(['monitor-thresholds', *args]) == 2
        err = capsys.readouterr().err
        assert fragment in err and err.count('\n') == 1, err
    assert out.read_bytes() == before and not (tmp_path / 'b.yaml').exists()


def test_what_a_flight_reveals_is_flown_not_assumed(capsys):
    """A hold at rest without load reveals a null bias (the loop must correct it) and none of
    the faults that need motion, pressure or load to show; the paper's flight reveals every
    one, at the packaged thresholds. The command prints the table under the thresholds."""
    from servovalve_twin.prognostics.monitor import HealthConfig, calibrated_thresholds
    from servovalve_twin.prognostics.thresholds import format_revealed, revealed
    cfg = HealthConfig(**calibrated_thresholds('SQ'))
    hold = {'duration': 0.3, 'com': [[0.0, 0.0]], 'fr': [[0.0, 0.0]]}
    rev = revealed('SQ', {'hold': hold, 'paper': 'paper'}, cfg, 2, 5)
    assert rev['null_bias']['hold'] == [2, 2]
    for fault in ('leakage_growth', 'static_friction', 'dynamic_friction', 'supply_loss'):
        assert rev[fault]['hold'] == [0, 0] and rev[fault]['paper'] == [2, 2], fault
    text = format_revealed({f: {'hold': v['hold']} for f, v in rev.items()})
    assert 'leakage_growth                 10 x CLk  hold: 0(0)/2' in text
    assert text.splitlines()[-1].startswith('not revealed') and 'null_bias' not in \
        text.splitlines()[-1] and 'servovalve-twin bit' in text


def test_monitor_run_refuses_a_run_its_ecu_would_not_match():
    """The monitor samples every 1 ms row: a run with a continuous ECU would differ from its
    model by the sampling alone (7 WARNs in 110 healthy runs of bench_monitor, none at 1 ms)."""
    from servovalve_twin.errors import TwinError
    from servovalve_twin.prognostics.monitor import monitor_run
    for period in (None, 2e-3):
        run = simulate('C2', {'duration': 0.01}, ecu_period=period)
        with pytest.raises(TwinError, match='ecu_period=1e-3'):
            monitor_run(run)


def test_a_gumbel_law_of_too_few_peaks_is_refused():
    """MIN_PEAKS = 2: the scale is a sample sd, NaN of one peak."""
    from servovalve_twin.errors import TwinError
    from servovalve_twin.prognostics.thresholds import gumbel_quantile
    with pytest.raises(TwinError, match='at least 2 finite healthy peaks, got 1'):
        gumbel_quantile([0.3], 1e-3)
    with pytest.raises(TwinError, match='not all finite'):
        gumbel_quantile([0.3, math.nan, 0.2], 1e-3)
    # two peaks: the moments' law, by hand
    beta = np.std([1.0, 2.0], ddof=1) * math.sqrt(6) / math.pi
    mu = 1.5 - 0.5772156649 * beta
    assert gumbel_quantile([1.0, 2.0], 0.01) == pytest.approx(
        mu - beta * math.log(-math.log(0.99)))


@pytest.mark.parametrize('first, later', [('xj', 'p12'), ('xj', 'dxj'), ('dxj', 'p12')])
def test_a_row_s_level_is_its_worst_signal_s(first, later):
    """An HD unit with a 10 x leak read by SQ; thresholds set so that ``first`` is at ERROR as
    soon as its indicator moves and ``later`` (after it in the row) only at WARN: every row
    where both have moved is ERROR, the worse of the two, whichever signal comes later (a WARN
    on a later signal that overwrote an earlier ERROR passed every test)."""
    from servovalve_twin.prognostics.monitor import RESIDUALS, HealthConfig, monitor_run
    sc = dict(load_scenario('paper').to_dict(),
              faults=[{'at': 0.0, 'fault': 'leakage_growth', 'severity': 10.0}])
    run = simulate('HD', sc, ecu_period=1e-3)
    kw = {}
    for s in RESIDUALS:
        warn, err = {first: (1e-300, 2e-300), later: (1e-300, 1e300)}.get(s, (1e300, 1e300))
        kw.update({f'warn_{s}': warn, f'error_{s}': err})
    res = monitor_run(run, 'SQ', HealthConfig(window=0.05, **kw))
    both = (res.indicators[first] > 1e-300) & (res.indicators[later] > 1e-300)
    assert both.sum() > 100
    assert np.all(res.level[both] == 2)
    only_later = (res.indicators[first] <= 1e-300) & (res.indicators[later] > 1e-300)
    assert np.all(res.level[only_later] == 1)


def test_the_monitor_loads_its_loop_at_setup_not_at_its_first_sample(monkeypatch):
    """setup() runs the monitor's rows loop once over no row, on copies of its state: a node
    hosting it says it has started once it can step (a first sample compiled the loop for
    ~7.5 s without the compiled module). Its own state is not touched."""
    from servovalve_twin.prognostics import monitor as mon
    calls = []

    def fake_rows_for(model_id):
        def rows(mid, s, vs, P, n_sub, u, w, ring, out, level, stop):
            calls.append((mid, u.shape[0], w, ring, n_sub))
            return mon.DONE
        return rows
    monkeypatch.setattr(mon, 'monitor_rows_for', fake_rows_for)
    alg = MonitorAlgorithm()
    assert not calls
    alg.setup(1e-3, DEFAULTS)
    assert len(calls) == 1
    mid, rows, w, ring, n_sub = calls[0]
    assert rows == 0 and mid == alg.plant.model.id and n_sub == alg.n_sub > 0
    assert w is not alg._w and ring is not alg._ring
