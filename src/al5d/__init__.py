"""al5d: driver and ROS 2 server for the Lynxmotion AL5D arm on an SSC-32U."""

__version__ = "0.1.0"
