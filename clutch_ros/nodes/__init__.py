"""Thin rclpy nodes of clutch_ros, one Node class per module.

``can_bridge``, ``rig_sim``, ``estimator``, ``controller``, ``recorder``, ``bag_player``:
each module has ``main(args=None)`` (the console script ``ros2 run clutch_ros <name>`` runs)
and answers ``--help`` without starting ROS. ``common`` holds the shared plumbing.
"""
