"""pytest fixtures for testing your nodes against bags (registered through the ``pytest11``
entry point: installing servovalve_twin gives every test suite these).

- ``ros_context``: a private, initialised rclpy context for one test, shut down after it;
- ``replay``: :func:`~servovalve_twin.testing.replay_into`, the nodes then given to it;
- ``twin_bag``: ``twin_bag(scenario='paper', valve_model='HD', faults=(), monitor=None)``
  records a bag of the twin once per test session (cached by its arguments) and returns its
  directory -- e.g. ``twin_bag(faults=[{'at': 0.1, 'fault': 'leakage_growth',
  'severity': 10.0}])``.
"""

from __future__ import annotations

import json

import pytest


@pytest.fixture
def ros_context():
    import rclpy
    from rclpy.context import Context
    from rclpy.signals import SignalHandlerOptions
    ctx = Context()
    rclpy.init(context=ctx, signal_handler_options=SignalHandlerOptions.NO)
    yield ctx
    rclpy.try_shutdown(context=ctx)


@pytest.fixture
def replay():
    from . import replay_into
    return replay_into


@pytest.fixture(scope='session')
def twin_bag(tmp_path_factory):
    cache: dict[str, object] = {}

    def make(scenario='paper', valve_model='HD', faults=(), monitor=None, params=None):
        import rclpy
        from rclpy.context import Context
        from rclpy.signals import SignalHandlerOptions
        from ..config import load_scenario
        from ..twin import TwinConfig, run_twin
        key = json.dumps([scenario if isinstance(scenario, str) else repr(scenario),
                          valve_model, list(faults), monitor, params or {}], sort_keys=True,
                         default=str)
        if key in cache:
            return cache[key]
        raw = load_scenario(scenario).to_dict()
        if faults:
            raw['faults'] = list(raw.get('faults', [])) + list(faults)
        path = tmp_path_factory.mktemp('twin_bags') / f'{raw["name"]}_{valve_model}'
        ctx = Context()
        rclpy.init(context=ctx, signal_handler_options=SignalHandlerOptions.NO)
        try:
            run_twin(TwinConfig(valve_model, raw, bag=path, monitor=monitor), params, context=ctx,
                     handle_signals=False, keep_values=False)
        finally:
            rclpy.try_shutdown(context=ctx)
        cache[key] = path
        return path
    return make
