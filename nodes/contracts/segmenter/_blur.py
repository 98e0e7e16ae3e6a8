"""Gaussian smoothing of 8-bit images: the exact pixels of ``cv2.GaussianBlur``, cheaper on small
windows.

For an 8-bit image ``cv2.GaussianBlur(img, (0, 0), sigma)`` runs OpenCV's bit-exact fixed-point
path: the kernel as integers k_i summing to 256, a row pass R = sum_i k_i p_i, a column pass
S = sum_j k_j R_j and the pixel (S + 2**15) >> 16. In the OpenCV 5.0 wheel that path is 2-2.5x
slower on the segmenters' windows (about 100 x 100 px, sigma 1-2 px) than ``cv2.sepFilter2D``
with the same integer kernel into float32, where every partial sum is an integer below 2**24
(255 x 256 x 256 at most) and so exact; the same rounding then gives the same pixels.

The integer kernel is read back from ``cv2.GaussianBlur`` itself, and the fast path serves a
sigma only once it has reproduced ``cv2.GaussianBlur`` bit for bit on a random probe image: an
OpenCV build whose Gaussian works otherwise keeps ``cv2.GaussianBlur``.
"""

from __future__ import annotations

import cv2
import numpy as np

# sigma (px) -> float32 integer kernel, or None where the fast path does not reproduce OpenCV.
_KERNELS: dict[float, np.ndarray | None] = {}
# Fast path only for windows of at most this many values (rows x columns x channels): its float32
# buffers (4 B a value) then come from the heap; larger ones (from ~200 KB here, glibc's mmap
# threshold) are mapped afresh on every call, and their page faults cost more than the faster
# filter saves (measured: 2x faster up to 120x120x3, slower from 130x130x3 at sigma 1 px).
_MAX_FAST_VALUES = 40_000
# Below this kernel length (sigma < ~0.9 px) cv2.GaussianBlur is as fast.
_MIN_FAST_KSIZE = 7


def gaussian_blur(img: np.ndarray, sigma: float) -> np.ndarray:
    """``cv2.GaussianBlur(img, (0, 0), sigma)`` (default border), the same pixels.

    Parameters
    ----------
    img : HxW or HxWxC array (uint8 takes the fast path on small windows)
    sigma : float
        Standard deviation of the Gaussian (px).
    """
    if img.dtype != np.uint8 or img.size > _MAX_FAST_VALUES:
        return cv2.GaussianBlur(img, (0, 0), sigma)
    k = _KERNELS.get(sigma, False)
    if k is False:
        k = _KERNELS[sigma] = _checked_kernel(sigma)
    if k is None or len(k) < _MIN_FAST_KSIZE:
        return cv2.GaussianBlur(img, (0, 0), sigma)
    return _separable(img, k)


def _separable(img: np.ndarray, k: np.ndarray) -> np.ndarray:
    # S + 2**15 < 2**24, so the float32 sum and its scaling by 2**-16 are exact; the cast to uint8
    # truncates, i.e. floors the non-negative value: (S + 2**15) >> 16.
    s = cv2.sepFilter2D(img, cv2.CV_32F, k, k, delta=32768.0)
    return (s * np.float32(1.0 / 65536.0)).astype(np.uint8)


def _checked_kernel(sigma: float) -> np.ndarray | None:
    """The integer kernel of ``cv2.GaussianBlur`` for ``sigma`` (float32), or None if the fast path
    does not reproduce it on a probe image."""
    k = _probe_kernel(sigma)
    if k is None:
        return None
    # Random values, and isolated impulses of every value 0-255: each output is v k_i k_j / 2**16,
    # some exactly on a half, where a rounding that differs shows.
    noise = np.random.default_rng(0).integers(0, 256, (23, 29, 3), dtype=np.uint8)
    step = len(k) + 2
    impulses = np.zeros((16 * step, 16 * step), np.uint8)
    impulses[step // 2 :: step, step // 2 :: step] = np.arange(256, dtype=np.uint8).reshape(16, 16)
    for probe in (noise, impulses):
        if not np.array_equal(_separable(probe, k), cv2.GaussianBlur(probe, (0, 0), sigma)):
            return None
    return k


def _probe_kernel(sigma: float) -> np.ndarray | None:
    """Read the integer kernel back from ``cv2.GaussianBlur`` of a vertical line of 255.

    Rows are constant, so the column pass multiplies by exactly 256 and tap k comes out as
    floor(255 k / 256 + 1/2): k itself up to 128, k - 1 from 129 on (an output of 128 is k = 128
    or 129, told apart by the kernel's sum of 256). Taps beyond OpenCV's kernel read as 0.
    """
    r = int(np.ceil(4.0 * sigma)) + 1  # half length: OpenCV's kernel has 3 sigma (8-bit images)
    w = 6 * r + 3
    line = np.zeros((2 * r + 1, w), np.uint8)
    line[:, w // 2] = 255
    out = cv2.GaussianBlur(line, (0, 0), sigma)[r, w // 2 - r : w // 2 + r + 1][::-1].astype(
        np.int64
    )
    k = np.where(out > 128, out + 1, out)
    tie = np.flatnonzero(out == 128)
    if len(tie) > 1:
        return None
    if len(tie) == 1:
        k[tie[0]] = 256 - (k.sum() - 128)
    if k.sum() != 256 or (len(tie) == 1 and k[tie[0]] not in (128, 129)):
        return None
    nz = np.flatnonzero(k)
    half = max(nz[-1] - r, r - nz[0])  # drop the zero taps on both ends, keeping the kernel centred
    return k[r - half : r + half + 1].astype(np.float32)
