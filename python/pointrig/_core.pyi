"""Type stubs for the private native module ``pointrig._core`` (hand-written).

All point arrays are float64, C-contiguous, shape ``(n, 3)``, metres. Functions raise
``ValueError`` on wrong shapes or non-contiguous input and
``pointrig.errors.InputError`` on NaN/inf values.
"""

import numpy as np
import numpy.typing as npt

__version__: str

def kabsch(
    src: npt.NDArray[np.float64],
    dst: npt.NDArray[np.float64],
    weights: npt.NDArray[np.float64] | None = None,
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """Weighted absolute orientation (Eq. 14, Lemma 1): ``R (3, 3)``, ``t (3,)`` with
    ``dst ~ src @ R.T + t``."""
