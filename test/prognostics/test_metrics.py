"""metrics: each PHM metric against a hand computation."""

from __future__ import annotations

import math

import numpy as np
import pytest

from servovalve_twin.errors import TwinError
from servovalve_twin.prognostics.metrics import (alpha_lambda, detection_rates,
                                                 interval_coverage, prognostic_horizon,
                                                 relative_accuracy, time_to_detect)


def test_detection_rates_by_hand():
    # 4 healthy (1 alarmed), 5 faulty (2 missed)
    faulty = [False] * 4 + [True] * 5
    alarmed = [True, False, False, False, True, False, True, False, True]
    r = detection_rates(faulty, alarmed)
    assert r == dict(false_alarm_rate=0.25, missed_detection_rate=0.4, healthy=4, faulty=5)
    with pytest.raises(TwinError):
        detection_rates([True], [])


def test_time_to_detect_and_coverage_and_relative_accuracy():
    assert time_to_detect(0.3, 0.42) == pytest.approx(0.12)
    assert time_to_detect(0.3, 0.2) == math.inf and time_to_detect(0.3, None) == math.inf
    c = interval_coverage([1.0, 2.0, 3.0, 4.0], [[0, 1], [2.5, 3], [2, 4], [4, 4]])
    assert c == dict(hits=3, n=4, coverage=0.75)
    assert relative_accuracy(8.0, 10.0) == pytest.approx(0.8)
    assert relative_accuracy(12.0, 10.0) == pytest.approx(0.8)


def test_alpha_lambda_and_prognostic_horizon_by_hand():
    """True EOL 100. At cycle 50 the samples centre on 45 cycles left (truth 50): alpha 0.2
    allows 40-60, so all are in; at cycle 20 they centre on 40 (truth 80, bounds 64-96): out.
    The horizon is EOL minus the first cycle from which predictions meet the bounds: 100 - 50."""
    rng = np.random.default_rng(0)
    pred = {20.0: 40 + rng.normal(0, 0.5, 200), 50.0: 45 + rng.normal(0, 0.5, 200),
            70.0: 30 + rng.normal(0, 0.5, 200)}
    assert alpha_lambda(pred, 100.0, lam=50.0) is True
    assert alpha_lambda(pred, 100.0, lam=10.0) is False          # the cycle-20 prediction
    assert alpha_lambda(pred, 100.0, lam=60.0) is True           # the cycle-70 one: 24-36
    assert prognostic_horizon(pred, 100.0) == pytest.approx(50.0)
    # infinite lives are outside every bound
    assert alpha_lambda({50.0: [math.inf] * 10}, 100.0, lam=50.0) is False
