"""Rectified images served on request: a whole coarse level, or full-resolution windows.

A segmenter looks at a whole image only at a coarse pyramid level and at full resolution only
in a small window around the object. Remapping both 640x480 colour views in full costs more
than all the segmentation work (about 1.3 ms per view with ``cv2.remap`` on one core), so a
segmenter given the *raw* camera images and the Rectification rectifies just what it reads:

* :meth:`RectifiedView.window` remaps a full-resolution window through the same slice of the
  same fixed-point maps, so its pixels are exactly those of a crop of the full remap;
* :meth:`RectifiedView.coarse` remaps a pyramid level of the raw image (``cv2.pyrDown``,
  Gaussian smoothing before decimation, so the table's texture does not alias) through the
  maps decimated to that level -- pyrDown and a near-identity warp commute, so this is the
  pyrDown of the rectified image up to interpolation.

For an image that is already rectified (a ``RectifiedPair``) the same calls slice and pyrDown.
"""

from __future__ import annotations

import math
import weakref

import cv2
import numpy as np

__all__ = ["RectifiedView", "pair_views"]

# (id(map_x), level) -> (weakref to map_x, fixed map, interp map). Decimated maps are derived
# from an immutable Rectification, so they are computed once per map array and process.
_LEVEL_MAPS: dict[tuple[int, int], tuple[weakref.ref, np.ndarray, np.ndarray]] = {}


def level_maps(map_x: np.ndarray, map_y: np.ndarray, level: int) -> tuple[np.ndarray, np.ndarray]:
    """Fixed-point remap maps from pyramid level ``level`` of the raw image to that of the rectified
    one.

    Pixel i of a ``cv2.pyrDown`` level k sits at full-resolution pixel ``2**k * i``, so the
    level's map is the full map sampled every ``2**k`` pixels, divided by ``2**k``.
    """
    key = (id(map_x), level)
    hit = _LEVEL_MAPS.get(key)
    if hit is not None and hit[0]() is map_x:
        return hit[1], hit[2]
    s = 2**level
    mx = np.ascontiguousarray(map_x[::s, ::s], np.float32) / s
    my = np.ascontiguousarray(map_y[::s, ::s], np.float32) / s
    fixed, interp = cv2.convertMaps(mx, my, cv2.CV_16SC2)
    if len(_LEVEL_MAPS) > 16:  # a long-lived process meeting many calibrations: forget the old ones
        _LEVEL_MAPS.clear()
    _LEVEL_MAPS[key] = (weakref.ref(map_x), fixed, interp)
    return fixed, interp


def _pyramid_level(img: np.ndarray, level: int) -> np.ndarray:
    """``level`` successive ``cv2.pyrDown``s of ``img``."""
    for _ in range(level):
        img = cv2.pyrDown(img)
    return img


