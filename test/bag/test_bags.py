"""Bags: exact CDR bytes, the rosbag2 layout, independent readers, provenance, interruption,
reindexing, corrupt input."""

import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
import yaml

from servovalve_twin.bag import cdr
from servovalve_twin.bag.reader import read_bag
from servovalve_twin.cli import main
from servovalve_twin.errors import BagError
from servovalve_twin.twin import TwinConfig, run_twin
from cases import short
from conftest import ROOT

SHORT = short(0.3, load_at=0.1, drop_at=0.2)


@pytest.fixture(scope='module')
def hd_bag(tmp_path_factory):
    """A recorded HD run and what the twin published (kept values)."""
    import rclpy
    from rclpy.context import Context
    from rclpy.signals import SignalHandlerOptions
    ctx = Context()
    rclpy.init(context=ctx, signal_handler_options=SignalHandlerOptions.NO)
    try:
        path = tmp_path_factory.mktemp('bags') / 'short_HD'
        result = run_twin(TwinConfig('HD', SHORT, bag=path, clock_period=1e-3), context=ctx,
                          handle_signals=False)
    finally:
        rclpy.try_shutdown(context=ctx)
    return path, result


def test_encoders_equal_raw_wire_bytes(ros_context):
    """Our CDR encoders against what rmw_fastrtps puts on the wire (raw subscriptions)."""
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from rosgraph_msgs.msg import Clock
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64
    from servovalve_twin.nodes.topics import QOS, joint_state
    node = Node('cdr_probe', context=ros_context)
    got = {}
    msgs = {}
    f = Float64()
    f.data = -1.234567890123e-7
    msgs['f64'] = (Float64, f, cdr.encode_float64)
    c = Clock()
    c.clock.sec, c.clock.nanosec = 12, 345678901
    msgs['clock'] = (Clock, c, cdr.encode_clock)
    msgs['jack'] = (JointState, joint_state(1_234_567_890, 0.0123, -0.2, 1.5e4),
                    cdr.encode_joint_state)
    other = JointState()
    other.header.frame_id = 'base_link'
    other.name = ['a', 'bb', 'ccc']
    other.position = [1.0, 2.0, 3.0]
    other.velocity = []
    other.effort = [0.5]
    msgs['other'] = (JointState, other, cdr.encode_joint_state)
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
    diag = DiagnosticArray()
    diag.header.stamp.sec = 7
    st = DiagnosticStatus()
    st.level = DiagnosticStatus.ERROR
    st.name, st.message, st.hardware_id = 'servovalve_twin: EHA monitor', 'ERROR: xj', 'eha'
    st.values = [KeyValue(key='residual_xj', value='0.0123'), KeyValue(key='k', value='')]
    diag.status = [st, DiagnosticStatus()]
    msgs['diag'] = (DiagnosticArray, diag, cdr.encode_diagnostic_array)
    pubs = {}
    for key, (typ, _, _) in msgs.items():
        node.create_subscription(typ, f'probe_{key}', lambda data, k=key: got.setdefault(k, data),
                                 QOS, raw=True)
        pubs[key] = node.create_publisher(typ, f'probe_{key}', QOS)
    ex = SingleThreadedExecutor(context=ros_context)
    ex.add_node(node)
    deadline = time.monotonic() + 10
    while len(got) < len(msgs) and time.monotonic() < deadline:
        for key, (_, msg, _) in msgs.items():
            if key not in got:
                pubs[key].publish(msg)
        ex.spin_once(timeout_sec=0.05)
    ex.shutdown()
    node.destroy_node()
    for key, (_, msg, enc) in msgs.items():
        print(key, len(got[key]), 'bytes on the wire')
        assert enc(msg) == bytes(got[key]), key
    assert cdr.encode_joint_state_general(msgs['jack'][1]) == cdr.encode_joint_state(
        msgs['jack'][1])


