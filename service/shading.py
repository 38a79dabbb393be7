"""Pictures of a camera's hits, as PNG (Pillow): the shadings of ``/render`` (docs/sensors.md).

Every function takes the hits of one image as arrays of shape (height, width[, 3]), row 0 at the
top, and answers 8-bit pixels; a miss is a pixel with ``t = inf``.

- ``depth``: grey ("L"); a hit at depth d is ``round(255 - 200 (d - near) / (far - near))``, where
  near and far are the least and greatest depth of the image's hits (255 if they are equal): near
  is bright, far is dim (55), a miss is 0.
- ``normal``: colour ("RGB"); a hit is ``round(255 (n + 1) / 2)`` per channel of its unit
  geometric normal n in the scene (as ``closest`` reports it, not turned toward the camera); a miss
  is black.
- ``shaded``: colour ("RGB"); a hit is its mesh's colour (``PALETTE[index % len(PALETTE)]``) times
  ``0.15 + 0.85 |n . d|`` (d the unit ray direction: a light at the eye), rounded; a miss is
  ``BACKGROUND``.
"""

from __future__ import annotations

import io

import numpy as np
from PIL import Image

SHADINGS = ("shaded", "normal", "depth")
#: Mesh colours of ``shaded``, by mesh index modulo their number.
PALETTE = np.array(
    [
        [222, 200, 160],
        [140, 180, 220],
        [200, 140, 150],
        [150, 200, 150],
        [210, 180, 220],
        [230, 210, 120],
        [130, 200, 200],
        [220, 160, 120],
    ],
    np.float64,
)
_PALETTE32 = PALETTE.astype(np.float32)
BACKGROUND = (30, 33, 40)  #: the colour of a miss in ``shaded``
DEPTH_NEAR, DEPTH_FAR = 255, 55  #: the grey of the nearest and of the farthest hit in ``depth``
AMBIENT = 0.15  #: the share of a mesh's colour that a grazing hit keeps in ``shaded``


def depth_pixels(depth: np.ndarray) -> tuple[np.ndarray, tuple[float, float] | None]:
    """(uint8 (H, W) grey, (near, far) of the hits or None if there is none)."""
    hit = np.isfinite(depth)
    grey = np.zeros(depth.shape, np.uint8)
    if not hit.any():
        return grey, None
    values = depth[hit].astype(np.float64)
    near, far = float(values.min()), float(values.max())
    scale = (DEPTH_NEAR - DEPTH_FAR) / (far - near) if far > near else 0.0
    grey[hit] = np.rint(DEPTH_NEAR - scale * (values - near)).astype(np.uint8)
    return grey, (near, far)


def normal_pixels(t: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """uint8 (H, W, 3): each hit's unit normal mapped from [-1, 1] to [0, 255]; misses black."""
    rgb = np.rint((normal + np.float32(1)) * np.float32(127.5)).clip(0, 255).astype(np.uint8)
    rgb[~np.isfinite(t)] = 0
    return rgb


def shaded_pixels(
    t: np.ndarray, mesh: np.ndarray, normal: np.ndarray, directions: np.ndarray
) -> np.ndarray:
    """uint8 (H, W, 3): each hit's mesh colour lit by a light at the eye; misses BACKGROUND."""
    cosine = np.abs(np.einsum("...i,...i->...", directions, normal))
    cosine /= np.sqrt(np.einsum("...i,...i->...", directions, directions))
    light = np.float32(AMBIENT) + np.float32(1 - AMBIENT) * np.minimum(cosine, np.float32(1))
    colour = _PALETTE32[np.maximum(mesh, 0) % len(PALETTE)] * light[..., None]
    rgb = np.rint(colour).astype(np.uint8)  # at most 230: no clipping needed
    rgb[~np.isfinite(t)] = BACKGROUND
    return rgb


def png(pixels: np.ndarray) -> bytes:
    """A PNG of uint8 pixels: (H, W) is mode "L", (H, W, 3) mode "RGB"."""
    out = io.BytesIO()
    # level 1: a 640 x 480 picture encodes in a few ms, and the viewer asks for one per drag step
    Image.fromarray(np.ascontiguousarray(pixels)).save(out, format="PNG", compress_level=1)
    return out.getvalue()
