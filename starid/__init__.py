"""starid: star catalogue, camera models, star detection and star identification.

Example:
    >>> from adfusion import starid
    >>> cam = starid.Camera.pinhole(width=1024, height=768, fov_x_deg=11.4)
    >>> cam.width
    1024
"""

from typing import TYPE_CHECKING, Any

from adfusion.starid.camera.model import Camera
from adfusion.starid.detection.detect import detect
from adfusion.starid.detection.detections import Detections

from adfusion.maths import rotations

if TYPE_CHECKING:
    from adfusion.starid.catalog.stars import Catalog
    from adfusion.starid.config import SolverConfig
    from adfusion.starid.solver import Candidate, Prior, Solution, Solver

__all__ = [
    "Camera",
    "Candidate",
    "Catalog",
    "Detections",
    "Prior",
    "Solution",
    "Solver",
    "SolverConfig",
    "detect",
    "rotations",
]

# The catalogue and the solver (scipy, numba) load on first use: a process that only
# detects stars — replay's detection worker — starts ~0.4 s sooner without them.
_LAZY = {"Catalog": "adfusion.starid.catalog.stars", "Candidate": "adfusion.starid.solver",
         "Prior": "adfusion.starid.solver", "Solution": "adfusion.starid.solver",
         "Solver": "adfusion.starid.solver", "SolverConfig": "adfusion.starid.config"}


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        import importlib

        value = getattr(importlib.import_module(_LAZY[name]), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'starid' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
