"""Offline workflows: the model over recorded and simulated runs, without ROS.

Layer: above the simulated rig, storage and CAN, below the nodes (see ARCHITECTURE.md).

Modules:
    replay             ``replay_bag`` / ``write_estimates``: the estimator over a bag's
                       RigState stream (the back end of ``clutch replay``)
    streaming          estimate while reading: the bag read and the model loop overlapped
    batch              ``run_jobs``: one job per bag, serially, in processes or on Dask
    adapt              the adaptive estimator over bags, saving what it learned (``--adapt``)
    fit_auto           which keys ``clutch fit`` fits, and ``--law auto``
    rig_runs           simulated rig runs written as RigState bags (golden data, round trips)
    golden             golden regression data: generate, compare, readable diffs
    flexiforce         bags -> calibrated FlexiForce front/rear pressures (fit, calibrate, report)
    closed_loop        the controller and estimator against the simulated rig, offline
    steady_state       the plateau (steady-state) error of a closed-loop run
    demo_summary       the demo's figures from its bag (settled accuracy, overshoot, RMSE)
    plots, replay_report, validation_report
                       PNG reports (matplotlib, imported when a report is drawn)
    errors             ``OfflineError``: ``BatchJobError``, ``ClusterError``

Importing this package imports nothing heavy; import the modules you need.
"""
