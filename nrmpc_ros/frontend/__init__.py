"""Front end: images and IMU samples in, relative pose and gravity estimates out (docs/PIPELINE.md).

``Pipeline`` (:mod:`.pipeline`) is shared by ``nrmpc replay`` and the ROS 2
node, which both feed it through :mod:`.feeder` (decoding by :mod:`.images`,
stamp checks by :mod:`.stamps`, frame sets by :mod:`.sync`) and
:mod:`.runner`. :mod:`.tracking` follows features (KLT), :mod:`.zupt` and
:mod:`.holds` decide when the rig is still and measure each hold from its
settled frames, :mod:`.linking` gives landmarks one id across holds,
:mod:`.imu` turns the accelerometer into gravity. Offline, :mod:`.estimates_csv`
writes and reads the estimates, :mod:`.reference` reads a bag's IMU and ground
truth, :mod:`.imu_reference` gives the IMU's own gravity at a stamp,
:mod:`.evaluation` scores estimates against both, :mod:`.evaluation_report`
prints and draws the scores and :mod:`.trajectory` writes TUM files. The module map is
docs/ARCHITECTURE.md. Every drop reason is a :class:`.drops.Drop` (its message made
only where it is shown).
"""
