"""servovalve_twin: a ROS 2 digital twin of an aerospace electro-hydraulic actuator (EHA).

The physics lives in :mod:`servovalve_twin.physics` (ROS-free); the ROS 2 nodes in
:mod:`servovalve_twin.nodes`; the command line in :mod:`servovalve_twin.cli`.
"""

__version__ = '0.1.0'
