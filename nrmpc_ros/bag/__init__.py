"""rosbag2 reading and writing through the ``rosbags`` library, no ROS install needed (docs/CONVENTIONS.md (Bags))."""
