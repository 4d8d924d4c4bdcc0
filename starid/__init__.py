"""starid: star catalogue, camera models, star detection and star identification.

Example:
    >>> import starid
    >>> cam = starid.Camera.pinhole(width=1024, height=768, fov_x_deg=11.4)
    >>> cam.width
    1024
"""

from starid import rotations
from starid.camera import Camera

__all__ = ["Camera", "rotations"]
