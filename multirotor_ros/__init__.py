"""multirotor_ros: simulation, control, identification and fault diagnosis of multirotors on ROS 2.

The physics and the algorithms (``model``, ``control``, ``ident``, ``diagnosis``, ``discrepancy``,
``io``, ``mavlink``) are pure Python/numpy libraries; only ``nodes`` imports rclpy.
"""

__version__ = "0.1.0"
