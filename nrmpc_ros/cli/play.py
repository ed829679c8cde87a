"""``nrmpc play``: publish a bag's messages over ROS 2 with their original timing (see :mod:`nrmpc_ros.ros_play`)."""

from __future__ import annotations


def register(sub):
    p = sub.add_parser(
        "play", help="publish a bag's messages over ROS 2 with their original timing (no rosbag2 needed)",
        description="Publishes every message of BAG (rosbag2 sqlite3/mcap or ROS 1 .bag) on its topic, spaced "
                    "as recorded (divided by --rate). Message headers are left untouched.")
    p.add_argument("bag", metavar="BAG", help="bag directory (rosbag2) or .bag file (ROS 1)")
    p.add_argument("--rate", type=float, default=1.0, help="playback speed factor (default 1.0)")
    p.add_argument("--topics", nargs="+", metavar="TOPIC", help="publish only these topics (default: all)")
    p.add_argument("--loop", action="store_true", help="start again at the end, until interrupted")
    p.add_argument("--wait-for-subscribers", type=float, default=0.0, metavar="SECONDS",
                   help="before playing, wait up to SECONDS until every topic has a subscriber (then 0.5 s more)")
    p.add_argument("--delay", type=float, default=0.0, metavar="SECONDS",
                   help="sleep SECONDS after creating the publishers (DDS discovery) before the first message")
    p.add_argument("--clock", action="store_true", help="also publish /clock (rosgraph_msgs/Clock) from bag time")
    p.add_argument("--quiet", action="store_true", help="no summary line")
    p.set_defaults(func=run)



def run(args) -> int:
    from ..ros_play import play

    return play(args)
