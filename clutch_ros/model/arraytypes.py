"""Array type aliases for annotations (numpy.typing); nothing here runs at import time."""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

__all__ = ["BoolArray", "FloatArray", "IntArray"]

#: float arrays: float64 in practice (the model's dtype); typed as any floating dtype because
#: numpy's stubs give linalg results and quotients as ``floating[Any]``
FloatArray = NDArray[np.floating[Any]]
#: bool arrays (masks, the warm stuck set)
BoolArray = NDArray[np.bool_]
#: int64 arrays (indices, entry numbers)
IntArray = NDArray[np.int64]
