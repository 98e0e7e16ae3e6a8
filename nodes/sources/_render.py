"""Ray-cast renderer of a synthetic stereo rig's ball scenes: pure functions, no engine imports.

With :mod:`._rig` (cameras and light), :mod:`._lens` (distortion model), :mod:`._materials`
(colours, table texture), :mod:`._raycast` (intersections, shadows, shading, noise),
:mod:`._silhouette` (exact truth), :mod:`._scenes` (scene descriptions) and :mod:`._boards`
(calibration views) this is the physics behind ``source.synthetic``; other nodes and tests
import them to build scenes with exact ground truth. Every pixel's ray is cast
through the camera's distortion model (OpenCV's k1 k2 p1 p2 k3 model, inverted
exactly by Newton iterations) into a 3-D scene: a textured table (plane
``z = 0`` of the table frame), a matte ball, optional clutter objects, lit by a
point light with Lambertian shading and soft cast shadows. The ball's edge is
anti-aliased by supersampling the pixels near its silhouette (10 x 10 rays per
pixel), so that the centroid of its rendered pixels is accurate to about
0.01 px.

Public API (stable)
-------------------
``make_rig(**params) -> rig``
    Build the two cameras, their pose over the table and the light. ``rig`` is a
    dict; ``rig["truth"]`` is the plain-data ``RigTruth`` artifact (see
    ``docs/artifacts.md``). Parameters are those of :data:`RIG_DEFAULTS`.
``make_scene(rig, kind="plain", rng=None, **overrides) -> scene``
    Draw a random scene of a given kind (see :data:`SCENE_KINDS`).
``render_scene(rig, scene, seed=0, noise_sigma=None, coverage=False) -> (left, right, truth)``
    Render one stereo pair (uint8 BGR) and its ground truth (the
    ``StereoPair.truth`` dict; ``None`` when the scene has no ball).
``render_board_view(rig, pose_left_from_board, seed=0, noise_sigma=None) -> (left, right, corners)``
    Render a chessboard calibration view; ``corners`` holds the true corner
    pixels in both images.
``random_board_poses(rig, n, rng) -> list of 4x4``
    Board poses (left-camera frame, cm) fully visible in both cameras.
``silhouette(K, D, center_cam_cm, radius_cm) -> dict``
    The exact outline of a sphere: the ellipse cut by its tangent cone in the
    ideal (undistorted) image, and the area centroid / area of the true
    (distorted) silhouette, computed from a dense polygon of its boundary.
``project_points(K, D, pts_cam)`` / ``undistort_pixels(K, D, px)``
    The camera model and its exact inverse (pixels <-> normalised rays).

Scene description (plain data, JSON/YAML friendly)
--------------------------------------------------
::

    {"kind": "plain",                      # free label, copied into truth
     "ball": {"center_cm": [x, y],         # table frame; resting on the table
              "radius_cm": 2.0,            # (give [x, y, z] to float it)
              "color": "orange"},          # name (see COLORS) or [b, g, r] 0..255
     "objects": [                          # optional clutter, any number
        {"type": "box", "center_cm": [x, y], "size_cm": [sx, sy, sz],
         "yaw_deg": 20, "color": "blue"},
        {"type": "cylinder", "center_cm": [x, y], "radius_cm": 2, "height_cm": 8,
         "color": "green"},
        {"type": "ball", "center_cm": [x, y], "radius_cm": 2.5, "color": "red"}]}

``"ball": None`` renders a scene without the target (truth is then ``None``).

Hard scenes
-----------
Ask :func:`make_scene` for a ``kind`` among :data:`SCENE_KINDS`:
``"plain"`` (ball alone), ``"clutter"`` (boxes and cylinders of other colours
near the ball), ``"second_ball"`` (another ball of another colour),
``"border"`` (ball partly cut by the left or right image border),
``"occluded"`` (a box between the left camera and the ball hides part of it),
``"hidden"`` (the ball is entirely hidden in the left image), ``"empty"`` (no
ball), and issue 15's partial-view / touching kinds of :mod:`._hard_scenes` (``border_cut``,
``occluded_part``, ``touching_box``, ``touching_ball``, ``distractor``, ``same_color``).
``source.synthetic`` exposes them as ``hard_cases: [clutter, border]``
(``n_hard_each`` scenes per kind) and accepts explicit scene dicts in its
``scenes`` parameter. The truth of every pair carries ``kind``,
``visible_fraction_left`` / ``_right`` (visible share of the silhouette) and
``touches_border_left`` / ``_right``.

Frames: the table frame has its origin on the table where the left camera's
optical axis meets it, x to the right (along the baseline), y away from the
cameras, z up. ``T_table_from_left`` maps left-camera points (cm) into it.
"""

