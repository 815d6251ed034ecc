"""Thin rclpy nodes of clutch_ros, one Node class per module.

Nodes: ``can_bridge``, ``rig_sim``, ``estimator``, ``controller``, ``recorder``,
``bag_player``, ``dashboard``. Each module has ``main(args=None)`` (the console script
``ros2 run clutch_ros <name>`` runs) and answers ``--help`` without starting ROS.
``demo_driver`` is the demo's stand-in test engineer (torque requests, rig motor speed),
started by ``clutch demo``.

Helpers, by what they are:
    parameters, model_params       one ROS parameter per ``ParamSpec``; model keys as parameters
    can_bridge_params, controller_params, adapt_params
                                   the parameters of the bridge, controller and adaptation
    qos, stamps, convert           QoS per topic, stamps <-> seconds, messages <-> samples
    diagnostics, can_diagnostics   ``/diagnostics`` status, the bridge's health
    peers, command_sources         which publishers feed a node; who sends ``pressure_command``
    loss_tracker                   the recorder's bookkeeping (no rclpy)
    runner                         ``--help``, the executor, spin, clean shutdown

One BLAS thread per node process (and no huge-page advice for numpy's arrays): importing
this package calls :func:`clutch_ros.numeric_env.configure` before any node imports numpy
(a value you set is kept); why, and what it measured, is in that module.
"""

from clutch_ros import numeric_env

numeric_env.configure()
