"""Names for the core's type annotations. Units and frames are stated where they are used:
poses (x, y, theta) are in the arena frame (m, m, rad), commands (v, w) in m/s and rad/s.
"""

from typing import Any, TypeAlias

import numpy as np
from numpy.typing import NDArray


FloatArray: TypeAlias = NDArray[np.floating[Any]]
IntArray: TypeAlias = NDArray[np.int64]
BoolArray: TypeAlias = NDArray[np.bool_]
Pose: TypeAlias = tuple[float, float, float]
Point: TypeAlias = tuple[float, float]
Command: TypeAlias = tuple[float, float]
