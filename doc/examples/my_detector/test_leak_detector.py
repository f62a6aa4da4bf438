"""The detector's tests as a user writes them in their own package: the fixtures ``ros_context``,
``replay`` and ``twin_bag`` come with servovalve_twin (its pytest plugin); the node under test is
the detector in the twin's ``algorithm`` node, fed bags of the twin deterministically."""

from rclpy.parameter import Parameter

from leak_detector import LeakDetector
from servovalve_twin.nodes.algorithm import AlgorithmNode
from servovalve_twin.prognostics import ERROR

LEAK = [{'at': 0.1, 'fault': 'leakage_growth', 'severity': 5.0}]


def detector(ros_context):
    return AlgorithmNode(LeakDetector(), context=ros_context, parameter_overrides=[
        Parameter('use_sim_time', value=True)])


def levels(out):
    """(time, level) of each DiagnosticArray the detector published (level is a byte)."""
    return [(t, m.status[0].level[0]) for t, m in out['/diagnostics']]


def test_healthy_actuator_raises_no_alarm(ros_context, replay, twin_bag):
    out = replay(detector(ros_context), twin_bag())
    index = out.data('/algorithm/leak_index')
    print('healthy: peak leak index', max(index))
    assert len(index) == 1000 and max(index) < LeakDetector.parameters['warn']
    assert all(level == 0 for _, level in levels(out))


def test_leak_is_detected_once_the_load_is_held(ros_context, replay, twin_bag):
    out = replay(detector(ros_context), twin_bag(faults=LEAK))
    first = next(t for t, level in levels(out) if level == ERROR) * 1e-9
    index = out.data('/algorithm/leak_index')
    print(f'leak x5 from 0.1 s: ERROR at {first:.3f} s, final index {index[-1]:.3f}')
    # the 10.4 kN load is applied at 0.2 s; the actuator first holds it still at 0.30 s and
    # then from 0.75 s
    assert 0.2 < first < 0.8


def test_same_outputs_every_replay(ros_context, replay, twin_bag):
    bag = twin_bag(faults=LEAK)
    a = replay(detector(ros_context), bag)
    b = replay(AlgorithmNode(LeakDetector(), name='again', context=ros_context,
                             parameter_overrides=[Parameter('use_sim_time', value=True)]), bag)
    assert a.keys() == b.keys()
    for topic in a:
        assert a[topic] == b[topic], topic
