"""Shared fixtures. Runs of the paper scenario are cached per session: they are deterministic,
and the statements of the paper are checked on the same runs the report tabulates."""

import functools
import os
import sys
import tempfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

# the suite's own cache of flight calibrations (calibrate-diagnosis): a user's, under
# ~/.cache, would make diagnose apply a calibration of its own to the tests' bags (the
# processes the tests start inherit it)
os.environ['SERVOVALVE_TWIN_CACHE'] = tempfile.mkdtemp(prefix='servovalve_twin_test_cache_')


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


# ros_context, replay and twin_bag come from the package's own pytest plugin
# (servovalve_twin.testing.plugin, entry point pytest11), as in any user's test suite.


def console_script(name: str) -> str:
    """Path of an installed executable of this package, found the way ``ros2 run`` finds it:
    in ``lib/servovalve_twin/`` of the package's prefix in the ament index (a colcon
    workspace after ``source install/setup.bash``, or a ROS installation); else beside the
    interpreter (a pip install into the venv), else on PATH."""
    import shutil
    candidates = []
    try:
        from ament_index_python.packages import PackageNotFoundError, get_package_prefix
        try:
            candidates.append(Path(get_package_prefix('servovalve_twin')) / 'lib'
                              / 'servovalve_twin' / name)
        except (PackageNotFoundError, OSError):     # OSError: no AMENT_PREFIX_PATH at all
            pass
    except ImportError:
        pass
    candidates.append(Path(sys.executable).parent / name)
    for path in candidates:
        if path.exists():
            return str(path)
    found = shutil.which(name)
    if not found:
        pytest.fail(f'executable {name!r} of servovalve_twin is not installed: run scripts/setup '
                    '(pip) or colcon build and source install/setup.bash')
    return found


def answer(executor, send, timeout_s: float = 120.0, resend_s: float = 10.0):
    """The result of a service request ``send()`` (a function returning its future), sent
    again every ``resend_s`` until one is answered (None after ``timeout_s``): a request made
    just as the service is discovered can be lost before the server's reply writer has
    matched the client (Fast DDS), and then is never answered -- on a busy machine a
    parameter request waited its whole minute."""
    import time
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        fut = send()
        executor.spin_until_future_complete(fut, timeout_sec=min(resend_s, max(
            0.0, deadline - time.monotonic())))
        if fut.done():
            return fut.result()
    return None


ROS_FIXTURES = {'ros_context', 'replay', 'twin_bag'}


def pytest_collection_modifyitems(config, items):
    """The tiers: a test that may start rclpy nodes -- it lives in test/ros/, takes
    ``ros_context``, ``replay`` or ``twin_bag``, or is marked ``ros`` by hand -- is in the
    ``ros`` tier (``pytest -m "not ros"`` needs no ROS graph; :func:`_rclpy_only_in_the_ros_tier`
    holds the others to it). It was chosen by a word search of the module, which put
    test_physics_without_ros.py in it. ``slow`` is marked by hand on tests of more than about
    2 s here, so that ``pytest -m "not slow"`` is the fast tier."""
    for item in items:
        if '/ros/' in str(item.fspath) or ROS_FIXTURES & set(getattr(item, 'fixturenames', ())):
            item.add_marker(pytest.mark.ros)


@pytest.fixture(autouse=True)
def _rclpy_only_in_the_ros_tier(request, monkeypatch):
    """A test outside the ros tier that starts rclpy in this process fails, naming the tier
    it belongs to (a process it starts is its own business: mark it by hand)."""
    if request.node.get_closest_marker('ros') is not None:
        return
    from rclpy.context import Context

    def refused(*args, **kwargs):
        raise RuntimeError(f'{request.node.nodeid} starts rclpy: mark it @pytest.mark.ros '
                           '(or move it to test/ros/)')
    monkeypatch.setattr(Context, 'init', refused)
