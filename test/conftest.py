"""Shared fixtures. Runs of the paper scenario are cached per session: they are deterministic,
and the statements of the paper are checked on the same runs the report tabulates."""

import functools
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))


@functools.lru_cache(maxsize=None)
def paper_run(model: str, **overrides):
    from servovalve_twin.runs import simulate
    return simulate(model, 'paper', overrides or None)


def cached_run(model: str, clk: float | None = None):
    return paper_run(model) if clk is None else paper_run(model, CLk=clk)


@pytest.fixture(scope='session')
def runs():
    """Every registered model on the paper scenario with the default parameters."""
    from servovalve_twin.physics.valves import VALVE_MODEL_NAMES
    return {m: cached_run(m) for m in VALVE_MODEL_NAMES}


@pytest.fixture
def ros_context():
    """A private, initialised rclpy context for one test (no global state, no signal hooks)."""
    import rclpy
    from rclpy.context import Context
    from rclpy.signals import SignalHandlerOptions
    ctx = Context()
    rclpy.init(context=ctx, signal_handler_options=SignalHandlerOptions.NO)
    yield ctx
    rclpy.try_shutdown(context=ctx)


def console_script(name: str) -> str:
    """Path of an installed console script of this package (next to the interpreter)."""
    import shutil
    path = Path(sys.executable).parent / name
    if path.exists():
        return str(path)
    found = shutil.which(name)
    if not found:
        pytest.fail(f'console script {name!r} is not installed: run scripts/setup')
    return found
