"""Parameters and the port interface every segmenter shares: the object model, shadow and
partial-view settings, and the type of a method's mask function (:class:`MaskFunction`).
"""

from __future__ import annotations

from typing import Protocol

import numpy as np
from pydantic import model_validator

from nodes.contracts.objects import ObjectSpec, declared_object
from stereograph.api import Field, In, Out, Params, PositiveRange


class MaskFunction(Protocol):
    """``mask(image_bgr, params, r_range_px, scale, roi) -> uint8 mask`` (255 = may be the object).

    Parameters
    ----------
    image_bgr : ndarray
        One rectified image (BGR or gray uint8), downscaled by ``scale`` while detecting.
    params : SegmenterParams
        The node's parameters (the method's own fields included).
    r_range_px : (float, float)
        Smallest and largest image radius of the object at this scale (px), from the calibration,
        the object's radius and the working range.
    scale : int
        Downscale factor of ``image_bgr`` (1 = full resolution): divide full-resolution sizes by it.
    roi : bool
        True for the small full-resolution window around a detected object (its border is
        background), False for a whole image.
    """

    def __call__(
        self,
        image_bgr: np.ndarray,
        params: SegmenterParams,
        r_range_px: tuple[float, float],
        scale: int = 1,
        roi: bool = False,
    ) -> np.ndarray: ...


# Every segmenter has this interface, so that swapping methods is a one-line YAML change.
SEGMENTER_INPUTS = {
    "pair": In(
        "RectifiedPair | StereoPair",
        description="Rectified pair, or camera images rectified on request (needs "
        "`rectification`).",
    ),
    "rectification": In("Rectification", optional=True, description="For the expected ball size."),
    "appearance": In(
        "ObjectAppearance",
        optional=True,
        description="The ball's colour learned from training truth (segmenter.appearance); used "
        "when "
        "object.color_bgr and hue_range_deg are unset.",
    ),
    "objects": In(
        "Objects",
        optional=True,
        description="What is on the table (objects.declare): its object and working range "
        "replace the "
        "node's own `object` and `working_range_cm`, whatever the segmenter type.",
    ),
}
SEGMENTER_OUTPUTS = {
    "segmentation": Out("Segmentation", description="Masks and region properties."),
    "overlay": Out(
        "Image",
        save=True,
        lossy=True,
        description="Left|right with outline and centroid (BGR, JPEG).",
    ),
}


class ShadowParams(Params):
    """Shadow suppression: drop dark, low-saturation pixels that the mask took from the table."""

    enabled: bool = Field(True, description="Remove shadow pixels attached to the object (bool).")
    max_removed_fraction: float = Field(
        0.8,
        gt=0,
        le=1,
        description="Keep a region unchanged if more than this share would go (a dark object, "
        "not a shadow; ratio).",
    )
    max_brightness_ratio: float = Field(
        0.8,
        gt=0,
        lt=1,
        description="A shadow pixel is at most this fraction of the local background brightness "
        "(ratio).",
    )
    max_saturation_gain: int = Field(
        30,
        ge=0,
        le=255,
        description="A shadow pixel is at most this much more saturated than the background (HSV "
        "S, 0-255).",
    )
    max_chroma_shift: float = Field(
        0.12,
        gt=0,
        description="Max change of normalised chromaticity (b,g,r)/sum vs the background "
        "(unitless).",
    )


class PartialParams(Params):
    """Balls cut by the image border, partly hidden or touching another object (issue 15)."""

    enabled: bool = Field(
        True,
        description="When no whole ball is found, fit the sphere's image to the true part of a "
        "region's "
        "outline (bool); see nodes/contracts/segmenter/_partial.py.",
    )
    max_sigma_z_cm: float = Field(
        0.25,
        gt=0,
        description="Report a partly seen ball only if the depth uncertainty predicted from the "
        "fit of "
        "its visible arc (1 sigma, both views) is at most this (cm); 4 sigma = 1 cm.",
    )
    min_disc_coverage: float = Field(
        0.4,
        gt=0,
        le=1,
        description="Share of the fitted ball's in-image disc the region must cover (ratio): an "
        "arc "
        "that the region does not fill is not a ball.",
    )
    size_tolerance: float = Field(
        0.01,
        ge=0,
        le=0.5,
        description="Besides the fits' own 3 sigma, how far (ratio) a partly seen ball's distance "
        "from its fitted size may differ from the stereo distance (the radius's and "
        "the calibration's error).",
    )
    ambiguous_second_arc: float = Field(
        0.3,
        gt=0,
        le=1,
        description="A merged region whose remaining outline holds this share (ratio) of a second "
        "ball image of similar size, of the same colour or with no colour given, is "
        "refused as ambiguous.",
    )


