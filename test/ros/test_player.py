"""Reading any rosbag2 bag and playing it on the ROS graph (``servovalve-twin play``): bags
written here in real rosbag2 layouts (MCAP and sqlite3, metadata v4 and v9, split, compressed),
received by an independent raw subscriber, byte for byte."""

import os
import signal
import subprocess
import sys
import time

import pytest
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock
from std_msgs.msg import Float64
from std_srvs.srv import Trigger

from bagmaker import write_bag
from servovalve_twin.bag.anybag import open_any_bag
from servovalve_twin.errors import BagError
from servovalve_twin.nodes.player import Player, PlayOptions
from conftest import ROOT, answer

LAYOUTS = [
    dict(storage='mcap', version=9),
    dict(storage='mcap', version=9, compression='zstd', split=2),
    dict(storage='mcap', version=4, compression='lz4'),
    dict(storage='sqlite3', version=4),
    dict(storage='sqlite3', version=9, split=2),
]


def _ids(layouts):
    return ['-'.join(f'{v}' for v in d.values()) for d in layouts]


@pytest.mark.parametrize('layout', LAYOUTS, ids=_ids(LAYOUTS))
def test_any_bag_yields_every_message_exactly(tmp_path, layout):
    written = write_bag(tmp_path / 'b', **layout)
    bag = open_any_bag(tmp_path / 'b')
    got = list(bag.messages())
    assert [(t, n, d) for t, _, n, d in written] == got
    assert bag.message_count == len(written) and len(bag.files) == layout.get('split', 1)
    assert bag.topics['/value'].type == 'std_msgs/msg/Float64'
    # v4 stored integer policies in a YAML string: read as the v9 names
    fast = bag.topics['/fast'].qos[0]['reliability']
    assert fast == ('best_effort' if layout['version'] == 4 else 'reliable')
    some = list(bag.messages(topics=['/value'], start_ns=written[10][2], end_ns=written[40][2]))
    assert some == [(t, n, d) for t, _, n, d in written
                    if t == '/value' and written[10][2] <= n <= written[40][2]]


def test_bare_storage_files_and_bad_input(tmp_path):
    written = write_bag(tmp_path / 'm', storage='mcap')
    write_bag(tmp_path / 's', storage='sqlite3', version=4)
    for f in (tmp_path / 'm' / 'm_0.mcap', tmp_path / 's' / 's_0.db3'):
        assert len(list(open_any_bag(f).messages())) == len(written)
    ros1 = tmp_path / 'old.bag'
    ros1.write_bytes(b'#ROSBAG V2.0\n' + b'\x00' * 64)
    with pytest.raises(BagError, match='ROS 1 bag, not a rosbag2 bag'):
        open_any_bag(ros1)
    (tmp_path / 'm' / 'm_0.mcap').write_bytes(b'\x89MCAP0\r\n' + b'\x00' * 40)
    with pytest.raises(BagError, match='truncated or corrupt|holds no messages'):
        open_any_bag(tmp_path / 'm')
    with pytest.raises(BagError, match='no bag at'):
        open_any_bag(tmp_path / 'missing')


def _drive(ctx, bag_path, options, *, topics=('/value', '/fast'), qos_reliable=True,
           timeout=120.0, stop_after=None):
    """Play in-process beside an independent raw subscriber; start once every publisher has
    matched its subscriber (no discovery race), then collect until the end."""
    bag = open_any_bag(bag_path)
    sub_node = Node('probe', context=ctx)
    got = {t: [] for t in topics}
    clock = []
    qos = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE if qos_reliable
                     else ReliabilityPolicy.BEST_EFFORT)
    for t in topics:
        sub_node.create_subscription(Float64, t, lambda m, t=t: got[t].append(m), qos, raw=True)
    sub_node.create_subscription(Clock, '/clock', lambda m: clock.append(
        m.clock.sec * 1_000_000_000 + m.clock.nanosec), 100)
    player = Player(bag, PlayOptions(**dict(options, start_paused=True)), context=ctx)
    ex = SingleThreadedExecutor(context=ctx)
    ex.add_node(player)
    ex.add_node(sub_node)
    try:
        deadline = time.monotonic() + timeout
        while not all(p.get_subscription_count() >= 1 for p in player.pubs.values()):
            ex.spin_once(timeout_sec=0.05)
            assert time.monotonic() < deadline, 'subscriber never matched'
        player._set_paused(options.get('start_paused', False))
        wall0 = time.monotonic()
        next_clock = 0.0
        while not player.finished and time.monotonic() < deadline:
            wait = player.step(0.01)
            if player.clock_pub is not None and time.monotonic() >= next_clock:
                player.publish_clock()
                next_clock = time.monotonic() + 1.0 / options['clock']
            ex.spin_once(timeout_sec=min(wait, 0.01))
            if stop_after is not None and player.published >= stop_after:
                break
        wall = time.monotonic() - wall0
        player.publish_clock()
        remaps = player.options.remaps()
        heard = [t for t in player.pubs if remaps.get(t, t) in got]
        expected = sum(1 for _ in bag.messages(topics=heard))
        end = time.monotonic() + 30
        while sum(len(v) for v in got.values()) < min(player.published, expected) and \
                time.monotonic() < end:
            ex.spin_once(timeout_sec=0.05)
        for _ in range(20):
            ex.spin_once(timeout_sec=0.01)
        return player, got, clock, wall
    finally:
        ex.shutdown()
        player.destroy_node()
        sub_node.destroy_node()


