"""starid: star catalogue, camera models, star detection and star identification.

Example:
    >>> import starid
    >>> cam = starid.Camera.pinhole(width=1024, height=768, fov_x_deg=11.4)
    >>> cam.width
    1024
"""

from starid import rotations
from starid.camera import Camera
from starid.catalog import Catalog
from starid.detect import Detections, detect
from starid.solver import Candidate, Prior, Solution, Solver

__all__ = [
    "Camera",
    "Candidate",
    "Catalog",
    "Detections",
    "Prior",
    "Solution",
    "Solver",
    "detect",
    "rotations",
]
