"""Reading a frame: an image file or array as one grey float image (:func:`read_image`).
"""

from __future__ import annotations

import os
from typing import Any

import numpy as np

from adfusion.imagefiles import read_frame_file

__all__ = ["read_image"]


# Kept in their own type (no conversion pass; thresholds compare as integers); other integer
# types become float.
_NATIVE_INT = (np.uint8, np.uint16)


def read_image(path: str | os.PathLike[str]) -> np.ndarray:
    """Read an image file as a 2-D grey array, keeping its bit depth (8/16-bit, float TIFF,
    FITS).

    Colour files are converted to grey (OpenCV's BGR order is known for files). The file
    is read by :func:`adfusion.imagefiles.read_frame_file`, the project's one frame
    reader: names of any bytes, a pixel cap (``ADFUSION_MAX_IMAGE_PIXELS``) checked on the
    header before decoding, truncated files refused. Raises FileNotFoundError for a
    missing file and ValueError (one line naming the file) when it cannot be used.

    Example:
        >>> import tempfile
        >>> from pathlib import Path
        >>> import cv2
        >>> p = Path(tempfile.mkdtemp()) / "f.png"
        >>> _ = cv2.imwrite(str(p), np.full((4, 6), 1000, np.uint16))
        >>> a = read_image(p); a.shape, a.dtype.name, int(a[0, 0])
        ((4, 6), 'uint16', 1000)
    """
    return read_frame_file(path)


def _as_grey(image: Any) -> np.ndarray:
    """Validate an array (or read a file) and return a contiguous 2-D array to detect on.

    uint8/uint16 and float32/float64 pass through; other real dtypes become float32 (float64
    for 32/64-bit integers, whose values float32 cannot hold exactly).
    """
    if isinstance(image, (str, os.PathLike)):
        img = read_image(image)
    elif isinstance(image, np.ndarray):
        img = image
    else:
        raise TypeError(
            f"image must be a numpy array or a file path, not {type(image).__name__}"
        )
    if img.size == 0:
        raise ValueError(f"image is empty (shape {img.shape})")
    if img.ndim == 3 and img.shape[2] == 1:
        img = img[:, :, 0]
    if img.ndim == 3 and img.shape[2] in (3, 4):
        # An array carries no channel order (RGB from PIL/matplotlib, BGR from OpenCV), so a
        # silent conversion could weight the channels wrongly; files are converted instead.
        raise ValueError(
            f"image is a {img.shape[2]}-channel colour array {img.shape}; pass a 2-D grey "
            "image, e.g. cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)"
        )
    if img.ndim != 2:
        raise ValueError(f"image must be 2-D (height, width), got ndim={img.ndim}, {img.shape}")
    kind = img.dtype.kind
    if kind == "b":
        raise TypeError("image has dtype bool; convert it, e.g. img.astype(np.uint8)")
    if kind not in "uif":
        raise TypeError(f"image dtype {img.dtype} is not a real number type (int or float)")
    if not img.dtype.isnative:  # FITS data are big-endian; OpenCV needs native byte order
        img = img.astype(img.dtype.newbyteorder("="))
    if img.dtype.type in _NATIVE_INT or img.dtype.type in (np.float32, np.float64):
        pass
    elif kind in "ui" and img.dtype.itemsize >= 4:
        img = img.astype(np.float64)
    else:
        img = img.astype(np.float32)
    return np.ascontiguousarray(img)


def _all_finite(img: np.ndarray) -> bool:
    """One cheap reduction instead of a full isfinite mask: the sum is finite iff every pixel
    is (barring float64 overflow, which only sends the caller down the careful path)."""
    with np.errstate(invalid="ignore", over="ignore"):
        return bool(np.isfinite(img.sum(dtype=np.float64)))
