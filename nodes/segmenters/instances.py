"""``segmenter.instances``: every instance of every declared object in each pair, one result each.

The objects come from the wired ``objects`` (objects.declare); ``method`` names the mask function
(any built-in segmenter's). Each instance is its own item of the ``segmentation`` collection,
``<pair>/<object><k>``, so the per-item disparity, locator, compensator and IK nodes locate each
ball; refused instances are items too (``found: false`` with the reason). Two objects claiming
one ball: the closer colour wins, else both are refused.
"""

from __future__ import annotations

import difflib
from typing import Any, Literal

import cv2
import numpy as np
from pydantic import ValidationError, model_validator

from nodes.contracts.overlay import label_pair
from nodes.contracts.segmenter import (
    SegmenterParams,
    apply_objects,
    as_bgr,
    expected_radius_px,
    find_instances,
    pair_is_raw,
    same_ball,
    validate_pair,
)
from nodes.contracts.views import pair_views
from stereograph.api import Field, In, Out, node

from . import color, edge_morph, hough, otsu, slic, watershed

METHODS = {
    "edge_morph": (edge_morph.edge_morph, edge_morph.EdgeMorphParams),
    "color": (color.color, color.ColorParams),
    "otsu": (otsu.otsu, otsu.OtsuParams),
    "hough": (hough.hough, hough.HoughParams),
    "watershed": (watershed.watershed, watershed.WatershedParams),
    "slic": (slic.slic, slic.SlicParams),
}


class InstancesParams(SegmenterParams):
    method: Literal[tuple(METHODS)] = Field(
        "color",
        description="The mask function: which segmenter's method finds the objects' pixels.",
    )
    method_params: dict[str, Any] = Field(
        default_factory=dict,
        description="That method's own parameters "
        "(as its segmenter node takes them, e.g. {open_px: 3}).",
    )
    max_per_object: int = Field(
        8, ge=1, le=64, description="Most instances of one object per pair (count)."
    )

    @model_validator(mode="after")
    def _method_params_fit(self) -> InstancesParams:
        cls = METHODS[self.method][1]
        for key in self.method_params:
            if key not in cls.model_fields:
                near = difflib.get_close_matches(key, cls.model_fields, n=1)
                raise ValueError(
                    f"method_params: segmenter.{self.method} has no parameter {key!r}"
                    + (f" (did you mean {near[0]!r}?)" if near else "")
                    + f"; `stereograph nodes segmenter.{self.method}` lists them"
                )
        try:
            self.for_method()
        except ValidationError as e:
            first = e.errors()[0]
            where = ".".join(str(x) for x in first["loc"])
            raise ValueError(
                f"method_params: segmenter.{self.method} parameter {where!r}: {first['msg']}"
            ) from None
        return self

    def for_method(self) -> SegmenterParams:
        """The chosen method's own params: these common ones and ``method_params``."""
        common = self.model_dump(
            exclude={"method", "method_params", "max_per_object"}, exclude_unset=True
        )
        return METHODS[self.method][1].model_validate({**common, **self.method_params})


def _record(
    pid: str, name: str, k: int, inst: dict, params: SegmenterParams, pair: dict, method: str
) -> dict:
    return {
        "id": f"{pid}/{name}{k}",
        "pair": pid,
        "object": name,
        "instance": k,
        "found": inst["found"],
        "reason": inst["reason"],
        "left": inst.get("left"),
        "right": inst.get("right"),
        "left_mask": None,
        "right_mask": None,
        "left_px": inst["left_px"],
        "method": f"instances:{method}",
        "merged": bool(inst.get("merged")),  # found in a region of more than one ball
        "object_radius_cm": float(params.object.radius_cm),
        "working_range_cm": sorted(float(z) for z in params.working_range_cm),
        "color_from": "params" if params.object.color_bgr is not None else None,
        "split": pair.get("split"),
        "rejected_left_px": [],
        "rejected_left_why": [],
        "rejected_right_px": [],
        "rejected_right_why": [],
    }


def _one_claim(found: list[tuple[str, dict]]) -> None:
    """A ball claimed by two objects: the closer colour keeps it, else both are refused."""
    for i, (na, a) in enumerate(found):
        for nb, b in found[i + 1 :]:
            if not (a["found"] and b["found"] and same_ball(a, b)):
                continue
            sa, sb = a.get("color_score"), b.get("color_score")
            if sa is not None and sb is not None and abs(sa - sb) > 0.25:
                lose = b if sa < sb else a
                lose.update(
                    found=False,
                    reason=f"the same ball as a {na if lose is b else nb}, whose colour is closer",
                )
            else:
                for x in (a, b):
                    x.update(found=False, reason=f"{na} or {nb}: their colours cannot tell which")


