"""Thin rclpy nodes of clutch_ros, one Node class per module.

``can_bridge``, ``rig_sim``, ``estimator``, ``controller``, ``recorder``, ``bag_player``,
``dashboard``:
each module has ``main(args=None)`` (the console script ``ros2 run clutch_ros <name>`` runs)
and answers ``--help`` without starting ROS. The shared plumbing is split by what it
is: ``parameters``, ``qos``, ``stamps``, ``diagnostics``, ``runner``.

One BLAS thread per node process (and no huge-page advice for numpy's arrays): importing
this package calls :func:`clutch_ros.numeric_env.configure` before any node imports numpy
(a value you set is kept); why, and what it measured, is in that module.
"""

from clutch_ros import numeric_env

numeric_env.configure()
