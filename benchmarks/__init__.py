"""Speed and throughput benchmarks of clutch_ros (outside the package; see README.md).

Each module runs as ``.venv/bin/python -m benchmarks.<name>`` from the repository root and
prints its figures next to a baseline measured in the same run.
"""

from clutch_ros import numeric_env

# Every benchmark process (and the baseline processes they start) runs numpy under the same
# settings as the clutch command and the nodes (one BLAS thread, no huge-page advice), set
# before numpy loads: figures and baselines then measure the code, not the settings.
numeric_env.configure()
