"""Plain numerical physics of the EHA: no rclpy, no I/O, no clocks."""