@pytest.mark.parametrize('layout', [LAYOUTS[1], LAYOUTS[4]], ids=_ids([LAYOUTS[1], LAYOUTS[4]]))
def test_player_publishes_every_message_as_recorded(ros_context, tmp_path, layout):
    written = write_bag(tmp_path / 'b', **layout)
    player, got, clock, wall = _drive(ros_context, tmp_path / 'b',
                                      dict(rate=4.0, clock=100.0))
    for topic in ('/value', '/fast'):
        assert got[topic] == [d for t, _, _, d in written if t == topic], topic
    # the uninstalled type is skipped with one warning naming it; the bag's /clock is replaced
    assert any('/custom' in w and 'demo_msgs/msg/Reading' in w for w in player.warnings)
    assert '/clock' not in player.pubs and '/custom' not in player.pubs
    assert clock == sorted(clock) and clock[-1] == written[-1][2]
    assert clock[0] >= written[0][2] and len(set(clock)) > 3
    duration = (written[-1][2] - written[0][2]) * 1e-9
    print(f'{len(written)} messages, bag {duration:.2f} s played at rate 4 in {wall:.2f} s')
    assert wall >= duration / 4 * 0.95                  # paced, never ahead of the bag


def test_player_options(ros_context, tmp_path):
    written = write_bag(tmp_path / 'b', storage='mcap', version=4)
    t0 = written[0][2]
    values = [(n, d) for t, _, n, d in written if t == '/value']
    # start offset, playback duration, topic selection, remap
    player, got, _, _ = _drive(ros_context, tmp_path / 'b', dict(
        rate=10.0, start_offset=0.2, playback_duration=0.1, topics=('/value',),
        remap=('/value:=/renamed',)), topics=('/renamed',))
    assert set(player.pubs) == {'/value'}
    assert got['/renamed'] == [d for n, d in values if t0 + 2e8 <= n <= t0 + 3e8]
    # excluded topics; QoS from the v4 integers: /fast was recorded best effort
    player, got, _, _ = _drive(ros_context, tmp_path / 'b', dict(
        rate=20.0, exclude_topics=('/value',)), topics=('/fast',), qos_reliable=False)
    assert set(player.pubs) == {'/fast', '/clock'}      # without --clock the bag's own plays
    assert player.pubs['/fast'].qos_profile.reliability == ReliabilityPolicy.BEST_EFFORT
    # loop: the bag again from its start
    player, got, _, _ = _drive(ros_context, tmp_path / 'b', dict(
        rate=50.0, loop=True, topics=('/value',)), topics=('/value',),
        stop_after=len(values) + 5)
    assert got['/value'][:len(values) + 5] == [d for _, d in values] + [d for _, d in values[:5]]


def test_play_executable_services_signals_and_bad_bags(ros_context, tmp_path):
    write_bag(tmp_path / 'b', storage='sqlite3', version=9)
    env = dict(os.environ, PYTHONUNBUFFERED='1')
    proc = subprocess.Popen([sys.executable, '-m', 'servovalve_twin.cli', 'play',
                             str(tmp_path / 'b'), '--start-paused', '--rate', '0.05'],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
                            cwd=ROOT)
    node = Node('client', context=ros_context)
    ex = SingleThreadedExecutor(context=ros_context)
    ex.add_node(node)

    def call(name):
        cli = node.create_client(Trigger, f'/player/{name}')
        assert cli.wait_for_service(timeout_sec=120), name
        fut = cli.call_async(Trigger.Request())
        ex.spin_until_future_complete(fut, timeout_sec=60)
        return fut.result()
    try:
        assert call('is_paused').success
        assert call('play_next').success                 # one message while paused
        assert call('resume').success and not call('is_paused').success
        assert call('toggle_paused').message == 'paused' and call('is_paused').success
        proc.send_signal(signal.SIGTERM)
        out, err = proc.communicate(timeout=60)
        print(out, err[-500:])
        assert proc.returncode == 0 and 'Traceback' not in err
        assert 'play: stopped:' in out and "skipping /custom" in err
    finally:
        if proc.poll() is None:
            proc.kill()
        ex.shutdown()
        node.destroy_node()
    for bad, fragment in ((tmp_path / 'nope', 'no bag at'), (ROOT / 'README.md',
                                                           'not a rosbag2 storage file')):
        r = subprocess.run([sys.executable, '-m', 'servovalve_twin.cli', 'play', str(bad)],
                           capture_output=True, text=True, timeout=120, cwd=ROOT)
        assert r.returncode == 2 and fragment in r.stderr and r.stderr.count('\n') == 1, r.stderr


