"""ROS-free prognostics on the physics: the algorithm interface your own detectors and
estimators implement, the monitor model and its health assessment, fault sweeps into labelled
datasets."""

from .algorithm import ERROR, OK, WARN, Algorithm, AlgorithmError, Health

__all__ = ['Algorithm', 'AlgorithmError', 'Health', 'OK', 'WARN', 'ERROR']
