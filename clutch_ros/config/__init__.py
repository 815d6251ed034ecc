"""Configuration files: ROS 2 parameter YAML files and where the shipped presets live.

Layer: above :mod:`clutch_ros.model` (it turns YAML into validated model parameters), below the
storage, CAN and everything else (see ARCHITECTURE.md). No ROS, no CAN, no bags.
"""
