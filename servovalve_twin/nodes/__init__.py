"""Thin rclpy nodes, one per EHA subsystem. They translate messages to physics calls and back;
every number they produce comes from :mod:`servovalve_twin.physics`."""