class RectifiedView:
    """One rectified image, produced on request.

    Parameters
    ----------
    image : uint8 HxW or HxWx3
        The raw camera image (with ``maps``) or the rectified image itself (``maps=None``).
    maps : dict, optional
        ``{"x", "y"}``: float32 maps of the rectified size (``map_left_x`` ... of a
        Rectification), and ``{"fixed", "interp"}``: their fixed-point form when available.
    """

    def __init__(self, image: np.ndarray, maps: dict | None = None):
        self.image = image
        self.maps = maps
        self._levels: list[np.ndarray] = [image]
        if maps is None:
            self.shape = image.shape
        else:
            self.shape = maps["x"].shape[:2] + image.shape[2:]

    @property
    def is_raw(self) -> bool:
        """True when the pixels are rectified on request (not slices of a rectified image)."""
        return self.maps is not None

    def window(self, u0: int, v0: int, u1: int, v1: int) -> np.ndarray:
        """Rectified pixels [v0:v1, u0:u1] at full resolution."""
        if self.maps is None:
            return self.image[v0:v1, u0:u1]
        m = self.maps
        if m.get("fixed") is not None:
            return cv2.remap(
                self.image, m["fixed"][v0:v1, u0:u1], m["interp"][v0:v1, u0:u1], cv2.INTER_LINEAR
            )
        return cv2.remap(self.image, m["x"][v0:v1, u0:u1], m["y"][v0:v1, u0:u1], cv2.INTER_LINEAR)

    def coarse(self, scale: int, u0: int, v0: int, u1: int, v1: int) -> np.ndarray:
        """Rectified pixels [v0:v1, u0:u1] at ``1/scale`` resolution (``scale`` a power of two).

        ``u0``, ``v0`` must be multiples of ``scale``; ``u1``, ``v1`` too unless they are the
        image's edge. The result has ``ceil((u1 - u0) / scale)`` columns, as ``cv2.pyrDown``
        of the window would.
        """
        level = int(round(math.log2(scale)))
        if self.maps is None:
            return _pyramid_level(self.image[v0:v1, u0:u1], level)
        if level == 0:
            return self.window(u0, v0, u1, v1)
        fixed, interp = level_maps(self.maps["x"], self.maps["y"], level)
        cu0, cv0 = u0 // scale, v0 // scale
        cu1, cv1 = -(-u1 // scale), -(-v1 // scale)
        fixed, interp = fixed[cv0:cv1, cu0:cu1], interp[cv0:cv1, cu0:cu1]
        h, w = self.shape[:2]
        if (u1 - u0) * (v1 - v0) < 0.5 * w * h and len(self._levels) <= level:
            # A small window (the epipolar band): build the pyramid of just the raw pixels it
            # reads. The crop starts on the level's grid and has a margin of 4 level pixels,
            # so its pyramid equals the whole image's wherever the maps sample it. The level's
            # maps read the full maps at every ``scale``-th row and column from (u0, v0) (both
            # on that grid): only those positions are sampled, so only they bound the crop.
            xs, ys = (
                self.maps["x"][v0:v1:scale, u0:u1:scale],
                self.maps["y"][v0:v1:scale, u0:u1:scale],
            )
            ih, iw = self.image.shape[:2]
            pad = 4 * scale
            x0 = max(0, int(math.floor(float(xs.min()))) - pad) // scale * scale
            y0 = max(0, int(math.floor(float(ys.min()))) - pad) // scale * scale
            x1 = min(iw, int(math.ceil(float(xs.max()))) + pad + 1)
            y1 = min(ih, int(math.ceil(float(ys.max()))) + pad + 1)
            if x1 > x0 and y1 > y0:
                small = _pyramid_level(self.image[y0:y1, x0:x1], level)
                # integer part of the fixed-point map
                shifted = fixed - np.int16([x0 // scale, y0 // scale])
                return cv2.remap(small, shifted, interp, cv2.INTER_LINEAR)
        while len(self._levels) <= level:
            self._levels.append(cv2.pyrDown(self._levels[-1]))
        return cv2.remap(self._levels[level], fixed, interp, cv2.INTER_LINEAR)

    def full(self) -> np.ndarray:
        """The whole rectified image (a full remap for a raw image)."""
        h, w = self.shape[:2]
        return self.window(0, 0, w, h)


def pair_views(
    rect: dict | None, left: np.ndarray, right: np.ndarray, raw: bool
) -> tuple[RectifiedView, RectifiedView]:
    """Views of a stereo pair: ``raw=True`` rectifies the camera images on request with ``rect``'s
    maps."""
    if not raw:
        return RectifiedView(left), RectifiedView(right)
    views = []
    for side, im in (("left", left), ("right", right)):
        maps = {
            "x": rect[f"map_{side}_x"],
            "y": rect[f"map_{side}_y"],
            "fixed": rect.get(f"map_{side}_fixed"),
            "interp": rect.get(f"map_{side}_interp"),
        }
        views.append(RectifiedView(im, maps))
    return views[0], views[1]