class SegmenterParams(Params):
    """Parameters common to every segmenter."""

    object: ObjectSpec = Field(
        default_factory=ObjectSpec,
        description="Object model (radius in cm, colour); "
        "a wired `objects` input (objects.declare) replaces it.",
    )
    object_name: str | None = Field(
        None,
        description="Which declared object to segment when `objects` is wired "
        "(name; None = the first).",
    )
    working_range_cm: PositiveRange = Field(
        (20.0, 80.0),
        description="Nearest and farthest distance of the object from the cameras (cm).",
    )
    radius_px_range: PositiveRange | None = Field(
        None,
        description="Expected image radius range (px) when no Rectification is wired; None = 3 "
        "px .. half the image.",
    )
    min_roundness: float = Field(
        0.72,
        ge=0,
        le=1,
        description="Min area / (pi * r_max^2) of a candidate, 1 = disc (unitless).",
    )
    ambiguity_ratio: float = Field(
        0.1,
        gt=0,
        le=1,
        description="Second-best plausible candidate (ball-sized, round, the object's colour "
        "when given) area / best "
        "area at or above which the choice is ambiguous (ratio). Size alone cannot tell "
        "two balls apart "
        "(a nearer one looks bigger), so the default 0.1 counts any second ball down to "
        "a third of the "
        "first's image radius.",
    )
    max_area_ratio: float = Field(
        1.25, ge=1, description="Max ratio of the left and right region areas (ratio)."
    )
    max_row_offset_px: float = Field(
        2.0,
        ge=0,
        description="Max |v_left - v_right| of the two centroids in rectified images (px).",
    )
    detect_downscale: int | None = Field(
        None,
        ge=1,
        le=8,
        description="Downscale factor for detection; None = from the smallest expected radius.",
    )
    coarse_first: bool = Field(
        True,
        description="With an automatic detect_downscale, look first at a level twice as coarse "
        "when the largest "
        "expected ball is >= 8 px there, and fall back to the regular level when no "
        "plausible region of "
        ">= 4 px radius is found there (bool; faster for near and mid-range balls).",
    )
    subpixel: bool = Field(True, description="Refine the contour to sub-pixel accuracy (bool).")
    edge_search_px: float = Field(
        3.0,
        ge=0.5,
        le=20,
        description="Half length of the normal search for the sub-pixel edge (px); "
        "at least half a pixel, or it samples nothing.",
    )
    shadow: ShadowParams = Field(
        default_factory=ShadowParams, description="Shadow suppression options."
    )
    partial: PartialParams = Field(
        default_factory=PartialParams, description="Partly visible / touching balls."
    )
    max_size_mismatch: float = Field(
        0.15,
        gt=0,
        le=1,
        description="Max relative difference between the distance the silhouette's size gives for "
        "a ball of object.radius_cm and the stereo distance (ratio); above -> not found "
        "(another object, or the wrong radius in the YAML).",
    )
    lr_size_tolerance_px: float = Field(
        0.5,
        ge=0,
        description="Besides 3 sigma of the two outline fits, how far the left and right "
        "silhouettes may "
        "disagree in size (px of image radius; half a pixel: what a sub-pixel outline must "
        "beat); above -> not found (one view sees only part of the ball).",
    )
    overlay: bool = Field(
        True, description="Render the overlay image (bool); off = no overlay output."
    )

    @model_validator(mode="after")
    def _ball_fits_the_working_range(self) -> SegmenterParams:
        far = max(self.working_range_cm)
        if far <= self.object.radius_cm:
            raise ValueError(
                f"working_range_cm ends at {far:g} cm, within the ball's own radius "
                "(object.radius_cm "
                f"{self.object.radius_cm:g} cm): the cameras would be inside the ball; give the "
                "distances from the cameras to the ball's centre, in cm"
            )
        return self


def apply_objects(params: SegmenterParams, objects: dict | None, ctx=None) -> SegmenterParams:
    """``params`` with the declared object and working range when ``objects`` is wired (they rule:
    the object is declared once for the pipeline); a warning when the node sets its own as well."""
    if objects is None:
        return params
    obj, working_range = declared_object(objects, params.object_name)
    own = {"object", "working_range_cm"} & params.model_fields_set
    if own and ctx is not None:
        ctx.warn(
            f"{' and '.join(sorted(own))} of this node are not used: the wired `objects` "
            "declares them "
            "(remove them here, or unwire `objects`)"
        )
    return params.model_copy(update={"object": obj, "working_range_cm": working_range})


def apply_appearance(
    params: SegmenterParams, appearance: dict | None, ctx=None
) -> tuple[SegmenterParams, str | None]:
    """``params`` with the learned colour when the YAML gives none, and where the colour comes from.

    Returns ``(params, source)``, ``source`` being ``"params"`` (the YAML's colour or hue range
    wins; with ``ctx``, a warning says the learned one is not used), ``"appearance"`` (learned,
    ``segmenter.appearance``) or None (no colour at all).
    """
    obj = params.object
    if obj.color_bgr is not None or obj.hue_range_deg is not None:
        if appearance is not None and ctx is not None:
            ctx.warn(
                "object.color_bgr / hue_range_deg is given in the YAML: the colour "
                "learned by the wired "
                "`appearance` input is not used (remove one of the two)"
            )
        return params, "params"
    if appearance is None:
        return params, None
    try:
        colour = tuple(int(c) for c in appearance["color_bgr"])
        tol = float(appearance["color_tolerance"])
        if len(colour) != 3 or not all(0 <= c <= 255 for c in colour) or not 0 < tol <= 2:
            raise ValueError
    except (KeyError, TypeError, ValueError):
        from stereograph.api import NodeError

        raise NodeError(
            "the segmenter's `appearance` input is not an ObjectAppearance (color_bgr: 3 values "
            "0-255, color_tolerance in (0, 2]).",
            hint="wire `appearance` to segmenter.appearance's `appearance` output.",
        ) from None
    learned = obj.model_copy(update={"color_bgr": colour, "color_tolerance": tol})
    return params.model_copy(update={"object": learned}), "appearance"
