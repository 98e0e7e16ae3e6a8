"""``source.synthetic``: a physically consistent synthetic stereo rig with ground truth.

The images are ray-cast (see :mod:`nodes.sources._render`): every pixel's ray
goes through the camera's distortion model into a textured table scene with a
matte ball, Lambertian shading, a soft cast shadow and image noise. The rig's
cameras, the ball's centre and its exact silhouette come with every render.
"""

from __future__ import annotations

import copy
import functools
import threading
from typing import Literal

import numpy as np
from pydantic import field_validator, model_validator

from nodes.contracts.board import charuco_board
from nodes.sources._boards import random_board_poses, render_board_view
from nodes.sources._materials import _table_texture, color_bgr
from nodes.sources._render import _empty_table, render_scene
from nodes.sources._rig import _ray_grid, make_rig
from nodes.sources._scene_spec import SceneSpec
from nodes.sources._scenes import SCENE_KINDS, make_scene
from stereograph.api import Field, NodeError, Out, Params, node

# every scene kind but the plain one
HardCase = Literal[tuple(k for k in SCENE_KINDS if k != "plain")]


class SyntheticParams(Params):
    image_width_px: int = Field(640, ge=64, le=4096, description="Image width, pixels.")
    image_height_px: int = Field(480, ge=48, le=4096, description="Image height, pixels.")
    focal_length_px: float = Field(
        560.0, gt=50, le=100_000, description="Left camera focal length, pixels."
    )
    focal_ratio_right: float = Field(
        1.006, gt=0.5, lt=2, description="Right / left focal length (unitless)."
    )
    distortion_left: tuple[float, float, float, float] = Field(
        (-0.12, 0.06, 0.0008, -0.0005),
        description="Left camera k1, k2, p1, p2 (OpenCV model, unitless).",
    )
    distortion_right: tuple[float, float, float, float] = Field(
        (-0.10, 0.04, -0.0006, 0.0007),
        description="Right camera k1, k2, p1, p2 (OpenCV model, unitless).",
    )
    baseline_cm: float = Field(
        8.0, gt=0.5, le=50, description="Distance between the optical centres, cm."
    )
    rotation_deg: tuple[float, float, float] = Field(
        (0.6, -1.2, 0.4),
        description="Rotation vector of the right camera relative to the left, degrees.",
    )
    camera_height_cm: float = Field(
        32.0, gt=5, description="Height of the left optical centre above the table, cm."
    )
    camera_tilt_deg: float = Field(
        45.0, gt=10, lt=90, description="Optical axis below the horizontal, degrees."
    )
    light_cm: tuple[float, float, float] = Field(
        (18.0, 12.0, 90.0), description="Point light, table frame, cm."
    )
    ambient: float = Field(
        0.35, ge=0, le=1, description="Ambient share of the lighting (unitless)."
    )
    shadow_strength: float = Field(
        0.7, ge=0, le=1, description="Light blocked in a full shadow (0..1)."
    )
    noise_sigma: float = Field(2.0, ge=0, le=50, description="Gaussian image noise, grey levels.")
    ball_radius_cm: float = Field(2.0, gt=0.2, le=20, description="Ball radius, cm.")
    ball_color: str | tuple[int, int, int] = Field(
        "orange", description="Ball colour: a name (orange, red, green, ...) or [b, g, r] 0..255."
    )
    n_scenes: int = Field(120, ge=0, le=5000, description="Number of plain ball scenes (count).")
    min_distance_cm: float = Field(
        30.0, gt=5, description="Nearest ball centre from the left camera, cm."
    )
    max_distance_cm: float = Field(
        60.0, gt=5, description="Farthest ball centre from the left camera, cm."
    )
    placement_region_cm: tuple[float, float, float, float] | None = Field(
        None,
        description="Keep ball centres in an annulus of the table: centre x, y and radii min, "
        "max (cm, "
        "table frame) — e.g. what an arm standing there can reach; None = anywhere in view.",
    )
    hard_cases: list[HardCase] = Field(
        default_factory=list,
        description="Extra hard scene kinds to add (clutter, second_ball, border, occluded, "
        "hidden, empty; issue 15: border_cut, occluded_part, touching_box, "
        "touching_ball, distractor, same_color -- see "
        "nodes/sources/_hard_scenes.py).",
    )
    n_hard_each: int = Field(10, ge=0, le=1000, description="Scenes per hard case (count).")
    scenes: list[SceneSpec] = Field(
        default_factory=list,
        description="Explicit scenes, appended: {id, kind, ball: {center_cm, radius_cm, color}, "
        "objects: [{type: box|cylinder|ball, center_cm, size_cm, ...}]} "
        "(nodes/sources/_scene_spec.py).",
    )
    n_views: int = Field(16, ge=0, le=200, description="Chessboard calibration views (count).")
    board_cols: int = Field(9, ge=3, le=40, description="Chessboard inner corners per row (count).")
    board_rows: int = Field(
        6, ge=3, le=40, description="Chessboard inner corners per column (count)."
    )
    square_cm: float = Field(2.5, gt=0.1, le=20, description="Chessboard square size, cm.")
    board_type: Literal["chessboard", "charuco"] = Field(
        "chessboard",
        description="Calibration board: a plain chessboard, or OpenCV's ChArUco board (ArUco "
        "markers "
        "in the light squares; board_cols x board_rows inner corners).",
    )
    aruco_dict: str = Field(
        "DICT_4X4_50", description="ArUco dictionary of the ChArUco board (an OpenCV name)."
    )
    marker_fraction: float = Field(
        0.7, gt=0.1, lt=1.0, description="ChArUco marker side / square side (unitless)."
    )
    train_fraction: float = Field(
        0.5, ge=0, le=1, description="Share of scenes marked split=train (0..1)."
    )
    split_mode: Literal["span", "random"] = Field(
        "span",
        description="How scenes are split: span = the nearest and the farthest plain placement "
        "are train "
        "(a correction fitted on the train split then covers the whole working range), the "
        "rest at random; random = all at random.",
    )
    truth_masks: bool = Field(
        False, description="Add the ball's per-pixel coverage (float32 0..1) to the truth."
    )
    seed: int = Field(0, ge=0, description="Seed of placements, noise and split.")

    @model_validator(mode="after")
    def _check_ranges(self):
        # Checked here, not at run time, so `stereograph validate` reports them (exit 2, file:line).
        if self.max_distance_cm <= self.min_distance_cm:
            raise ValueError(
                f"max_distance_cm ({self.max_distance_cm}) must exceed min_distance_cm "
                f"({self.min_distance_cm}); widen the distance range"
            )
        if self.placement_region_cm is not None:
            r_min, r_max = self.placement_region_cm[2:]
            if not 0 <= r_min < r_max:
                raise ValueError(
                    f"placement_region_cm radii must satisfy 0 <= min < max, got min {r_min}, "
                    f"max {r_max}"
                )
        return self

    @model_validator(mode="after")
    def _check_charuco(self):
        if self.board_type == "charuco":
            charuco_board(
                self.board_cols,
                self.board_rows,
                self.square_cm,
                self.aruco_dict,
                self.marker_fraction,
            )  # ValueError naming the known dictionaries
        return self

    @field_validator("ball_color")
    @classmethod
    def _check_color(cls, value):
        color_bgr(value)  # ValueError naming the known colours
        return value


