"""Your own algorithm in the loop: one Algorithm gives identical outputs live in the twin, on the
recorded bag (``evaluate``) and in a sweep; failures are one line; ``replay_into`` feeds nodes a
bag deterministically, independent of machine load."""

import json
import os
import subprocess
import sys

import numpy as np
import pytest
from rclpy.node import Node
from rclpy.parameter import Parameter
from std_msgs.msg import Float64

from bagmaker import write_bag
from servovalve_twin.apps.evaluate import evaluate
from servovalve_twin.bag.reader import read_bag
from servovalve_twin.cli import main
from servovalve_twin.errors import TwinError
from servovalve_twin.prognostics import ERROR, WARN, Algorithm, AlgorithmError
from servovalve_twin.prognostics.algorithm import load_algorithm
from servovalve_twin.prognostics.monitor import MonitorAlgorithm
from servovalve_twin.prognostics.sweep import make_cases, run_case, run_cases
from servovalve_twin.testing import replay_into
from servovalve_twin.twin import Twin, TwinConfig, run_twin
from conftest import ROOT
from cases import PAPER

EXAMPLE = ROOT / 'doc' / 'examples' / 'my_detector'
sys.path.insert(0, str(EXAMPLE))
DETECTOR = 'leak_detector:LeakDetector'
LEAKING = dict(PAPER, faults=[{'at': 0.1, 'fault': 'leakage_growth', 'severity': 5.0}])


class Raises(Algorithm):
    inputs = ('xj',)
    outputs = ('y',)

    def step(self, t, u):
        if t >= 0.05:
            raise ZeroDivisionError('boom')
        return {'y': u['xj']}


class Echo(Algorithm):
    inputs = ('com', 'cor', 'xs', 'qj')
    outputs = ('sum',)
    parameters = {'gain': 1.0}

    def step(self, t, u):
        return {'sum': self.params['gain'] * (u['com'] + u['cor'] + u['xs'] + u['qj']) + t}


@pytest.fixture(scope='module')
def live(tmp_path_factory):
    """The detector and the monitor live in the twin (HD plant, leak x5 from 0.1 s)."""
    import rclpy
    from rclpy.context import Context
    from rclpy.signals import SignalHandlerOptions
    ctx = Context()
    rclpy.init(context=ctx, signal_handler_options=SignalHandlerOptions.NO)
    bag = tmp_path_factory.mktemp('alg') / 'leaking'
    try:
        with Twin(TwinConfig('HD', LEAKING, bag=bag, monitor='SQ', algorithm=[DETECTOR, (Echo,
                  {'gain': 2.0})]), context=ctx) as twin:
            twin.run()
            values = {t: twin.recorder.values(t) for t in twin.recorder.float_topics
                      if t.startswith(('algorithm', 'monitor'))}
    finally:
        rclpy.try_shutdown(context=ctx)
    return bag, {k: (np.array(t), np.array(v)) for k, (t, v) in values.items()}


def test_one_algorithm_live_on_the_bag_and_in_a_sweep_identically(live):
    bag, values = live
    t_live, index_live = values['algorithm/leak_index']
    assert len(t_live) == 1001 and index_live.max() > 1.85
    # on the recorded bag, ROS-free: the same ticks, the same floats
    run = evaluate(bag, DETECTOR)
    np.testing.assert_array_equal(np.rint(run.t * 1e9).astype(np.int64), t_live)
    np.testing.assert_array_equal(run.outputs['leak_index'], index_live)
    np.testing.assert_array_equal(run.outputs['holding'], values['algorithm/holding'][1])
    # in a sweep: the same fault at the same onset on the ROS-free physics
    case = make_cases(plant_model='HD', faults={'leakage_growth': [5.0]}, nominal_runs=0,
                      onset=0.1, algorithm=DETECTOR)[0]
    swept = run_case(case)
    np.testing.assert_array_equal(swept['traces']['out_leak_index'], index_live)
    assert swept['row']['alarm'] == 1
    assert swept['row']['alarm_time'] == run.first()
    # a second algorithm beside it, with a parameter, and the built-in monitor likewise
    echo = evaluate(bag, Echo, {'gain': 2.0})
    np.testing.assert_array_equal(echo.outputs['sum'], values['algorithm/sum'][1])
    mon = evaluate(bag, MonitorAlgorithm())
    for name in MonitorAlgorithm.outputs:
        np.testing.assert_array_equal(mon.outputs[name], values[f'monitor/{name}'][1], name)


