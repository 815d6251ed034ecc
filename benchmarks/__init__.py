"""Speed and throughput benchmarks of clutch_ros (outside the package; see README.md).

Each module runs as ``.venv/bin/python -m benchmarks.<name>`` from the repository root and
prints its figures next to a baseline measured in the same run.
"""