def test_a_bag_type_name_never_imports_a_module_that_is_not_a_message_package(tmp_path):
    """A crafted bag names its type `evilpkg/msg/Foo` (or `this/msg/Foo`, which prints the Zen
    of Python on import): resolving it must not run that package's import-time code; an
    installed rosidl package still resolves."""
    import os
    import subprocess
    import sys
    pkg = tmp_path / 'evilpkg'
    (pkg / 'msg').mkdir(parents=True)
    marker = tmp_path / 'imported'
    (pkg / '__init__.py').write_text(f'open({str(marker)!r}, "w").close()\n')
    (pkg / 'msg' / '__init__.py').write_text('Foo = 1\n')
    code = ('import sys\nfrom servovalve_twin.nodes.player import message_class\n'
            "assert message_class('evilpkg/msg/Foo') is None\n"
            "assert message_class('this/msg/Foo') is None and 'this' not in sys.modules\n"
            "assert message_class('std_msgs/msg/Float64').__name__ == 'Float64'\n")
    r = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                       env={**os.environ, 'PYTHONPATH': os.pathsep.join(filter(None, (
                           str(tmp_path), os.environ.get('PYTHONPATH'))))},
                       timeout=120)
    assert r.returncode == 0, r.stderr
    assert not marker.exists() and 'Beautiful is better' not in r.stdout


@pytest.mark.ros
def test_the_player_executable_holds_its_options_as_parameters(ros_context, tmp_path):
    """``ros2 param get /player rate`` answers, with an integer given for the double stored as
    the double, arrays as string arrays (empty ones too), and no option changes mid-play."""
    from rclpy.parameter import Parameter
    from rclpy.parameter_client import AsyncParameterClient
    from conftest import console_script
    write_bag(tmp_path / 'b', storage='mcap', version=9)
    proc = subprocess.Popen([console_script('player'), '--ros-args', '-p',
                             f'bag:={tmp_path / "b"}', '-p', 'rate:=2', '-p',
                             "topics:=['/value']", '-p', 'start_paused:=true'],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    node = Node('asker', context=ros_context)
    ex = SingleThreadedExecutor(context=ros_context)
    ex.add_node(node)
    client = AsyncParameterClient(node, '/player')
    names = ['bag', 'rate', 'topics', 'exclude_topics', 'start_paused', 'clock', 'remap']
    try:
        assert client.wait_for_services(timeout_sec=120)
        got = {n: Parameter.from_parameter_msg(
            __import__('rcl_interfaces.msg', fromlist=['Parameter']).Parameter(name=n, value=v))
            for n, v in zip(names, answer(ex, lambda: client.get_parameters(names)).values)}
        assert got['bag'].value == str(tmp_path / 'b')
        assert got['rate'].type_ == Parameter.Type.DOUBLE and got['rate'].value == 2.0
        assert got['topics'].type_ == Parameter.Type.STRING_ARRAY
        assert list(got['topics'].value) == ['/value']
        assert got['exclude_topics'].type_ == Parameter.Type.STRING_ARRAY
        assert list(got['exclude_topics'].value) == []
        assert got['start_paused'].value is True and got['clock'].value == 0.0
        for p in (Parameter('rate', value=4.0), Parameter('topics', value=['/fast'])):
            assert not answer(ex, lambda: client.set_parameters([p])).results[0].successful, \
                p.name
    finally:
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=60)
        ex.shutdown()
        node.destroy_node()
    print(out, err[-800:])
    assert proc.returncode == 0 and 'Traceback' not in err


@pytest.mark.ros
def test_play_values_never_reach_rcl_as_its_own_arguments(tmp_path):
    """rcl read the whole command line: a --remap value became a (deprecated) global remap
    rule of rcl's, a --topics value could rename the node. Only the player uses them now."""
    r = subprocess.run([sys.executable, '-m', 'servovalve_twin.cli', 'play', '@paper_HD', '-r',
                        '1000', '--remap', '/xj:=/xj_renamed', '--topics', '/xj', '/com'],
                       capture_output=True, text=True, timeout=300, cwd=tmp_path)
    print(r.stdout, r.stderr)
    assert r.returncode == 0 and '[rcl]' not in r.stderr and 'deprecated' not in r.stderr
    assert 'play: done: 2002 messages' in r.stdout
    # a rule of rcl's given as a topic is the player's topic (one the bag lacks), not rcl's
    r = subprocess.run([sys.executable, '-m', 'servovalve_twin.cli', 'play', '@paper_HD',
                        '--topics', '/xj', '__node:=renamed'], capture_output=True, text=True,
                       timeout=300, cwd=tmp_path)
    assert r.returncode == 2 and 'topics /__node:=renamed: not in the bag' in r.stderr