from __future__ import annotations

import math

import numpy as np

from nodes.sources._lens import project_points, undistort_pixels
from nodes.sources._materials import _table_texture
from nodes.sources._raycast import _objects_of, _to_uint8, _trace
from nodes.sources._rig import _ray_grid
from nodes.sources._scenes import _bbox_inside, _table_to_cam
from nodes.sources._silhouette import silhouette

_SUPERSAMPLE = 10  # rays per pixel side near a ball's silhouette (100 per pixel)


def _empty_table(rig: dict, i: int, tex: np.ndarray) -> np.ndarray:
    """The lit, empty table as seen by camera ``i`` (H, W, 3 float32); cached in the rig."""
    cache = rig.setdefault("_cache", {})
    key = ("table", i)
    if key not in cache:
        w, h = rig["truth"]["image_size"]
        img, _ = _trace(rig, i, _ray_grid(rig["cams"][i], (w, h)), [], tex)
        cache[key] = img.reshape(h, w, 3).astype(np.float32)
    return cache[key]


def _object_points(o: dict) -> np.ndarray:
    """Points whose convex hull bounds an object (table frame), for screen-space bounding boxes."""
    if o["type"] == "sphere":
        g = np.array([[x, y, z] for x in (-1, 0, 1) for y in (-1, 0, 1) for z in (-1, 0, 1)], float)
        return o["c"] + 1.8 * o["r"] * g / np.maximum(np.linalg.norm(g, axis=1, keepdims=True), 1)
    if o["type"] == "box":
        s = np.linspace(-1, 1, 7)
        g = np.array(
            [
                [x, y, z]
                for x in s
                for y in s
                for z in s
                if int(abs(x) == 1) + int(abs(y) == 1) + int(abs(z) == 1) >= 2
            ]
        )
        return o["c"] + (g * o["half"]) @ o["Rz"].T
    th = np.linspace(0, 2 * np.pi, 32, endpoint=False)
    ring = np.stack([np.cos(th), np.sin(th), np.zeros_like(th)], axis=1) * o["r"] * 1.05
    return np.concatenate([o["c"] + ring, o["c"] + ring + [0, 0, o["h"]]])


def _roi(rig: dict, i: int, objs: list[dict]) -> tuple[int, int, int, int] | None:
    """Pixel rectangle (u0, v0, u1, v1 inclusive) containing every object and its shadow."""
    w, h = rig["truth"]["image_size"]
    cam = rig["cams"][i]
    L = rig["light_table"]
    pts = []
    for o in objs:
        q = _object_points(o)
        pts.append(q)
        if np.any(q[:, 2] >= L[2] - 1e-6):
            return 0, 0, w - 1, h - 1
        # Shadow outline: the object's points projected from the lamp onto the table.
        s = L[2] / (L[2] - q[:, 2])
        sh = L + (q - L) * s[:, None]
        sh[:, 2] = 0.0
        pts.append(sh)
    if not pts:
        return None
    P = _table_to_cam(rig, i, np.concatenate(pts))
    if np.any(P[:, 2] <= 1e-3):
        return 0, 0, w - 1, h - 1
    px = project_points(cam["K"], cam["D"], P)
    m = 4  # px: bowing of straight edges under distortion, soft shadow edges
    u0, v0 = int(max(np.floor(px[:, 0].min()) - m, 0)), int(max(np.floor(px[:, 1].min()) - m, 0))
    u1, v1 = (
        int(min(np.ceil(px[:, 0].max()) + m, w - 1)),
        int(min(np.ceil(px[:, 1].max()) + m, h - 1)),
    )
    if u0 > u1 or v0 > v1:
        return None
    return u0, v0, u1, v1


