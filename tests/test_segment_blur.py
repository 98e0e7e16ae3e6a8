"""The segmenters' Gaussian smoothing (contracts/segmenter/_blur.py) gives cv2.GaussianBlur's
pixels, bit for bit."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from nodes.contracts.segmenter import _blur
from nodes.contracts.segmenter._blur import gaussian_blur

SIGMAS = (0.4, 0.5, 0.75, 1.0, 1.5, 2.0, 3.0, 5.0)  # px; the segmenters use 0.5, 1 and 2


@pytest.fixture
def fast_everywhere(monkeypatch):
    """The fast path for every size and kernel length (it is only chosen where it is faster)."""
    monkeypatch.setattr(_blur, "_MAX_FAST_VALUES", 10**9)
    monkeypatch.setattr(_blur, "_MIN_FAST_KSIZE", 1)


def test_kernel_read_back_from_opencv():
    for sigma in SIGMAS:
        k = _blur._checked_kernel(sigma)
        if k is None:
            pytest.skip(
                f"this OpenCV's 8-bit GaussianBlur is not the fixed-point path (sigma {sigma}): "
                "gaussian_blur is cv2.GaussianBlur itself"
            )
        assert k.sum() == 256 and np.array_equal(k, k[::-1]) and k[0] > 0, (sigma, k)
        assert np.all(k == np.round(k)), (sigma, k)


def test_same_pixels_as_cv2(fast_everywhere):
    rng = np.random.default_rng(7)
    n = 0
    for i in range(400):
        h, w = (int(x) for x in rng.integers(1, 90, 2))
        cn = int(rng.choice([1, 3, 4]))
        img = rng.integers(0, 256, (h, w, cn) if cn > 1 else (h, w), dtype=np.uint8)
        if i % 4 == 1:  # hard edges and saturated areas: the extremes of the integer sums
            img = np.where(img > 127, 255, 0).astype(np.uint8)
        elif i % 4 == 2:
            img[:] = 255
        sigma = SIGMAS[i % len(SIGMAS)]
        assert np.array_equal(gaussian_blur(img, sigma), cv2.GaussianBlur(img, (0, 0), sigma)), (
            img.shape,
            sigma,
        )
        n += 1
    # A window of a larger image (not contiguous): the segmenters' regions of interest.
    big = rng.integers(0, 256, (150, 170, 3), dtype=np.uint8)
    for sigma in (1.0, 2.0):
        win = big[13:97, 21:118]
        assert np.array_equal(gaussian_blur(win, sigma), cv2.GaussianBlur(win, (0, 0), sigma))
    assert n == 400


def test_impulses_of_every_value(fast_everywhere):
    # Isolated impulses: each output is v k_i k_j / 2**16, so some land exactly on a half and the
    # rounding direction shows (e.g. v = 128 on taps 16 x 16 of sigma 2).
    for sigma in (1.0, 2.0, 3.0):
        step = 2 * int(np.ceil(3 * sigma)) + 3
        img = np.zeros((16 * step, 16 * step), np.uint8)
        img[step // 2 :: step, step // 2 :: step] = np.arange(256, dtype=np.uint8).reshape(16, 16)
        assert np.array_equal(gaussian_blur(img, sigma), cv2.GaussianBlur(img, (0, 0), sigma)), (
            sigma
        )


def test_other_types_and_large_images_use_opencv():
    rng = np.random.default_rng(1)
    f = rng.random((40, 50, 3), dtype=np.float32)
    assert np.array_equal(gaussian_blur(f, 2.0), cv2.GaussianBlur(f, (0, 0), 2.0))
    big = rng.integers(0, 256, (480, 640, 3), dtype=np.uint8)
    assert np.array_equal(gaussian_blur(big, 2.0), cv2.GaussianBlur(big, (0, 0), 2.0))
