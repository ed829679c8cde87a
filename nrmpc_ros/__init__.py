"""nrmpc_ros: relative pose and gravity for non-rigid multi-perspective cameras.

The core (``nrmpc_ros.core``), the simulator and the offline tools never use
rclpy; only ``nrmpc_ros.node`` (and ``ros_play`` for ``nrmpc play``) does (docs/CONVENTIONS.md (Python API)).
"""

__version__ = "0.1.0"
