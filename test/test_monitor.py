"""The monitor survives a sensor glitch: one absurd sample on any monitored topic is dropped and
counted, and the monitor goes on -- its residuals and health afterwards those of the run
without the glitch (the independent reference: the same run, clean)."""

from __future__ import annotations

import numpy as np
import pytest

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