SLOW_SUBSCRIBER = r'''
import json, sys, time
import rclpy
from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from std_msgs.msg import Float64
topics, expected = sys.argv[1].split(','), int(sys.argv[2])
rclpy.init()
node = Node('slow_subscriber')
counts = {t: 0 for t in topics}
last = [time.monotonic()]

def make(topic):
    def cb(_msg):
        counts[topic] += 1
        last[0] = time.monotonic()
        end = time.perf_counter() + 50e-6            # a callback that takes its time
        while time.perf_counter() < end:
            pass
    return cb
qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=2 * expected,
                 reliability=ReliabilityPolicy.RELIABLE)
subs = [node.create_subscription(Float64, t, make(t), qos) for t in topics]
print('ready', flush=True)
while min(counts.values()) < expected and time.monotonic() - last[0] < 20:
    rclpy.spin_once(node, timeout_sec=0.1)
print(json.dumps(counts), flush=True)
'''


def _slow_subscriber(topics, expected):
    """SLOW_SUBSCRIBER in a process of its own, once it says it is subscribed."""
    sub = subprocess.Popen([sys.executable, '-c', SLOW_SUBSCRIBER, ','.join(topics),
                            str(expected)], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                           text=True)
    if sub.stdout.readline().strip() != 'ready':
        sub.kill()
        raise AssertionError(sub.stderr.read())
    return sub


def test_the_player_never_outruns_a_reliable_subscriber(ros_context):
    """At -r 1000 a reliable subscriber in another process, with a callback of 50 us and a
    history deep enough for the whole bag, receives every message: the player waits for its
    acknowledgements (it lost 14-23 % when the player's keep-last-10 history overwrote what it
    had not yet received)."""
    import json
    from servovalve_twin.nodes.player import play
    bag = ROOT / 'servovalve_twin' / 'data' / 'paper_HD'
    info = open_any_bag(bag).topics
    topics = sorted(t for t, i in info.items() if i.type == 'std_msgs/msg/Float64')
    expected = info['/xj'].count
    sub = _slow_subscriber(topics, expected)
    try:

        def matched(player):
            # discovery, not a sleep: the subscriber is matched on every played topic
            deadline = time.monotonic() + 120
            while min(player.pubs[t].get_subscription_count() for t in topics) < 1:
                assert time.monotonic() < deadline and sub.poll() is None
                time.sleep(0.01)
        result = play(bag, PlayOptions(rate=1000.0, topics=tuple(topics)),
                      context=ros_context, on_ready=matched)
        out, err = sub.communicate(timeout=120)
    finally:
        sub.kill()
    counts = json.loads(out.strip().splitlines()[-1])
    print(f'{result["published"]} published in {result["wall_s"]:.2f} s; received {counts}')
    assert result['published'] == len(topics) * expected and not result['warnings']
    assert counts == {t: expected for t in topics}


def test_the_player_waits_for_its_subscribers_before_the_first_message(ros_context):
    """--wait-for-subscribers 1 at -r 1000: a reliable subscriber started in another process
    just before receives all 1001 messages of each topic, the first included -- without a
    wait the first 0.2 s of the bag went out before it had matched (800 of 1001, 1 run in
    4). The player itself, not the test, waits for the match."""
    import json
    from servovalve_twin.nodes.player import play
    bag = ROOT / 'servovalve_twin' / 'data' / 'paper_HD'
    info = open_any_bag(bag).topics
    topics = ['/xj', '/p12']
    expected = info['/xj'].count
    sub = _slow_subscriber(topics, expected)
    try:
        result = play(bag, PlayOptions(rate=1000.0, topics=tuple(topics),
                                       wait_for_subscribers=1), context=ros_context)
        out, err = sub.communicate(timeout=120)
    finally:
        sub.kill()
    counts = json.loads(out.strip().splitlines()[-1])
    assert counts == {t: expected for t in topics}
    assert result['published'] == 2 * expected


@pytest.mark.parametrize('n', [-1, 1.5, True, 10_000])
def test_wait_for_subscribers_takes_a_whole_count(n):
    from servovalve_twin.errors import TwinError
    with pytest.raises(TwinError, match='wait_for_subscribers must be a whole number'):
        PlayOptions(wait_for_subscribers=n).check()
