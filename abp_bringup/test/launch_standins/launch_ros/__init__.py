"""Stand-in for ROS 2 Jazzy's `launch_ros` package (see ../README.md)."""
