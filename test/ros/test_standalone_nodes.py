"""Each node run alone as a ROS user runs it (`ros2 run servovalve_twin plant --ros-args ...`):
a subprocess whose parameters and topics a test node reads back over DDS."""

import os
import signal
import subprocess
import threading
import time

import pytest
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter_client import AsyncParameterClient
from std_msgs.msg import Float64
from sensor_msgs.msg import JointState

from servovalve_twin.nodes.topics import QOS
from conftest import ROOT, console_script


def spin_until(ex, cond, timeout=60.0):
    deadline = time.monotonic() + timeout
    while not cond():
        ex.spin_once(timeout_sec=0.05)
        if time.monotonic() > deadline:
            return False
    return True


@pytest.fixture
def plant_process():
    proc = subprocess.Popen([console_script('plant'), '--ros-args', '-p', 'valve_model:=C4',
                             '--params-file', str(ROOT / 'config' / 'eha.yaml'),
                             '-p', 'M:=400.0'],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    yield proc
    if proc.poll() is None:
        proc.kill()
        proc.wait()


def test_standalone_plant_parameters_and_topics(ros_context, plant_process):
    node = Node('probe', context=ros_context)
    ex = SingleThreadedExecutor(context=ros_context)
    ex.add_node(node)
    got = {'xj': [], 'joint_states': [], 'p12': []}
    node.create_subscription(Float64, 'xj', lambda m: got['xj'].append(m.data), QOS)
    node.create_subscription(Float64, 'p12', lambda m: got['p12'].append(m.data), QOS)
    node.create_subscription(JointState, 'joint_states', lambda m: got['joint_states'].append(m),
                             QOS)
    # drive it: a current that opens the valve, as the ECU would
    cor = node.create_publisher(Float64, 'cor', QOS)
    msg = Float64()
    msg.data = 0.004
    client = AsyncParameterClient(node, 'plant')
    try:
        assert spin_until(ex, lambda: client.services_are_ready()), 'plant did not come up: ' \
            + (plant_process.stderr.read() if plant_process.poll() is not None else '')
        fut = client.get_parameters(['valve_model', 'M', 'CLk', 'use_sim_time'])
        assert spin_until(ex, fut.done)
        values = [p.string_value or p.double_value or p.bool_value for p in fut.result().values]
        print('plant parameters read back:', values)
        assert values[0] == 'C4' and values[1] == 400.0 and values[2] == 2e-13
        assert spin_until(ex, lambda: len(got['xj']) > 20)
        for _ in range(200):
            cor.publish(msg)
            ex.spin_once(timeout_sec=0.01)
        assert spin_until(ex, lambda: got['xj'] and got['xj'][-1] > 1e-4)
        js = got['joint_states'][-1]
        assert js.name == ['jack'] and js.header.stamp.sec + js.header.stamp.nanosec > 0
        print(f'standalone plant: {len(got["xj"])} XJ messages, last XJ {got["xj"][-1]:.6f} m')
        # a refused set: unknown model, with the reason, old value kept
        fut = client.set_parameters([__import__('rclpy').parameter.Parameter('valve_model',
                                                                            value='C9')])
        assert spin_until(ex, fut.done)
        assert not fut.result().results[0].successful
        assert 'expected one of' in fut.result().results[0].reason
    finally:
        ex.shutdown()
        node.destroy_node()
    plant_process.send_signal(signal.SIGINT)
    out, err = plant_process.communicate(timeout=20)
    print('plant exit code', plant_process.returncode, err[-300:])
    assert plant_process.returncode == 0 and 'Traceback' not in err


@pytest.mark.parametrize('name', ['command_generator', 'load_supply', 'ecu', 'plant', 'monitor',
                                  'clock'])
def test_each_executable_starts_and_stops_cleanly(name):
    """SIGTERM once the node says it has started (its handlers are then installed): a fixed
    sleep let the signal land during imports on a busy machine."""
    proc = subprocess.Popen([console_script(name), '--ros-args', '-p', 'use_sim_time:=false'],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=dict(os.environ, RCUTILS_LOGGING_BUFFERED_STREAM='0'))
    started = wait_for_line(proc, 'started: ', timeout=120)
    print(name, started.strip())
    assert proc.poll() is None
    assert 'wall time' in started and 'control period' in started or name == 'clock'
    proc.send_signal(signal.SIGTERM)
    out, err = proc.communicate(timeout=60)
    assert proc.returncode == 0, err
    assert 'Traceback' not in err


def wait_for_line(proc, fragment, timeout):
    """The first line of the process's stderr containing ``fragment`` (fails on exit/time)."""
    lines = []
    done = threading.Event()

    def reader():
        for line in proc.stderr:
            lines.append(line)
            if fragment in line:
                done.set()
                return
        done.set()
    threading.Thread(target=reader, daemon=True).start()
    assert done.wait(timeout), f'no {fragment!r} within {timeout} s: {"".join(lines)[-500:]}'
    hit = [ln for ln in lines if fragment in ln]
    assert hit, ''.join(lines)[-1000:]
    return hit[0]


def test_bad_start_up_parameter_is_one_line_exit_2():
    r = subprocess.run([console_script('plant'), '--ros-args', '-p', 'valve_model:=C9'],
                       capture_output=True, text=True, timeout=30)
    print(r.stderr)
    assert r.returncode == 2 and "unknown valve model 'C9'" in r.stderr
    assert 'Traceback' not in r.stderr
    r = subprocess.run([console_script('plant'), '--ros-args', '-p', 'M:=-3.0'],
                       capture_output=True, text=True, timeout=30)
    assert r.returncode == 2 and 'M' in r.stderr and 'Traceback' not in r.stderr


def test_replay_executable(tmp_path):
    r = subprocess.run([console_script('replay'), '--ros-args', '-p',
                        f'bag:={ROOT / "servovalve_twin" / "data" / "paper_HD"}', '-p',
                        'valve_model:=C3', '-p',
                        f'out:={tmp_path / "r"}'], capture_output=True, text=True, timeout=120)
    print(r.stdout[-800:], r.stderr[-500:])
    assert r.returncode == 0 and 'overstall' in r.stdout
    from servovalve_twin.bag.reader import read_bag
    assert read_bag(tmp_path / 'r').valve_model == 'C3'


@pytest.mark.slow
def test_twin_executable(tmp_path):
    r = subprocess.run([console_script('twin'), '--ros-args', '-p', 'valve_model:=C3',
                        '-p', f'bag:={tmp_path / "t"}', '-p', 'scenario:=defaults',
                        '-p', 'CLk:=3.0e-13', '-r', '__ns:=/left'],
                       capture_output=True, text=True, timeout=120)
    print(r.stdout, r.stderr[-500:])
    assert r.returncode == 0 and 'done' in r.stdout
    from servovalve_twin.bag.reader import read_bag
    run = read_bag(tmp_path / 't')
    assert run.valve_model == 'C3' and run.params()['CLk'] == 3e-13
    # the ROS way to namespace it: every topic under /left, /clock global, recorded so
    assert run.provenance.namespace == '/left' and '/left/xj' in run.topics
    assert '/clock' in run.topics and len(run.signals['xj']) == 1001
    # recording is on by default, into bags/<scenario>_<model>_<UTC time>: a rerun never
    # collides with an earlier bag; an explicit existing bag is replaced only with overwrite
    cmd = [console_script('twin'), '--ros-args', '-p', 'valve_model:=C1', '-p',
           'scenario:=defaults']
    for _ in range(2):
        r = subprocess.run(cmd, capture_output=True, text=True, timeout=120, cwd=tmp_path)
        assert r.returncode == 0, r.stderr
    made = sorted((tmp_path / 'bags').glob('defaults_C1_*'))
    assert len(made) == 2 and all(read_bag(b).valve_model == 'C1' for b in made)
    explicit = cmd + ['-p', f'bag:={made[0]}']
    r = subprocess.run(explicit, capture_output=True, text=True, timeout=120, cwd=tmp_path)
    assert r.returncode == 2 and 'exists' in r.stderr and '--overwrite' in r.stderr
    r = subprocess.run(explicit + ['-p', 'overwrite:=true'], capture_output=True, text=True,
                       timeout=120, cwd=tmp_path)
    assert r.returncode == 0


def test_twin_executable_and_run_take_the_same_options(tmp_path):
    """``servovalve-twin run`` and ``ros2 run servovalve_twin twin`` fill one TwinConfig: every
    option of one is a parameter of the other (the executable had no algorithm, estimator or
    clock period), and the executable hosts an algorithm and the estimator."""
    import argparse
    from servovalve_twin.cli import build_parser
    from servovalve_twin.twin.config import TwinConfig
    sub = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    run_dests = {a.dest for a in sub.choices['run']._actions}
    assert set(TwinConfig.names()) <= run_dests
    assert run_dests - set(TwinConfig.names()) == {'help', 'param', 'out', 'progress',
                                                   'discoverable'}
    r = subprocess.run([console_script('twin'), '--ros-args', '-p', 'valve_model:=C2', '-p',
                        'scenario:=defaults', '-p', 'record:=false', '-p',
                        "algorithm:=['servovalve_twin.prognostics.monitor:MonitorAlgorithm']",
                        '-p', 'estimator:=SQ', '-p', 'clock_period:=0.005'],
                       capture_output=True, text=True, timeout=300, cwd=tmp_path)
    print(r.stdout, r.stderr[-500:])
    assert r.returncode == 0
    assert 'twin: EHA monitor:' in r.stdout and 'twin: Estimator:' in r.stdout
    r = subprocess.run([console_script('twin'), '--ros-args', '-p', 'clock:=sometimes'],
                       capture_output=True, text=True, timeout=300, cwd=tmp_path)
    assert r.returncode == 2 and "clock = 'sometimes': expected one of own, follow" in r.stderr
    assert r.stderr.count('\n') == 1 and not list(tmp_path.iterdir())


SWALLOWED = """
import signal, sys, weakref
from servovalve_twin import entry, stopping
stopping.watch()
class Part:
    pass
def callback(ref):          # Python ignores an exception raised in a weakref callback
    signal.raise_signal(signal.SIGINT)
part = Part()
ref = weakref.ref(part, callback)
del part                    # the SIGINT lands in the callback: "Exception ignored"
assert stopping.asked()
sys.argv = [sys.argv[1], *sys.argv[2:]]
sys.exit(getattr(entry, sys.argv[0])())
"""


@pytest.mark.parametrize('exe,args', [
    ('plant', ['--ros-args', '-p', 'valve_model:=C2']),
    ('twin', ['--ros-args', '-p', 'valve_model:=C2', '-p', 'record:=false']),
    ('player', ['--ros-args', '-p', f'bag:={ROOT / "servovalve_twin" / "data" / "paper_HD"}']),
])
def test_a_ctrl_c_python_swallowed_while_starting_still_stops_it(exe, args):
    """A SIGINT that lands in a weakref callback while an executable starts (importlib's module
    locks have one) is printed as "Exception ignored" and lost to Python; the executable
    still stops (exit 0, never running its node) once its own handler is in place -- it ran
    for ever, deaf to the Ctrl-C, before stopping.asked() was checked."""
    import sys
    r = subprocess.run([sys.executable, '-c', SWALLOWED, exe, *args], capture_output=True,
                       text=True, timeout=120)
    print(r.stdout[-600:], r.stderr[-1200:])
    assert 'KeyboardInterrupt' in r.stderr          # swallowed: "Exception ignored in ..."
    assert r.returncode == 0
    assert 'started:' not in r.stderr + r.stdout
    if exe == 'player':
        assert ': 0 messages' in r.stdout


@pytest.mark.slow
def test_twin_executable_stops_cleanly_on_sigint(tmp_path):
    """Ctrl-C (or launch's SIGINT) ends ``twin`` at a tick with exit code 0 -- launch logs no
    'process has died' -- and a finished bag; a second SIGINT during the stop changes
    nothing."""
    scenario = tmp_path / 'long.yaml'
    scenario.write_text('duration: 600.0\ncom: [[0.0, 0.02]]\n')
    proc = subprocess.Popen([console_script('twin'), '--ros-args', '-p', 'valve_model:=C2',
                             '-p', f'scenario:={scenario}', '-p', f'bag:={tmp_path / "b"}'],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert 'twin: running C2 on long' in proc.stdout.readline()
        time.sleep(0.5)
        proc.send_signal(signal.SIGINT)
        time.sleep(0.02)
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    print(out, err[-800:])
    assert proc.returncode == 0 and 'twin: interrupted' in out and 'Traceback' not in err
    from servovalve_twin.bag.reader import read_bag
    assert 0.0 < read_bag(tmp_path / 'b').signals['t'][-1] < 600.0


def test_multi_process_graph_shares_simulated_time(ros_context, tmp_path):
    """`clock` drives simulated time for nodes in other processes (use_sim_time:=true): the
    command pulses to 0.03 m for 0.45 s of scenario time every 1.5 s, so whenever discovery
    lets the probe in, it sees a whole pulse, 0.45 s long on the shared /clock."""
    points = [[0.0, 0.02]]
    for i in range(1, 40):
        points += [[1.5 * i, 0.03], [1.5 * i + 0.45, 0.02]]
    scenario = tmp_path / 'pulses.yaml'
    scenario.write_text(f'duration: 61.0\ncom: {points}\n')
    from rosgraph_msgs.msg import Clock
    clock_proc = subprocess.Popen([console_script('clock'), '--ros-args', '-p', 'rate:=2.0'],
                                  stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    procs = [clock_proc]
    node = Node('probe_time', context=ros_context)
    ex = SingleThreadedExecutor(context=ros_context)
    ex.add_node(node)
    clock = []
    com = []
    node.create_subscription(Clock, '/clock', lambda m: clock.append(
        m.clock.sec + m.clock.nanosec * 1e-9), 10)
    # Com stamped with the probe's latest /clock (Com received before any /clock is ignored)
    node.create_subscription(Float64, 'com', lambda m: clock and com.append((clock[-1], m.data)),
                             QOS)
    try:
        assert spin_until(ex, lambda: len(clock) > 10)
        # Com every 10 ms of simulated time (not 1 ms): a probe that falls behind 2000
        # messages/s on a busy machine takes them in bursts stamped with one /clock, which
        # squeezes the pulse it measures (0.08 s seen once in CI)
        procs.append(subprocess.Popen([console_script('command_generator'), '--ros-args',
                                       '-p', 'use_sim_time:=true', '-p', f'scenario:={scenario}',
                                       '-p', 'control_period:=0.01'],
                                      stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True))
        def edges():
            """Times of the first observed rise to 0.03 and the fall after it."""
            rise = next((b[0] for a, b in zip(com, com[1:]) if a[1] == 0.02 and b[1] == 0.03),
                        None)
            fall = next((b[0] for a, b in zip(com, com[1:]) if rise is not None
                         and a[0] >= rise and a[1] == 0.03 and b[1] == 0.02), None)
            return rise, fall
        ok = spin_until(ex, lambda: edges()[1] is not None, timeout=30)
        assert ok, (len(clock), clock[-1:], len(com), com[:3], com[-3:], procs[1].poll())
        up, down = edges()
        print(f'Com 0.02 -> 0.03 m at {up:.3f} s and back at {down:.3f} s of simulated time')
        # the probe stamps Com with the last /clock it received, so delivery jitter on a
        # busy machine blurs each edge; a node on wall time instead of /clock (rate 2) would
        # see 0.225 s or 0.9 s
        assert down - up == pytest.approx(0.45, abs=0.1)
    finally:
        ex.shutdown()
        node.destroy_node()
        for p in procs[::-1]:
            p.send_signal(signal.SIGINT)
            _, err = p.communicate(timeout=20)
            assert p.returncode == 0, err[-2000:]


def test_algorithm_and_player_executables(tmp_path):
    """`ros2 run servovalve_twin algorithm -p class:=...` hosts a user's class alone (its
    parameters as ROS parameters); `player -p bag:=...` plays a bag to its end; bad input is
    one line and exit 2."""
    # the user's module added to the path, not in place of it (under colcon the package
    # itself comes from install/ through PYTHONPATH)
    env = dict(os.environ, RCUTILS_LOGGING_BUFFERED_STREAM='0',
               PYTHONPATH=os.pathsep.join(filter(None, (
                   str(ROOT / 'doc' / 'examples' / 'my_detector'),
                   os.environ.get('PYTHONPATH')))))
    proc = subprocess.Popen([console_script('algorithm'), '--ros-args', '-p',
                             'class:=leak_detector:LeakDetector', '-p', 'threshold:=2.5'],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    started = wait_for_line(proc, 'started: ', timeout=120)
    assert 'control period 0.001 s' in started
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 0 and 'Traceback' not in err, err
    for args, fragment in ((['class:=leak_detector:Nope'], "has no 'Nope'"),
                           ([], 'give the algorithm')):
        cmd = [console_script('algorithm'), '--ros-args'] + sum((['-p', a] for a in args), [])
        r = subprocess.run(cmd, capture_output=True, text=True, timeout=120, env=env)
        assert r.returncode == 2 and fragment in r.stderr and 'Traceback' not in r.stderr, \
            r.stderr
    from bagmaker import write_bag
    written = write_bag(tmp_path / 'b', storage='mcap', version=9, split=2)
    r = subprocess.run([console_script('player'), '--ros-args', '-p', f'bag:={tmp_path / "b"}',
                        '-p', 'rate:=20.0'], capture_output=True, text=True, timeout=120)
    played = sum(1 for m in written if m[0] != '/custom')
    assert r.returncode == 0 and f'player: {played} messages' in r.stdout, r.stdout + r.stderr
    r = subprocess.run([console_script('player'), '--ros-args', '-p', 'bag:=/nonexistent'],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 2 and 'no bag at' in r.stderr and r.stderr.count('\n') == 1


@pytest.mark.parametrize('name', ['twin', 'player'])
def test_help_is_the_usage_and_exit_0(name):
    """`twin --help` and `player --help` printed the usage as an error, exit 2."""
    import subprocess
    r = subprocess.run([console_script(name), '--help'], capture_output=True, text=True,
                       timeout=120)
    assert r.returncode == 0 and r.stdout.startswith(f'usage: {name} --ros-args')
    assert 'example: ros2 run servovalve_twin ' + name in r.stdout
    r = subprocess.run([console_script(name), 'stray'], capture_output=True, text=True,
                       timeout=120)
    assert r.returncode == 2 and r.stderr.startswith(f'usage: {name}')
