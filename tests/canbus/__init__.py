"""Tests of clutch_ros.canbus (pure python-can/cantools, no ROS)."""
