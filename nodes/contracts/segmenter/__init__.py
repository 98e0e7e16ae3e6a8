"""The segmenter contract: what every segmentation method is, and the shell that makes one a node.

A method is a *mask function* (:class:`MaskFunction`): which pixels of one image may belong to
the object. :func:`segmenter` turns it into a complete ``segmenter.*`` node with the shared ports
(:data:`SEGMENTER_INPUTS`, :data:`SEGMENTER_OUTPUTS`), the candidate search, the checks between
left and right, partial views, sub-pixel refinement and the overlay (``_pair.segment_pair``).
Parameters derive from :class:`SegmenterParams` (the object, the working range, the checks).
:func:`find_instances` finds every instance of an object instead of one (``segmenter.instances``).
Pixel helpers a method may use: :func:`fill_holes`, :func:`max_hole_area`,
:func:`structuring_element`, :func:`to_channel`, :func:`gaussian_blur`.
"""

from __future__ import annotations

from collections.abc import Callable

from stereograph.api import node

from ._blur import gaussian_blur
from ._checks import pair_is_raw, validate_pair
from ._color import color_distance_map
from ._instances import find_instances, same_ball
from ._pair import as_bgr, segment_pair
from ._params import (
    SEGMENTER_INPUTS,
    SEGMENTER_OUTPUTS,
    MaskFunction,
    ObjectSpec,
    SegmenterParams,
    apply_appearance,
    apply_objects,
)
from ._pixels import fill_holes, max_hole_area, structuring_element, to_channel
from ._size import expected_radius_px

__all__ = [
    "SEGMENTER_INPUTS",
    "SEGMENTER_OUTPUTS",
    "MaskFunction",
    "ObjectSpec",
    "SegmenterParams",
    "apply_appearance",
    "apply_objects",
    "as_bgr",
    "color_distance_map",
    "expected_radius_px",
    "fill_holes",
    "find_instances",
    "gaussian_blur",
    "max_hole_area",
    "pair_is_raw",
    "same_ball",
    "segment_pair",
    "segmenter",
    "structuring_element",
    "to_channel",
    "validate_pair",
]


def segmenter(
    name: str,
    params: type[SegmenterParams] = SegmenterParams,
    version: str = "1",
    check: Callable | None = None,
    before: Callable | None = None,
) -> Callable[[MaskFunction], Callable]:
    """Decorator: a mask function -> a registered segmenter node named ``name``.

    The node's description is the mask function's docstring. ``check(params, wired)`` refuses a
    configuration when the pipeline is validated; ``before(params)`` may refuse one at run time
    (a NodeError) after the learned colour is applied. The returned node function keeps the mask
    function as ``.mask``.
    """
    method = name.rpartition(".")[2]

    def wrap(mask: MaskFunction) -> Callable:
        def run(params, pair, rectification=None, appearance=None, objects=None, ctx=None):
            params, color_from = apply_appearance(
                apply_objects(params, objects, ctx), appearance, ctx
            )
            if before is not None:
                before(params)
            return segment_pair(pair, rectification, params, mask, method, ctx, color_from)

        run.__name__ = run.__qualname__ = method
        # (the cache keys the method's own code)
        run.__module__, run.__doc__ = mask.__module__, mask.__doc__
        run.mask = mask
        return node(
            name,
            inputs=SEGMENTER_INPUTS,
            outputs=SEGMENTER_OUTPUTS,
            params=params,
            version=version,
            check=check,
        )(run)

    return wrap