def _rig_kwargs(p: SyntheticParams) -> dict:
    return {
        "image_width_px": p.image_width_px,
        "image_height_px": p.image_height_px,
        "focal_length_px": p.focal_length_px,
        "focal_ratio_right": p.focal_ratio_right,
        "distortion_left": tuple(p.distortion_left),
        "distortion_right": tuple(p.distortion_right),
        "baseline_cm": p.baseline_cm,
        "rotation_deg": tuple(p.rotation_deg),
        "camera_height_cm": p.camera_height_cm,
        "camera_tilt_deg": p.camera_tilt_deg,
        "light_cm": tuple(p.light_cm),
        "ambient": p.ambient,
        "shadow_strength": p.shadow_strength,
        "noise_sigma": p.noise_sigma,
    }


def synthetic_rig(params: SyntheticParams) -> dict:
    """The rig (cameras, pose over the table, light) described by the node's params."""
    return make_rig(**_rig_kwargs(params))


@functools.lru_cache(maxsize=4)
def _shared_rig(params_json: str) -> dict:
    """The rig of these params, one per process: the scene plan and the calibration views share
    it, and with it the lit empty table each camera renders once (``rig["_cache"]``)."""
    params = SyntheticParams.model_validate_json(params_json)
    try:
        return synthetic_rig(params)
    except ValueError as exc:
        raise NodeError(
            f"source.synthetic: {exc}", hint="fix the parameter in the pipeline YAML"
        ) from exc


def _light_empty_table(rig: dict, i: int) -> None:
    """Camera ``i``'s lit empty table: what every render of this rig starts from. Large-array
    NumPy/OpenCV work that releases the GIL, so the two cameras' run on two threads. A failure
    here is left to the render that needs the table, which computes it again and says what went
    wrong."""
    try:
        _empty_table(rig, i, _table_texture(int(rig["params"]["texture_seed"])))
    except Exception:  # noqa: BLE001 -- only a head start: the render reports the error
        pass


