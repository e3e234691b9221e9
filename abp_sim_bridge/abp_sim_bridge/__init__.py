"""Simulated uBot-6 and ARcube world (plain modules; the ROS node wraps them)."""