def test_algorithm_outputs_are_recorded_and_a_sweep_scores_them(live, tmp_path):
    bag, _ = live
    run = read_bag(bag)
    assert run.topics['/algorithm/leak_index'] == 1001
    assert run.topics['/algorithm_2/sum' if '/algorithm_2/sum' in run.topics
                      else '/algorithm/sum'] == 1001
    cases = make_cases(plant_model='HD', faults={'leakage_growth': [5.0, 10.0]},
                       nominal_runs=2, algorithm=DETECTOR, vary={'M': 0.1}, seed=3)
    rows = [r['row'] for r in run_cases(cases, workers=2)]
    assert [r['alarm'] for r in rows] == [0, 0, 1, 1]
    assert all(r['detection_delay'] > 0.1 for r in rows if r['faulty'])
    assert 'peak_leak_index' in rows[0] and rows[0]['peak_leak_index'] < 1.85


@pytest.mark.ros
def test_cli_run_evaluate_and_sweep_with_an_algorithm(tmp_path, capsys, monkeypatch):
    monkeypatch.syspath_prepend(str(EXAMPLE))
    bag = tmp_path / 'b'
    assert main(['run', '--valve-model', 'C2', '--scenario', 'defaults', '--bag', str(bag),
                 '--algorithm', DETECTOR, '--algorithm-param', 'threshold=1.5']) == 0
    assert main(['evaluate', str(bag), '--algorithm', DETECTOR, '--algorithm-param',
                 'threshold=1.5', '--json', str(tmp_path / 'e.json')]) == 0
    payload = json.loads((tmp_path / 'e.json').read_text())
    recorded = read_bag(bag).series['/algorithm/leak_index'][1]
    assert payload['outputs']['leak_index'] == recorded.tolist()
    assert payload['algorithm'] == 'LeakDetector' and payload['ticks'] == len(recorded)
    assert main(['sweep', '--fault', 'leakage_growth:10', '--nominal', '1', '--workers', '1',
                 '--algorithm', DETECTOR, '--out', str(tmp_path / 's')]) == 0
    summary = json.loads((tmp_path / 's' / 'summary.json').read_text())
    assert summary['false_alarms'] == 0
    assert summary['faults']['leakage_growth'][0]['detection_rate'] == 1.0
    assert (tmp_path / 's' / 'signature.png').stat().st_size > 1000


def test_missing_input_and_a_raising_algorithm_name_it_and_the_bag_survives(ros_context,
                                                                            tmp_path):
    class Wants(Algorithm):
        inputs = ('xj', 'temperature')
        outputs = ('y',)
    with pytest.raises(AlgorithmError, match="Wants: unknown input 'temperature'"):
        load_algorithm(Wants)
    bag = tmp_path / 'r'
    with pytest.raises(TwinError, match=r'algorithm Raises raised at t = 0\.050 s: '
                                        r'ZeroDivisionError: boom'):
        run_twin(TwinConfig('C2', 'defaults', bag=bag, algorithm=[Raises]), context=ros_context,
                 handle_signals=False)
    run = read_bag(bag)                               # finalized: metadata.yaml, summary
    assert 0.04 <= run.signals['t'][-1] <= 0.05
    with pytest.raises(AlgorithmError, match=r'Raises raised at t = 0\.050 s'):
        evaluate(bag, Raises)


# -- replay_into ----------------------------------------------------------------------------

class Pipeline(Node):
    """A user's node: doubles /value on a subscription, and counts on a 25 ms sim-time timer
    what it has seen."""

    def __init__(self, ctx, name='pipe', raw=False):
        super().__init__(name, context=ctx,
                         parameter_overrides=[Parameter('use_sim_time', value=True)])
        self.pub = self.create_publisher(Float64, 'doubled', 10)
        self.count_pub = self.create_publisher(Float64, 'seen', 10)
        self.seen = 0
        self.raw_bytes = []
        if raw:
            self.create_subscription(Float64, 'value', self.raw_bytes.append, 10, raw=True)
        else:
            self.create_subscription(Float64, 'value', self.on_value, 10)
        self.create_timer(0.025, self.on_timer)

    def on_value(self, msg):
        self.seen += 1
        self.pub.publish(Float64(data=2.0 * msg.data))

    def on_timer(self):
        self.count_pub.publish(Float64(data=float(self.seen)))


