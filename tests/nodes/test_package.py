"""``clutch_ros.nodes``: importing it limits BLAS to one thread, unless the user said otherwise.

Checked on the real library: the number of threads of a fresh interpreter after importing
the package and numpy (OpenBLAS starts its pool when numpy loads).
"""

import os
import subprocess
import sys

from tests.conftest import REPO

PROBE = ("import os, clutch_ros.nodes, numpy; "
         "print(os.environ['OPENBLAS_NUM_THREADS'], len(os.listdir('/proc/self/task')))")


def _threads(**env) -> tuple[str, int]:
    base = {k: v for k, v in os.environ.items()
            if k not in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS")}
    done = subprocess.run([sys.executable, "-c", PROBE], cwd=REPO, env={**base, **env},
                          capture_output=True, text=True, timeout=60, check=True)
    value, threads = done.stdout.split()
    return value, int(threads)


def test_one_blas_thread_by_default():
    assert _threads() == ("1", 1)  # the main thread only: no OpenBLAS pool


def test_a_users_setting_is_kept():
    value, threads = _threads(OPENBLAS_NUM_THREADS="2")
    assert value == "2" and threads == 2  # main + one pool thread, as the user asked