def _head_start(rig: dict, jobs: list, lock: threading.Lock, texture: bool) -> None:
    """Make the table's texture (``texture``), then take the cameras' ray grids off ``jobs`` until
    none is left: what the first render needs, see :func:`_plan`. Errors as above."""
    try:
        if texture:
            _table_texture(int(rig["params"]["texture_seed"]))
        while True:
            with lock:
                if not jobs:
                    return
                cam = jobs.pop(0)
            _ray_grid(cam, tuple(rig["truth"]["image_size"]))
    except Exception:  # noqa: BLE001 -- only a head start
        pass


@functools.lru_cache(maxsize=4)
def _plan(params_json: str) -> tuple[dict, list[tuple[str, dict]], list[str]]:
    """The rig, every scene's description and split, in id order (cheap: nothing is rendered).

    Cached by the params' JSON, so that a process producing many items plans once. The first
    render needs the table's texture, both cameras' ray grids and both lit empty tables (~0.6 s
    of CPU), made here on two threads: the texture (large-array work that releases the GIL) on
    one while this one plans the scenes, each then undistorting a camera's ray grid; then one
    camera's table on each. Before a pool forks this process, so its workers inherit all of it.
    """
    params = SyntheticParams.model_validate_json(params_json)
    rig = _shared_rig(params_json)
    jobs, lock = list(rig["cams"]), threading.Lock()
    other = threading.Thread(
        target=_head_start,
        args=(rig, jobs, lock, True),
        name="stereograph-synthetic-texture",
        daemon=True,
    )
    other.start()
    try:
        plan = _plan_scenes(params, rig)
        _head_start(rig, jobs, lock, False)
    finally:
        other.join()  # before anything renders, and before a pool forks this process
    right = threading.Thread(
        target=_light_empty_table, args=(rig, 1), name="stereograph-synthetic-table", daemon=True
    )
    right.start()
    try:
        _light_empty_table(rig, 0)
    finally:
        right.join()
    return plan


def _plan_scenes(
    params: SyntheticParams, rig: dict
) -> tuple[dict, list[tuple[str, dict]], list[str]]:
    specs: list[tuple[str, dict]] = []
    scene_kw = {
        "radius_cm": params.ball_radius_cm,
        "color": params.ball_color,
        "min_distance_cm": params.min_distance_cm,
        "max_distance_cm": params.max_distance_cm,
        "region_cm": params.placement_region_cm,
    }
    try:
        for i in range(params.n_scenes):
            rng = np.random.default_rng([params.seed, 1, i])
            specs.append((f"s{i:03d}", make_scene(rig, "plain", rng, **scene_kw)))
        for kind in params.hard_cases:
            for i in range(params.n_hard_each):
                rng = np.random.default_rng([params.seed, 2, SCENE_KINDS.index(kind), i])
                specs.append((f"{kind}{i:03d}", make_scene(rig, kind, rng, **scene_kw)))
    except RuntimeError as exc:
        raise NodeError(
            f"source.synthetic: {exc}.", hint="check camera_height_cm / tilt and the distance range"
        ) from exc
    for i, sc in enumerate(params.scenes):
        specs.append((sc.id or f"custom{i:03d}", sc.model_dump(exclude_none=True, exclude={"id"})))

    forced_train: set[str] = set()
    if params.split_mode == "span" and params.train_fraction > 0:
        plain = [(pid, sc) for pid, sc in specs if sc.get("kind") == "plain" and sc.get("ball")]
        if len(plain) >= 4:
            # depth along the left optical axis: what z-based corrections are fitted against
            cam = rig["cams"][0]
            R, C1 = np.asarray(cam["R_table_from_cam"]), np.asarray(cam["origin_table"])
            dist = {
                pid: float(
                    (R.T @ (np.array([*sc["ball"]["center_cm"], sc["ball"]["radius_cm"]]) - C1))[2]
                )
                for pid, sc in plain
            }
            forced_train = {min(dist, key=dist.get), max(dist, key=dist.get)}
    # one draw per scene in order, as if drawn one by one (a per-item call gets the same split)
    draws = np.random.default_rng([params.seed, 3]).random(len(specs))
    splits = [
        "train" if (draws[k] < params.train_fraction or pid in forced_train) else "test"
        for k, (pid, _) in enumerate(specs)
    ]
    return rig, specs, splits


def _scene_ids(params: SyntheticParams, ctx=None) -> list[str]:
    """The pair ids, in the plan's order, without placing or rendering anything (the engine
    produces the pairs one per call)."""
    ids = [f"s{i:03d}" for i in range(params.n_scenes)]
    ids += [f"{kind}{i:03d}" for kind in params.hard_cases for i in range(params.n_hard_each)]
    return ids + [sc.id or f"custom{i:03d}" for i, sc in enumerate(params.scenes)]