def test_rosbag2_layout(hd_bag):
    from mcap.reader import make_reader
    path, _ = hd_bag
    assert sorted(p.name for p in path.iterdir()) == ['metadata.yaml', 'short_HD_0.mcap']
    meta = yaml.safe_load((path / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    assert meta['version'] == 9 and meta['storage_identifier'] == 'mcap'
    assert meta['relative_file_paths'] == ['short_HD_0.mcap'] and meta['ros_distro'] == 'jazzy'
    assert isinstance(meta['topics_with_message_count'][0]['topic_metadata'][
        'offered_qos_profiles'], list)
    with open(path / 'short_HD_0.mcap', 'rb') as fh:
        reader = make_reader(fh)
        header = reader.get_header()
        summary = reader.get_summary()
        assert header.profile == 'ros2'
        for schema in summary.schemas.values():
            assert schema.encoding == 'ros2msg'
        js = next(s for s in summary.schemas.values() if s.name == 'sensor_msgs/msg/JointState')
        text = js.data.decode()
        assert '\n' + '=' * 80 + '\nMSG: std_msgs/Header\n' in text
        assert 'MSG: builtin_interfaces/Time' in text
        for ch in summary.channels.values():
            assert ch.message_encoding == 'cdr'
            assert set(ch.metadata) == {'offered_qos_profiles', 'topic_type_hash'}
            assert ch.metadata['topic_type_hash'].startswith('RIHS01_')
            # every field of the v9 profile as `ros2 bag record` writes it (BAGS.md 5.2): the
            # offered QoS seen through discovery has history unknown and depth 0
            infinite = {'sec': 9223372036, 'nsec': 854775807}
            assert yaml.safe_load(ch.metadata['offered_qos_profiles']) == [{
                'history': 'unknown', 'depth': 0, 'reliability': 'reliable',
                'durability': 'volatile', 'deadline': infinite, 'lifespan': infinite,
                'liveliness': 'automatic', 'liveliness_lease_duration': infinite,
                'avoid_ros_namespace_conventions': False}]
        # rosbag2 stamps publish_time; the twin's is the tick's simulated time, the log time
        n = 0
        for _, _, message in reader.iter_messages():
            assert message.publish_time == message.log_time
            n += 1
        assert n == meta['message_count']
        metadata = {m.name: m.metadata for m in reader.iter_metadata()}
    embedded = yaml.safe_load(metadata['rosbag2']['serialized_metadata'])
    assert embedded['message_count'] == meta['message_count']
    prov = metadata['servovalve_twin']
    assert prov['valve_model'] == 'HD' and prov['version']
    assert yaml.safe_load(prov['params'])['M'] == 500.0
    assert yaml.safe_load(prov['scenario'])['fr'] == [[0.0, 0.0], [0.1, 5000.0]]
    print('bag', sum(f.stat().st_size for f in path.iterdir()), 'bytes,',
          meta['message_count'], 'messages')


def test_rosbags_anyreader_decodes_every_value(hd_bag):
    from rosbags.highlevel import AnyReader
    path, result = hd_bag
    decoded = {}
    with AnyReader([path]) as reader:
        for conn, t, raw in reader.messages():
            msg = reader.deserialize(raw, conn.msgtype)
            decoded.setdefault(conn.topic, []).append((t, msg))
    for col in ('com', 'fr', 'psr', 'cor', 'xs', 'xj', 'dxj', 'p12', 'qj', 'p1', 'p2'):
        got = [(t, m.data) for t, m in decoded[f'/{col}']]
        times, values = result_values(result, col)
        assert [t for t, _ in got] == times
        assert [v for _, v in got] == values, col
    js = decoded['/joint_states']
    xj_t, xj_v = result_values(result, 'xj')
    assert [m.position[0] for _, m in js] == xj_v
    assert [m.header.stamp.sec * 10**9 + m.header.stamp.nanosec for _, m in js] == xj_t
    clock = [m.clock.sec * 10**9 + m.clock.nanosec for _, m in decoded['/clock']]
    assert clock == [t for t, _ in decoded['/clock']] and len(clock) == 301


def result_values(result, col):
    from servovalve_twin.bag.reader import read_bag
    run = read_bag(result.bag)
    t, v = run.series[f'/{col}']
    return t.tolist(), v.tolist()


def test_rosbags_reader_without_metadata_and_mcap_ros2(hd_bag):
    from mcap_ros2.reader import read_ros2_messages
    from rosbags.highlevel import AnyReader
    path, _ = hd_bag
    mcap_file = path / 'short_HD_0.mcap'
    with AnyReader([mcap_file]) as reader:
        n_any = sum(1 for _ in reader.messages())
    n = 0
    values = []
    for m in read_ros2_messages(str(mcap_file)):
        n += 1
        if m.channel.topic == '/xj':
            values.append(m.ros_msg.data)
    assert n == n_any
    assert values == read_bag(path).series['/xj'][1].tolist()


def test_replay_source_values_survive_a_round_trip(hd_bag):
    path, result = hd_bag
    run = read_bag(path)
    ref = result.signals
    for col in ref:
        np.testing.assert_array_equal(run.signals[col], ref[col])


def _spawn_run(tmp_path, bag, duration=60.0):
    scenario = tmp_path / 'long.yaml'
    scenario.write_text(f'duration: {duration}\ncom: {{sine: {{amplitude: 0.02, '
                        'frequency: 1.0}}\n')
    env = dict(os.environ, PYTHONUNBUFFERED='1')
    return subprocess.Popen([sys.executable, '-m', 'servovalve_twin.cli', 'run', '--valve-model',
                             'C2', '--scenario', str(scenario), '--bag', str(bag), '--progress'],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
                            cwd=ROOT)


def _wait_progress(proc, until_s):
    """Read the run's '... flushed up to T s' lines until T >= until_s; returns the last T."""
    t = -1.0
    while t < until_s:
        line = proc.stdout.readline()
        if not line:
            raise AssertionError('run ended early: ' + proc.stderr.read()[-2000:])
        if line.startswith('flushed up to'):
            t = float(line.split()[3])
    return t


@pytest.mark.ros
@pytest.mark.parametrize('sig', [signal.SIGINT, signal.SIGTERM])
def test_interrupted_run_leaves_a_readable_bag(tmp_path, sig):
    bag = tmp_path / 'interrupted'
    proc = _spawn_run(tmp_path, bag)
    _wait_progress(proc, 0.5)
    proc.send_signal(sig)
    out, err = proc.communicate(timeout=60)
    print(sig.name, 'exit', proc.returncode, out.strip().splitlines()[-1:], err[-300:])
    assert proc.returncode == 130 and 'INTERRUPTED' in out
    run = read_bag(bag)                       # metadata.yaml written, summary intact
    assert 0.5 <= run.signals['t'][-1] < 60.0
    assert (bag / 'metadata.yaml').is_file()


@pytest.mark.ros
def test_killed_run_is_recovered_by_reindex(tmp_path):
    bag = tmp_path / 'killed'
    proc = _spawn_run(tmp_path, bag)
    flushed = _wait_progress(proc, 0.5)
    proc.kill()
    proc.wait(timeout=30)
    assert not (bag / 'metadata.yaml').exists()
    with pytest.raises(BagError, match='reindex'):
        read_bag(bag)
    assert main(['reindex', str(bag)]) == 0
    run = read_bag(bag)
    # the provenance record survives: without it replay would fall back to C2 with defaults
    assert run.valve_model == 'C2' and run.control_period == 1e-3
    assert run.params()['M'] == 500.0 and run.scenario()['duration'] == 60.0
    from mcap.reader import make_reader
    with open(next(bag.glob('*.mcap')), 'rb') as fh:
        names = [m.name for m in make_reader(fh).iter_metadata()]
    assert sorted(names) == ['rosbag2', 'servovalve_twin']    # rebuilt, not duplicated
    last = run.series['/xj'][0][-1] * 1e-9
    print(f'killed after the flush at {flushed:.3f} s of simulated time; recovered up to '
          f'{last:.3f} s')
    # every chunk flushed before the kill is there: at most 50 ms (the flush period) is lost
    assert last >= flushed - 0.05 - 1e-9


def test_corrupt_and_truncated_bags_are_clear_errors(hd_bag, tmp_path, capsys):
    path, _ = hd_bag
    data = (path / 'short_HD_0.mcap').read_bytes()
    trunc = tmp_path / 'trunc'
    trunc.mkdir()
    (trunc / 'trunc_0.mcap').write_bytes(data[: len(data) // 2])
    (trunc / 'metadata.yaml').write_text((path / 'metadata.yaml').read_text())
    garbage = tmp_path / 'garbage'
    garbage.mkdir()
    (garbage / 'garbage_0.mcap').write_bytes(b'not an mcap file at all' * 10)
    (garbage / 'metadata.yaml').write_text('x: 1\n')
    for bad in (trunc, garbage, tmp_path / 'missing'):
        for args in (['compare', str(path), str(bad)], ['replay', str(bad)]):
            assert main(args) == 2
            err = capsys.readouterr().err
            print(err.strip())
            assert err.count('\n') == 1 and 'Traceback' not in err
    # a truncated bag is still recoverable
    assert main(['reindex', str(trunc)]) == 0
    assert read_bag(trunc).signals['t'][-1] > 0.05


def test_a_fresh_hd_run_records_the_reference_bags_messages(ros_context, tmp_path):
    """The packaged @paper_HD bag was recorded before the twin's nodes handed their values
    over in process and before the recorder packed every topic at once: a fresh run must
    still record the same 12 113 messages -- topics, times, CDR bytes, order -- and the
    same message index (a reader seeking by time sees the same)."""
    from servovalve_twin.bag.anybag import open_any_bag
    from servovalve_twin.config import reference_dir
    from servovalve_twin.twin import TwinConfig, run_twin
    run_twin(TwinConfig('HD', 'paper', bag=tmp_path / 'paper_HD'), keep_values=False,
             context=ros_context, handle_signals=False)
    ref = list(open_any_bag(reference_dir() / 'paper_HD').messages())
    new = list(open_any_bag(tmp_path / 'paper_HD').messages())
    assert len(new) == len(ref) == 12113
    assert new == ref
    with open(tmp_path / 'paper_HD' / 'paper_HD_0.mcap', 'rb') as fa, \
            open(reference_dir() / 'paper_HD' / 'paper_HD_0.mcap', 'rb') as fb:
        from mcap.reader import make_reader
        a, b = make_reader(fa).get_summary(), make_reader(fb).get_summary()
        assert [(c.message_start_time, c.message_end_time, c.uncompressed_size)
                for c in a.chunk_indexes] == [(c.message_start_time, c.message_end_time,
                                               c.uncompressed_size) for c in b.chunk_indexes]


def test_a_bags_design_derives_its_derived_parameters_again():
    """Provenance.eha_params of a run's record: the design, with its derived parameters left
    to derive (a flight calibration's leak units of the shipped example stopped on C4_alpha)."""
    from servovalve_twin.bag.provenance import Provenance
    from servovalve_twin.config import load_scenario
    from servovalve_twin.physics.params import DEFAULTS
    prov = Provenance.build('HD', load_scenario('paper'), DEFAULTS.replace(M=450.0), 1e-3)
    design = prov.eha_params()
    assert design.M == 450.0 and design.C4_alpha is None and design.XSS is None
    design.replace(CLk=DEFAULTS.CLk * 50)                     # no longer refused