def _render_camera(rig, i, objs, tex):
    """Radiance image (H, W, 3 float) of camera ``i`` and the target ball's coverage (or None)."""
    w, h = rig["truth"]["image_size"]
    cam = rig["cams"][i]
    rays = _ray_grid(cam, (w, h))
    img = _empty_table(rig, i, tex).astype(float)
    has_target = bool(objs) and bool(objs[0].get("target"))
    cov = np.zeros((h, w)) if has_target else None
    roi = _roi(rig, i, objs)
    if roi is None:
        return img, cov
    u0, v0, u1, v1 = roi
    # Only the rectangle holding the objects and their shadows differs from the empty table.
    sub = rays.reshape(h, w, 3)[v0 : v1 + 1, u0 : u1 + 1].reshape(-1, 3)
    rad, ids = _trace(rig, i, sub, objs, tex)
    img[v0 : v1 + 1, u0 : u1 + 1] = rad.reshape(v1 - v0 + 1, u1 - u0 + 1, 3)
    if has_target:
        cov[v0 : v1 + 1, u0 : u1 + 1] = (ids == 0).reshape(v1 - v0 + 1, u1 - u0 + 1)
    # Supersample the band of pixels around every sphere's silhouette (analytic cone test).
    S = _SUPERSAMPLE
    off = (np.arange(S) + 0.5) / S - 0.5
    ou, ov = np.meshgrid(off, off)
    ou, ov = ou.ravel(), ov.ravel()
    for o in objs:
        if o["type"] == "sphere":
            _supersample_sphere(rig, i, o, rays, objs, tex, img, cov, (ou, ov))
    return img, cov


def _supersample_sphere(rig, i, o, rays, objs, tex, img, cov, offsets) -> None:
    """Supersample, in ``img`` and ``cov``, the band of camera ``i``'s pixels around sphere
    ``o``'s silhouette (analytic cone test); ``offsets``: the sub-pixel grid (u, v)."""
    w, h = rig["truth"]["image_size"]
    cam = rig["cams"][i]
    S = _SUPERSAMPLE
    ou, ov = offsets
    fmin = min(cam["K"][0, 0], cam["K"][1, 1])
    cc = _table_to_cam(rig, i, o["c"])[0]
    dist = np.linalg.norm(cc)
    if dist <= o["r"] * 1.01 or cc[2] <= o["r"]:
        return
    half = math.asin(o["r"] / dist)
    sil = silhouette(cam["K"], cam["D"], cc, o["r"], n_boundary=256)
    su0, sv0, su1, sv1 = sil["bbox_px"]
    iu0, iv0 = max(int(math.floor(su0)) - 2, 0), max(int(math.floor(sv0)) - 2, 0)
    iu1, iv1 = min(int(math.ceil(su1)) + 2, w - 1), min(int(math.ceil(sv1)) + 2, h - 1)
    if iu0 > iu1 or iv0 > iv1:
        return
    box = rays.reshape(h, w, 3)[iv0 : iv1 + 1, iu0 : iu1 + 1].reshape(-1, 3)
    ang = np.arccos(np.clip(box @ (cc / dist) / np.linalg.norm(box, axis=1), -1, 1))
    # A pixel's half-diagonal spans ~0.71/f rad (a little more where distortion stretches
    # the image): pixels whose centre ray is farther than 1.1/f from the cone are pure.
    band = np.abs(ang - half) < 1.1 / fmin
    if not np.any(band):
        return
    vv, uu = np.nonzero(band.reshape(iv1 - iv0 + 1, iu1 - iu0 + 1))
    uu, vv = uu + iu0, vv + iv0
    pu = (uu[:, None] + ou[None, :]).ravel()
    pv = (vv[:, None] + ov[None, :]).ravel()
    # Start Newton from the pixel centre's exact ray: two steps then reach machine precision.
    guess = np.repeat(rays.reshape(h, w, 3)[vv, uu, :2], S * S, axis=0)
    guess[:, 0] += (pu - np.repeat(uu, S * S)) / cam["K"][0, 0]
    guess[:, 1] += (pv - np.repeat(vv, S * S)) / cam["K"][1, 1]
    xy = undistort_pixels(cam["K"], cam["D"], np.stack([pu, pv], axis=1), guess=guess, iterations=3)
    srays = np.concatenate([xy, np.ones((xy.shape[0], 1))], axis=1)
    sc, sid = _trace(rig, i, srays, objs, tex)
    img[vv, uu] = sc.reshape(-1, S * S, 3).mean(axis=1)
    if cov is not None:
        cov[vv, uu] = (sid == 0).reshape(-1, S * S).mean(axis=1)