def _pair_instances(
    params: InstancesParams, pair: dict, rect: dict, objects: dict, raw: bool
) -> list[dict]:
    L, R = as_bgr(np.asarray(pair["left"])), as_bgr(np.asarray(pair["right"]))
    pid = str(pair.get("id"))
    bad = validate_pair(pair, rect, raw)
    names = [o["name"] for o in objects["objects"]]
    if bad is not None:
        return [
            _record(
                pid,
                n,
                1,
                {"found": False, "reason": bad, "left_px": [0.0, 0.0]},
                params,
                pair,
                params.method,
            )
            for n in names
        ]
    vl, vr = pair_views(rect, L, R, raw)
    K1, K2 = np.asarray(rect["P1"], float)[:, :3], np.asarray(rect["P2"], float)[:, :3]
    found: list[tuple[str, dict, SegmenterParams]] = []
    own = params.for_method()
    for name in names:
        p = apply_objects(own.model_copy(update={"object_name": name}), objects)
        r_range = expected_radius_px(p, rect, vl.shape[1::-1])
        insts = find_instances(vl, vr, METHODS[params.method][0].mask, p, r_range, rect, K1, K2)
        found += [(name, x, p) for x in insts[: params.max_per_object]]
    _one_claim([(n, x) for n, x, _ in found])
    count: dict[str, int] = {}
    out = []
    for name, inst, p in found:
        count[name] = count.get(name, 0) + 1
        out.append(_record(pid, name, count[name], inst, p, pair, params.method))
    return out


def draw(pair: dict, records: list[dict], rect: dict, raw: bool) -> np.ndarray:
    """Left | right with each instance's outline and label (green: found, red: refused)."""
    vl, vr = pair_views(
        rect, as_bgr(np.asarray(pair["left"])), as_bgr(np.asarray(pair["right"])), raw
    )
    left, right = vl.full().copy(), vr.full().copy()
    for r in records:
        colour = (0, 200, 0) if r["found"] else (0, 0, 230)
        for img, side in ((left, "left"), (right, "right")):
            reg = r.get(side)
            if reg is not None and reg.get("contour_px") is not None:
                cv2.polylines(
                    img, [np.round(np.asarray(reg["contour_px"])).astype(np.int32)], True, colour, 1
                )
        u, v = (int(round(c)) for c in r["left_px"])
        cv2.putText(
            left, r["id"].split("/")[-1], (u + 6, v - 6), cv2.FONT_HERSHEY_SIMPLEX, 0.4, colour, 1
        )
    n = sum(r["found"] for r in records)
    return label_pair(
        np.hstack([left, right]),
        pair.get("id"),
        True,
        None,
        f"{n} of {len(records)} instance(s) found",
    )


@node(
    "segmenter.instances",
    inputs={
        "pair": In("RectifiedPair | StereoPair", gather=True, description="Every pair."),
        "rectification": In(
            "Rectification", description="For the ball sizes and the left/right match."
        ),
        "objects": In("Objects", description="What to look for (objects.declare)."),
    },
    outputs={
        "segmentation": Out("Segmentation", collection=True, description="One item per instance."),
        "overlay": Out(
            "Image", save=True, lossy=True, description="The last pair with every instance."
        ),
    },
    params=InstancesParams,
    version="1",
)
def instances(params: InstancesParams, pair, rectification, objects, ctx=None):
    """Find every instance of every declared object (left/right matched by rows and size)."""
    raw = pair_is_raw(ctx, rectification)
    pairs = pair if isinstance(pair, dict) and "left" not in pair else {str(pair.get("id")): pair}
    segs, recs = {}, []
    for pid in pairs:
        recs = _pair_instances(params, pairs[pid], rectification, objects, raw)
        segs.update({r["id"]: r for r in recs})
        if ctx is not None:
            for r in recs:
                if not r["found"]:
                    ctx.warn(f"{r['id']}: {r['reason']}")
    # (the last pair)
    overlay = draw(pairs[pid], recs, rectification, raw) if params.overlay and pairs else None
    return {"segmentation": segs, "overlay": overlay}
