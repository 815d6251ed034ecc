"""Thin rclpy nodes of clutch_ros, one Node class per module.

``can_bridge``, ``rig_sim``, ``estimator``, ``controller``, ``recorder``, ``bag_player``,
``dashboard``:
each module has ``main(args=None)`` (the console script ``ros2 run clutch_ros <name>`` runs)
and answers ``--help`` without starting ROS. The shared plumbing is split by what it
is: ``parameters``, ``qos``, ``stamps``, ``diagnostics``, ``runner``.

One BLAS thread per node process: importing this package sets ``OPENBLAS_NUM_THREADS`` and
``OMP_NUM_THREADS`` to 1 unless they are set already (a value you set is kept), before any
node imports numpy. The model's matrices are at most ~30 x 30, far below where a second BLAS
thread pays off, while OpenBLAS's pool threads spin after each call and take CPU from the
DDS threads. Measured with ``python -m benchmarks.estimator_node`` on this 2-core machine, the
estimator's p99 latency at 1 kHz fell from 6-12 ms to 1.7-2.1 ms and at 2 kHz from 27-85 ms
to about 4 ms (median unchanged at ~0.4 ms).
"""

import os

for _name in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS"):
    os.environ.setdefault(_name, "1")
del _name
