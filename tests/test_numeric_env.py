"""``clutch_ros.numeric_env``: the clutch command and the nodes set numpy's libraries up first.

Checked on the real libraries, in a fresh interpreter per case, after importing the entry
package (``clutch_ros.cli`` or ``clutch_ros.nodes``) and then numpy: the number of threads
(OpenBLAS starts its pool when numpy loads) and numpy's huge-page advice flag.
"""

import os
import subprocess
import sys

import pytest

from clutch_ros import numeric_env
from tests.conftest import REPO

PROBE = ("import os, {package}, numpy; "
         "hp = numpy._core.multiarray._set_madvise_hugepage(False); "
         "print(os.environ.get('OPENBLAS_NUM_THREADS', '-'), "
         "len(os.listdir('/proc/self/task')), int(hp))")
PACKAGES = ("clutch_ros.cli", "clutch_ros.nodes")


def _probe(package: str, **env) -> tuple[str, int, int]:
    base = {k: v for k, v in os.environ.items() if k not in numeric_env.SETTINGS}
    done = subprocess.run([sys.executable, "-c", PROBE.format(package=package)], cwd=REPO,
                          env={**base, **env}, capture_output=True, text=True, timeout=60,
                          check=True)
    value, threads, hugepage = done.stdout.split()
    return value, int(threads), int(hugepage)


@pytest.mark.parametrize("package", PACKAGES)
def test_one_blas_thread_and_no_huge_page_advice_by_default(package):
    # the main thread only (no OpenBLAS pool); numpy's huge-page advice off
    assert _probe(package) == ("1", 1, 0)


@pytest.mark.parametrize("package", PACKAGES)
def test_a_users_settings_are_kept(package):
    value, threads, hugepage = _probe(package, OPENBLAS_NUM_THREADS="2",
                                      NUMPY_MADVISE_HUGEPAGE="1")
    assert value == "2" and threads == 2  # main + one pool thread, as the user asked
    assert hugepage == 1


def test_without_the_package_numpy_would_advise_and_spin():
    """The control: a bare interpreter gets the pool and the advice (what the setting changes)."""
    base = {k: v for k, v in os.environ.items() if k not in numeric_env.SETTINGS}
    probe = PROBE.replace("{package}, ", "")
    done = subprocess.run([sys.executable, "-c", probe], cwd=REPO, env=base,
                          capture_output=True, text=True, timeout=60, check=True)
    _, threads, hugepage = done.stdout.split()
    assert int(threads) > 1 and int(hugepage) == 1
