"""Configuration files: ROS 2 parameter YAML files, the shipped presets, launch files.

Layer: above :mod:`clutch_ros.model` (it turns YAML into validated model parameters), below the
storage, CAN and everything else (see ARCHITECTURE.md). No ROS, no CAN, no bags.

Modules:
    params_file   read and write ROS 2 parameter YAML files of the model parameters
    presets       where the shipped presets and the rig DBC live (source tree or share)
    launch_file   XML launch files read as ros2 launch does (``clutch up``): the elements
    launch_node   ``<node>``: its command line, parameters in order, respawn settings
    launch_subst  ``$(...)`` substitutions and typed parameter values of launch files
    errors        ``LaunchFileError`` (the rest raise ``ConfigError`` or ``ParameterError``)
"""
