"""The array types the project's signatures name, defined once (numpy's typing only).

Every layer may import this module (it imports nothing of ``app``), the compiled kernels
included: it holds no compiled code, so numba's per-file cache is not concerned.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

IntArray = npt.NDArray[np.int64]
FloatArray = npt.NDArray[np.float64]
Float32Array = npt.NDArray[np.float32]  # values kept by the million (a guide map's leads)
BoolArray = npt.NDArray[np.bool_]
KeyArray = npt.NDArray[np.int32]  # pair keys s * 4 + a, or cells, as int32
ByteArray = npt.NDArray[np.uint8]  # bytes of text, or flags
#: one explorer's moves as columns: states, actions, next states
Moves = tuple[IntArray, IntArray, IntArray]
