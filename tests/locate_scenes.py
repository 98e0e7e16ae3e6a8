"""Tiny exact renderer of a ball in front of an ideal rectified stereo pair (test helper).

Independent of the project's synthetic rig on purpose: pinhole cameras with no distortion, so
the true centre, the true centre images and the true disparity are known in closed form, and
the sphere is supersampled (anti-aliased outline) like a real camera's pixel integration.
"""

from __future__ import annotations

import numpy as np


def rect_calibration(f=700.0, cx=319.5, cy=239.5, baseline_cm=10.0, size=(640, 480), R1=None):
    """A Rectification dict of an ideal rectified pair (right camera at +B along x)."""
    K = np.array([[f, 0, cx], [0, f, cy], [0, 0, 1.0]])
    P1 = np.hstack([K, np.zeros((3, 1))])
    P2 = np.hstack([K, np.array([[-f * baseline_cm], [0], [0]])])
    Q = np.array([[1, 0, 0, -cx], [0, 1, 0, -cy], [0, 0, 0, f], [0, 0, 1.0 / baseline_cm, 0]])
    return {
        "R1": np.eye(3) if R1 is None else np.asarray(R1, float),
        "R2": np.eye(3),
        "P1": P1,
        "P2": P2,
        "Q": Q,
        "f_px": f,
        "cx_px": cx,
        "cy_px": cy,
        "baseline_cm": baseline_cm,
        "image_size": list(size),
        "K1": K,
        "D1": np.zeros(5),
        "dy_mean_px": 0.0,
        "dy_max_px": 0.0,
    }


def _shade(dirs, origin, spheres, light, table_y, table_bgr, wall_bgr, shadow_factor):
    """Colour of rays (N,3 unit directions) from origin (3,)."""
    n = len(dirs)
    col = np.empty((n, 3))
    # Background: table plane y = table_y below the horizon, wall above.
    t_plane = np.where(
        dirs[:, 1] > 1e-6, (table_y - origin[1]) / np.maximum(dirs[:, 1], 1e-6), np.inf
    )
    on_table = np.isfinite(t_plane) & (t_plane < 400)
    col[:] = wall_bgr
    P = origin + dirs * np.where(on_table, t_plane, 0)[:, None]
    # Checker-free mild texture so that edges of the table are not an issue.
    tex = 1.0 + 0.04 * np.sin(P[:, 0] * 0.7) * np.cos(P[:, 2] * 0.5)
    col[on_table] = np.asarray(table_bgr, float) * tex[on_table, None]
    depth = np.where(on_table, t_plane, np.inf)
    # Shadows of spheres on the table (light direction `light` points towards the light).
    for s in spheres:
        C, r = np.asarray(s["center"], float), s["radius"]
        w = C - P
        proj = w @ light
        dist2 = (w * w).sum(1) - proj**2
        sh = on_table & (proj > 0) & (dist2 < r * r)
        col[sh] *= shadow_factor
    # Spheres (nearest hit).
    for s in spheres:
        C, r = np.asarray(s["center"], float), s["radius"]
        oc = C - origin
        b = dirs @ oc
        disc = b * b - (oc @ oc - r * r)
        hit = disc > 0
        t = b - np.sqrt(np.maximum(disc, 0))
        hit &= (t > 0) & (t < depth)
        if hit.any():
            X = origin + dirs[hit] * t[hit, None]
            nrm = (X - C) / r
            lam = np.clip(nrm @ light, 0, 1)
            col[hit] = np.asarray(s["bgr"], float) * (0.45 + 0.55 * lam)[:, None]
            depth = np.where(hit, t, depth)
    return col


def render_view(
    calib,
    origin,
    spheres,
    light=(-0.3, -1.0, -0.4),
    table_y=None,
    table_bgr=(150, 160, 165),
    wall_bgr=(200, 205, 210),
    shadow_factor=1.0,
    ss=4,
    noise=1.0,
    rng=None,
):
    """Render one rectified view (uint8 BGR) of the spheres seen from ``origin`` (rectified-left
    frame)."""
    w, h = calib["image_size"]
    f, cx, cy = calib["f_px"], calib["cx_px"], calib["cy_px"]
    light = np.asarray(light, float)
    light /= np.linalg.norm(light)
    if table_y is None:
        table_y = max(s["center"][1] + s["radius"] for s in spheres)
    args = (spheres, light, table_y, table_bgr, wall_bgr, shadow_factor)
    uu, vv = np.meshgrid(np.arange(w, dtype=float), np.arange(h, dtype=float))
    d = np.stack([(uu - cx) / f, (vv - cy) / f, np.ones_like(uu)], -1).reshape(-1, 3)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    img = _shade(d, np.asarray(origin, float), *args).reshape(h, w, 3)
    # Supersample pixels near sphere outlines (and shadows) for anti-aliasing.
    for s in spheres:
        C = np.asarray(s["center"], float) - origin
        if C[2] <= s["radius"]:
            continue
        u, v = f * C[0] / C[2] + cx, f * C[1] / C[2] + cy
        rp = 1.6 * f * s["radius"] / C[2] + 3
        u0, u1 = int(max(0, u - rp)), int(min(w, u + rp + 1))
        v0, v1 = int(max(0, v - rp)), int(min(h, v + 2.5 * rp + 1))
        if u1 <= u0 or v1 <= v0:
            continue
        offs = (np.arange(ss) + 0.5) / ss - 0.5
        acc = np.zeros((v1 - v0, u1 - u0, 3))
        for oy in offs:
            for ox in offs:
                uu2, vv2 = np.meshgrid(np.arange(u0, u1) + ox, np.arange(v0, v1) + oy)
                d2 = np.stack([(uu2 - cx) / f, (vv2 - cy) / f, np.ones_like(uu2)], -1).reshape(
                    -1, 3
                )
                d2 /= np.linalg.norm(d2, axis=1, keepdims=True)
                acc += _shade(d2, np.asarray(origin, float), *args).reshape(v1 - v0, u1 - u0, 3)
        img[v0:v1, u0:u1] = acc / (ss * ss)
    if noise:
        rng = rng or np.random.default_rng(0)
        img = img + rng.normal(0, noise, img.shape)
    return np.clip(np.round(img), 0, 255).astype(np.uint8)


def make_pair(
    calib,
    center_rect_cm,
    radius_cm=2.0,
    bgr=(40, 60, 200),
    extra=(),
    pid="p0",
    shadow_factor=1.0,
    seed=0,
    split="test",
):
    """A RectifiedPair dict of one ball (plus ``extra`` spheres) with its truth.

    ``center_rect_cm`` is in the rectified-left frame; truth is reported in the physical left
    frame (R1^T applied), as the contract wants.
    """
    spheres = [{"center": list(center_rect_cm), "radius": radius_cm, "bgr": bgr}, *extra]
    rng = np.random.default_rng(seed)
    B = calib["baseline_cm"]
    L = render_view(calib, (0.0, 0, 0), spheres, shadow_factor=shadow_factor, rng=rng)
    R = render_view(calib, (B, 0, 0), spheres, shadow_factor=shadow_factor, rng=rng)
    c = np.asarray(center_rect_cm, float)
    truth = {
        "center_left_cm": (np.asarray(calib["R1"]).T @ c).tolist(),
        "center_table_cm": None,
        "radius_cm": radius_cm,
        "center_rect_cm": c.tolist(),
    }
    return {"id": pid, "left": L, "right": R, "truth": truth, "split": split}