def _render_pair(params: SyntheticParams, k: int) -> dict:
    """Render scene number ``k`` of the plan (its noise seed depends on ``k`` only)."""
    rig, specs, splits = _plan(params.model_dump_json())
    pid, scene = specs[k]
    try:
        left, right, truth = render_scene(
            rig, copy.deepcopy(scene), seed=params.seed * 100003 + k, coverage=params.truth_masks
        )
    except (ValueError, KeyError, TypeError) as exc:
        raise NodeError(
            f"source.synthetic: scene {pid!r} is malformed: {exc}",
            hint="see the scene description in nodes/sources/_render.py",
        ) from exc
    return {"id": pid, "left": left, "right": right, "truth": truth, "split": splits[k]}


@node(
    "source.synthetic",
    outputs={
        # a synthetic rig offers all three; each pipeline wires what it needs
        "pairs": Out(
            "StereoPair",
            collection=True,
            optional=True,
            description="Ball scenes with ground truth.",
        ),
        "views": Out(
            "StereoViews",
            optional=True,
            description="Chessboard calibration views (with the board poses).",
        ),
        "truth": Out(
            "RigTruth", optional=True, description="The rig's true cameras and table pose."
        ),
    },
    params=SyntheticParams,
    version="1",
    items=_scene_ids,
)
def synthetic(params: SyntheticParams, ctx=None) -> dict:
    """Render a synthetic stereo rig: ball scenes, chessboard views and the true cameras.

    Each pair carries ``split`` (train/test, seeded) and ``truth`` (see
    ``docs/artifacts.md``; also ``silhouette_left/right``, ``visible_fraction_*``,
    ``touches_border_*`` and ``kind``). The views carry ``board_poses_table``
    (``T_table_from_board`` per view, cm), so the Tsai calibrator can use them
    as one multi-plane 3-D target. In a run the engine renders the pairs one per
    call (``items=``), in the worker pool when there is one.
    """
    per_item = ctx is not None and ctx.producing_items
    if per_item and ctx.item is not None:
        ids = _scene_ids(params)
        if ctx.item not in ids:
            raise NodeError(f"source.synthetic: no scene {ctx.item!r} in this rig")
        return {"pairs": _render_pair(params, ids.index(ctx.item))}
    if per_item:  # the scenes are planned where the pairs are made (a worker): here the rig only
        rig = _shared_rig(params.model_dump_json())
    else:
        rig = _plan(params.model_dump_json())[0]
    report = ctx.progress if ctx is not None else (lambda *a: None)
    pairs = {}
    if not per_item:
        ids = _scene_ids(params)
        for k, pid in enumerate(ids):
            report(k, len(ids), "scenes")
            pairs[pid] = _render_pair(params, k)

    views, poses_table = _board_views(params, rig, report)
    truth = copy.deepcopy(rig["truth"])  # the plan is cached: hand out a copy
    board = {
        "cols": params.board_cols,
        "rows": params.board_rows,
        "square_cm": params.square_cm,
        "type": params.board_type,
    }
    if params.board_type == "charuco":
        board.update(dictionary=params.aruco_dict, marker_fraction=params.marker_fraction)
    out = {
        "views": {
            "views": views,
            "image_size": list(truth["image_size"]),
            "board": board,
            "truth": truth,
            "board_poses_table": poses_table,
        },
        "truth": truth,
    }
    if not per_item:
        out["pairs"] = pairs
    return out


def _board_views(params: SyntheticParams, rig: dict, report) -> tuple[list[dict], dict]:
    """``(the board views, each view's T_table_from_board)``: ``n_views`` random poses of the
    board, rendered in both cameras."""
    views: list[dict] = []
    poses_table: dict = {}
    if not params.n_views:
        return views, poses_table
    try:
        poses = random_board_poses(
            rig,
            params.n_views,
            np.random.default_rng([params.seed, 4]),
            params.board_cols,
            params.board_rows,
            params.square_cm,
        )
    except RuntimeError as exc:
        raise NodeError(
            f"source.synthetic: {exc}.",
            hint="use a smaller board (board_cols, board_rows, square_cm) "
            "or a shorter focal_length_px (a wider view)",
        ) from exc
    charuco = (
        {"dictionary": params.aruco_dict, "marker_fraction": params.marker_fraction}
        if params.board_type == "charuco"
        else None
    )
    for j, pose in enumerate(poses):
        report(j, len(poses), "views")
        vid = f"v{j:02d}"
        left, right, corners = render_board_view(
            rig,
            pose,
            params.board_cols,
            params.board_rows,
            params.square_cm,
            seed=params.seed * 7919 + j,
            charuco=charuco,
        )
        views.append({"id": vid, "left": left, "right": right})
        poses_table[vid] = corners["T_table_from_board"]
    return views, poses_table