def render_scene(
    rig: dict, scene: dict, seed: int = 0, noise_sigma: float | None = None, coverage: bool = False
) -> tuple[np.ndarray, np.ndarray, dict | None]:
    """Render a stereo pair of a scene with its ground truth.

    Parameters
    ----------
    rig : dict
        From :func:`make_rig`.
    scene : dict
        Scene description (module docstring).
    seed : int
        Seed of the image noise.
    noise_sigma : float, optional
        Gaussian noise, grey levels; default the rig's ``noise_sigma``.
    coverage : bool
        Also return the ball's per-pixel coverage (0..1 float, occlusions
        included) as ``truth["coverage_left"]`` / ``["coverage_right"]``.

    Returns
    -------
    left, right : uint8 HxWx3 BGR images
    truth : dict or None
        ``center_left_cm``, ``center_table_cm``, ``radius_cm``,
        ``center_px_left`` / ``_right`` (image of the centre, distorted
        pixels), ``silhouette_left`` / ``_right`` (see :func:`silhouette`),
        ``visible_fraction_left`` / ``_right``, ``touches_border_left`` /
        ``_right``, ``kind``, ``color``. ``None`` if the scene has no ball.
    """
    objs = _objects_of(scene)
    tex = _table_texture(int(rig["params"]["texture_seed"]))
    sigma = float(rig["params"]["noise_sigma"] if noise_sigma is None else noise_sigma)
    rng = np.random.default_rng(seed)
    imgs, covs = [], []
    for i in (0, 1):
        img, cov = _render_camera(rig, i, objs, tex)
        imgs.append(_to_uint8(img, sigma, rng))
        covs.append(cov)
    truth = None
    if objs and objs[0].get("target"):
        b = objs[0]
        T = rig["truth"]["T_table_from_left"]
        c_left = (b["c"] - T[:3, 3]) @ T[:3, :3]
        c_right = rig["truth"]["R"] @ c_left + rig["truth"]["T_cm"]
        sils = [
            silhouette(rig["cams"][0]["K"], rig["cams"][0]["D"], c_left, b["r"]),
            silhouette(rig["cams"][1]["K"], rig["cams"][1]["D"], c_right, b["r"]),
        ]
        truth = {
            "kind": scene.get("kind", "custom"),
            "center_left_cm": [float(v) for v in c_left],
            "center_table_cm": [float(v) for v in b["c"]],
            "radius_cm": float(b["r"]),
            "color": scene["ball"].get("color", "orange")
            if isinstance(scene["ball"].get("color", "orange"), str)
            else [int(v) for v in scene["ball"]["color"]],
            "center_px_left": sils[0]["center_px"],
            "center_px_right": sils[1]["center_px"],
            "silhouette_left": sils[0],
            "silhouette_right": sils[1],
        }
        for side, s, cov in (("left", sils[0], covs[0]), ("right", sils[1], covs[1])):
            truth[f"visible_fraction_{side}"] = float(min(cov.sum() / s["area_px"], 1.0))
            truth[f"touches_border_{side}"] = bool(not _bbox_inside(rig, s, 0.5))
            if coverage:
                truth[f"coverage_{side}"] = cov.astype(np.float32)
    return imgs[0], imgs[1], truth
