"""Front end: images and IMU samples in, relative pose and gravity estimates out.

``Pipeline`` (:mod:`.pipeline`) is shared by ``nrmpc replay`` and the ROS 2
node; :mod:`.sync` groups per-camera messages, :mod:`.images` decodes them,
:mod:`.tracking` finds correspondences, :mod:`.static` decides which views are
static and how they are paired, :mod:`.imu` turns the accelerometer into
gravity and :mod:`.evaluation` scores estimates against the IMU and ground truth.
"""
