# Type stub of the native module built from crates/pyplant.
# tests/test_stub.py runs mypy.stubtest against the compiled module: keep them in step.
from typing import Any

import numpy as np
import numpy.typing as npt

__all__ = [
    "InputError",
    "PlantDreamerError",
    "PlyError",
    "__version__",
    "info",
    "large_gaussian_mask",
]

__version__: str

class PlantDreamerError(Exception): ...
class InputError(PlantDreamerError): ...
class PlyError(PlantDreamerError): ...

def info() -> dict[str, Any]: ...

# Culling (crates/pyplant/src/culling.rs)
def large_gaussian_mask(
    log_scales: npt.NDArray[np.float32], c: float = 3.0
) -> tuple[npt.NDArray[np.bool_], dict[str, float]]: ...
