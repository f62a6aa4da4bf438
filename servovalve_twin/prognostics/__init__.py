"""ROS-free prognostics on the physics: the monitor model and its health assessment, fault
sweeps into labelled datasets."""
