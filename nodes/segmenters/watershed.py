"""``segmenter.watershed``: the foreground split by a watershed on its distance transform
(scikit-image)."""

from __future__ import annotations

import numpy as np
from scipy import ndimage as ndi
from skimage.feature import peak_local_max
from skimage.segmentation import watershed as sk_watershed

from nodes.contracts.segmenter import segmenter
from stereograph.api import Field

from .otsu import OtsuParams, otsu_mask


class WatershedParams(OtsuParams):
    """Parameters of ``segmenter.watershed`` (Otsu's foreground, plus the common ones)."""

    min_separation: float = Field(
        1.0,
        gt=0,
        le=4,
        description="Least distance of two balls' centres, in smallest expected radii (ratio).",
    )
    max_disc_excess: float = Field(
        1.5,
        ge=1,
        le=4,
        description="Largest area of a piece over the disc of "
        "its inscribed radius (ratio); larger pieces are not balls.",
    )


def split_lines(labels: np.ndarray) -> np.ndarray:
    """Pixels of a region that touch another region (8-neighbours): where touching balls meet."""
    positive = np.where(labels > 0, labels, np.iinfo(labels.dtype).max)
    return (labels > 0) & (ndi.grey_erosion(positive, size=3) != ndi.grey_dilation(labels, size=3))


def watershed_mask(
    img_bgr: np.ndarray, params: WatershedParams, r_range_px, scale: int = 1, roi: bool = False
) -> np.ndarray:
    """Segment the ball by splitting Otsu's foreground with a watershed on its distance transform:
    one marker per distance peak at least a ball radius deep, so touching balls become separate
    regions.

    The mask (uint8 0/255) is the foreground less the lines where two regions meet; the shared
    selection then judges each region (size, roundness, colour when given).
    """
    fg = otsu_mask(img_bgr, params, r_range_px, scale, roi) > 0
    dist = ndi.distance_transform_edt(fg)
    peaks = peak_local_max(
        dist,
        min_distance=max(1, int(params.min_separation * r_range_px[0])),
        threshold_abs=0.5 * r_range_px[0],
        labels=ndi.label(fg)[0],
        exclude_border=False,
    )
    ids = np.arange(1, len(peaks) + 1)
    markers = np.zeros(dist.shape, np.int32)
    markers[tuple(peaks.T)] = ids
    labels = sk_watershed(-dist, markers, mask=fg)
    # A piece is kept if it is about the disc of its inscribed radius: a ball's is; the pieces a
    # watershed cuts from a box, a corner or a strip are much larger than theirs.
    area = np.bincount(labels.ravel(), minlength=len(ids) + 1)[1:]
    keep = np.zeros(len(ids) + 1, bool)
    keep[1:] = area <= params.max_disc_excess * np.pi * np.square(ndi.maximum(dist, labels, ids))
    return (keep[labels] & ~split_lines(labels)).astype(np.uint8) * 255


# : ``segmenter.watershed``: the node (the shared shell of nodes.contracts.segmenter around
# watershed_mask);
#: named as its method, so that a worker process finds it by name
watershed = segmenter("segmenter.watershed", params=WatershedParams)(watershed_mask)