class Downstream(Node):
    def __init__(self, ctx):
        super().__init__('down', context=ctx,
                         parameter_overrides=[Parameter('use_sim_time', value=True)])
        self.pub = self.create_publisher(Float64, 'plus_one', 10)
        self.create_subscription(Float64, 'doubled',
                                 lambda m: self.pub.publish(Float64(data=m.data + 1.0)), 10)


def test_replay_into_order_time_and_routing(ros_context, tmp_path):
    written = write_bag(tmp_path / 'v4', storage='sqlite3', version=4)   # a rosbag2-written layout
    values = [(t, d) for topic, _, t, d in written if topic == '/value']
    t0 = values[0][0]
    out = replay_into([Pipeline(ros_context), Downstream(ros_context)], tmp_path / 'v4')
    # every message, in order, stamped with its log time; routed in-process downstream
    assert out.times('/doubled') == [t for t, _ in values]
    assert out.data('/doubled') == [2.0 * 0.5 * i for i in range(len(values))]
    assert out.data('/plus_one') == [2.0 * 0.5 * i + 1.0 for i in range(len(values))]
    assert out.times('/plus_one') == out.times('/doubled')
    # the sim-time timer fires at each of its deadlines (every 25 ms from t0, the bag's start)
    # and sees the messages logged up to and at that instant: /value comes every 10 ms
    stamps = out.times('/seen')
    assert stamps == [t0 + k * 25_000_000 for k in range(1, len(stamps) + 1)]
    assert out.data('/seen') == [float(1 + (k * 25) // 10) for k in range(1, len(stamps) + 1)]
    # a raw subscription gets the recorded bytes exactly
    raw = Pipeline(ros_context, 'raw_pipe', raw=True)
    replay_into(raw, tmp_path / 'v4', topics=['/value'])
    assert raw.raw_bytes == [d for _, d in values]
    with pytest.raises(TwinError, match="no topic '/nope'"):
        replay_into(raw, tmp_path / 'v4', topics=['/nope'])


def test_replay_into_is_deterministic_under_load(ros_context, twin_bag):
    """Two replays of a twin bag into the same kind of node, one with the other core saturated
    by a busy process: the outputs are the same, message for message."""
    from servovalve_twin.nodes.algorithm import AlgorithmNode
    from leak_detector import LeakDetector
    bag = twin_bag(faults=LEAKING['faults'])

    def once(name):
        node = AlgorithmNode(LeakDetector(), name=name, context=ros_context,
                             parameter_overrides=[Parameter('use_sim_time', value=True)])
        return replay_into(node, bag)
    quiet = once('quiet')
    hog = subprocess.Popen([sys.executable, '-c', 'while True: pass'])
    try:
        busy = once('busy')
    finally:
        hog.kill()
        hog.wait()
    assert quiet.keys() == busy.keys() and len(quiet['/algorithm/leak_index']) == 1000
    for topic in quiet:
        assert quiet[topic] == busy[topic], topic


@pytest.mark.slow
def test_the_worked_example_passes_as_a_users_test_suite():
    """doc/examples/my_detector's tests, run as a user runs them: the fixtures come from the
    installed package's pytest plugin, nothing from this repository's conftest."""
    r = subprocess.run([sys.executable, '-m', 'pytest', '-q', '-p', 'no:cacheprovider',
                        str(EXAMPLE)], capture_output=True,
                       text=True, timeout=600, cwd=EXAMPLE, env=dict(os.environ))
    print(r.stdout[-1500:], r.stderr[-500:])
    assert r.returncode == 0 and '3 passed' in r.stdout


class _Bad(Algorithm):
    """An algorithm that misbehaves the way ``how`` says (set as a class parameter)."""

    inputs = ('xj',)
    outputs = ('y',)
    parameters = {'how': ''}

    def __init__(self, **params):
        super().__init__(**params)
        if self.params['how'] == 'init':
            raise ZeroDivisionError('boom in init')

    def step(self, t, u):
        how = self.params['how']
        if how == 'exit':
            raise SystemExit(0)
        return {'y': {'bool': True, 'text': 'high', 'big': 10 ** 400}.get(how, 1.0)}

    def health(self):
        from servovalve_twin.prognostics import Health
        how = self.params['how']
        if how == 'level7':
            return Health(7, 'x')
        if how == 'message':
            return Health(1, 42)
        if how == 'key':
            return Health(1, 'x', {3: 1.0})
        return None


@pytest.mark.parametrize('how, fragment', [
    ('init', 'failed in __init__: ZeroDivisionError'),
    ('exit', 'raised at t = 0.000 s: SystemExit'),
    ('bool', 'must return a number'), ('text', 'must return a number'),
    ('big', 'must return a number'), ('level7', "level 7: expected OK"),
    ('message', 'message must be a string'), ('key', 'string keys')])
def test_a_misbehaving_algorithm_is_one_error_naming_it(how, fragment):
    """Every way a user's class can go wrong is an AlgorithmError naming the algorithm, never
    a traceback or a silent exit: a SystemExit in step() ended evaluate with rc 0 and no output,
    a health level 7 was scored as an alarm, a string key broke the diagnostics message."""
    from servovalve_twin.physics.params import DEFAULTS
    from servovalve_twin.prognostics.algorithm import run_algorithm
    with pytest.raises(AlgorithmError, match=fragment):
        alg = load_algorithm(_Bad, {'how': how})
        run_algorithm(alg, np.array([0, 1_000_000]), {'xj': np.zeros(2)}, 1e-3, DEFAULTS)


class _Steps(Algorithm):
    """A threshold on xj, tick by tick and, unless ``how`` says otherwise, in one call."""

    inputs = ('xj',)
    outputs = ('y',)
    parameters = {'how': 'right'}

    def step(self, t, u):
        self._y = 2.0 * u['xj'] + t
        return {'y': self._y}

    def health(self):
        from servovalve_twin.prognostics import Health
        level = ERROR if self._y > 0.5 else WARN if self._y > 0.2 else 0
        return Health(level, f'level {level}')

    def steps(self, t, u):
        how = self.params['how']
        if how == 'none':
            return None
        y = 2.0 * u[:, 0] + t
        level = np.where(y > 0.5, ERROR, np.where(y > 0.2, WARN, 0))
        if how == 'shape':
            return y[:-1, None], level, []
        if how == 'level':
            return y[:, None], level + 5, []
        if how == 'raise':
            raise ZeroDivisionError('boom in steps')
        changes = [(int(k), f'level {level[k]}') for k in range(len(y))
                   if level[k] and (k == 0 or level[k] != level[k - 1])]
        return y[:, None], level, changes


def test_an_algorithms_steps_is_what_stepping_gives_and_is_checked():
    """A host holding a whole run uses ``steps``; its result is the tick-by-tick one (outputs,
    levels, a message at each change of level, WARN -> ERROR included) and a wrong shape, a
    level outside OK/WARN/ERROR or an exception is one error naming the algorithm."""
    from servovalve_twin.physics.params import DEFAULTS
    from servovalve_twin.prognostics.algorithm import run_algorithm
    t_ns = np.arange(600, dtype=np.int64) * 1_000_000
    xj = {'xj': np.full(600, 0.05)}
    block = run_algorithm(_Steps(), t_ns, xj, 1e-3, DEFAULTS)
    ticks = run_algorithm(_Steps(how='none'), t_ns, xj, 1e-3, DEFAULTS)
    np.testing.assert_array_equal(block.outputs['y'], 0.1 + t_ns * 1e-9)
    np.testing.assert_array_equal(block.outputs['y'], ticks.outputs['y'])
    np.testing.assert_array_equal(block.level, ticks.level)
    assert ticks.messages == block.messages == ['level 1', 'level 2']
    assert ticks.first(WARN) == pytest.approx(0.101) and ticks.first(ERROR) == \
        pytest.approx(0.401)
    for how, fragment in (('shape', 'outputs of shape'), ('level', 'a health level outside'),
                          ('raise', 'raised between t = 0.000 and 0.599 s: ZeroDivisionError')):
        with pytest.raises(AlgorithmError, match=fragment):
            run_algorithm(_Steps(how=how), t_ns, xj, 1e-3, DEFAULTS)
