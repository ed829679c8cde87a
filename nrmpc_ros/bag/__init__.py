"""rosbag2 reading and writing through the ``rosbags`` library, no ROS install needed (SPEC section 11)."""
