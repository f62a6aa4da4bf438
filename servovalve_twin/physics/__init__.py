"""Plain numerical physics of the EHA: no rclpy, no I/O, no clocks."""

# the calibration of the simplified models from HD registers itself with the parameters, which
# derive XSS and GPQ through it (physics.params.register_hd_calibration); imported here so that
# any import of the physics has it (it imports no numba: its solver is compiled on first use)
from .valves import calibration as _calibration  # noqa: F401
