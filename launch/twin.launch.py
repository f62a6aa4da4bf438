"""Launch the EHA twin's nodes as separate processes sharing simulated time.

    ros2 launch servovalve_twin twin.launch.py valve_model:=HD scenario:=paper rate:=1.0

Two actuators of one surface, each under its own namespace, on one ``/clock``::

    ros2 launch servovalve_twin twin.launch.py namespace:=left
    ros2 launch servovalve_twin twin.launch.py namespace:=right clock:=false \
        params_file:=right_unit.yaml

``namespace`` moves every node and topic (``/left/xj``); ``/clock`` stays global and has one
owner: the first launch's ``clock`` process (``clock:=false`` for every other launch);
``params_file`` replaces config/eha.yaml (a ``/**:`` parameters file, so it matches nodes in
any namespace).

It also starts the monitor node (``monitor_model:=SQ``, the default) beside the plant. The ECU
and the plant are essential: when either exits (a bad parameter at start-up, say) the whole
launch ends.

A ``clock`` process publishes ``/clock`` at ``rate`` simulated seconds per wall second; every
node runs with ``use_sim_time`` and its own timer at ``control_period``. Across processes the
nodes are *not* in lockstep (each uses the latest input it received): for deterministic runs use
the single-process ``twin`` executable (``ros2 run servovalve_twin twin``). Written for Jazzy's
launch_ros; the physical parameters come from config/eha.yaml.
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, Shutdown
from launch.conditions import IfCondition
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node
from launch_ros.parameter_descriptions import ParameterValue

from servovalve_twin.physics.valves import VALVE_MODEL_NAMES      # the one registry
from servovalve_twin.prognostics.monitor import DEFAULT_MONITOR_MODEL


def generate_launch_description():
    share = get_package_share_directory('servovalve_twin')
    eha = os.path.join(share, 'config', 'eha.yaml')
    valve_model = LaunchConfiguration('valve_model')
    scenario = LaunchConfiguration('scenario')
    rate = LaunchConfiguration('rate')
    period = LaunchConfiguration('control_period')
    common = {'use_sim_time': True,
              'control_period': ParameterValue(period, value_type=float)}
    namespace = LaunchConfiguration('namespace')
    params_file = LaunchConfiguration('params_file')
    return LaunchDescription([
        DeclareLaunchArgument('namespace', default_value='',
                              description="the actuator's namespace (e.g. left)"),
        DeclareLaunchArgument('params_file', default_value=eha,
                              description="the unit's physical parameters (ROS params file)"),
        DeclareLaunchArgument('clock', default_value='true',
                              description='start the clock process, the one /clock owner of '
                                          'the graph (false for every other actuator)'),
        DeclareLaunchArgument('valve_model', default_value='C2',
                              description=', '.join(VALVE_MODEL_NAMES)),
        DeclareLaunchArgument('scenario', default_value='paper',
                              description='built-in scenario name or YAML file'),
        DeclareLaunchArgument('rate', default_value='1.0',
                              description='simulated seconds per wall second'),
        DeclareLaunchArgument('control_period', default_value='0.001',
                              description='control period [s] of every node'),
        DeclareLaunchArgument('monitor_model', default_value=DEFAULT_MONITOR_MODEL,
                              description='simplified model of the monitor node'),
        Node(package='servovalve_twin', executable='clock', name='clock', output='screen',
             condition=IfCondition(LaunchConfiguration('clock')),
             parameters=[{'rate': ParameterValue(rate, value_type=float),
                          'period': ParameterValue(period, value_type=float)}]),
        Node(package='servovalve_twin', executable='command_generator', namespace=namespace,
             name='command_generator', output='screen',
             parameters=[common, {'scenario': scenario}]),
        Node(package='servovalve_twin', executable='load_supply', namespace=namespace,
             name='load_supply', output='screen', parameters=[common, {'scenario': scenario}]),
        Node(package='servovalve_twin', executable='ecu', namespace=namespace, name='ecu',
             output='screen',
             on_exit=Shutdown(reason='ecu exited'),   # essential: ends the launch
             parameters=[params_file, common]),
        Node(package='servovalve_twin', executable='plant', namespace=namespace, name='plant',
             output='screen',
             on_exit=Shutdown(reason='plant exited'),   # essential: ends the launch
             parameters=[params_file, common, {'valve_model': valve_model}]),
        Node(package='servovalve_twin', executable='monitor', namespace=namespace,
             name='monitor', output='screen',
             parameters=[params_file, common,
                         {'monitor_model': LaunchConfiguration('monitor_model')}]),
    ])
