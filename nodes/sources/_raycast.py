"""Ray casting of the synthetic scenes: ray/object intersections (sphere, box, cylinder), soft
cast shadows, Lambertian shading and the noisy 8-bit image.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from nodes.sources._materials import _sample_texture, color_bgr


def _objects_of(scene: dict) -> list[dict]:
    """Normalise the scene into a list of primitives; the target ball (if any) first."""
    objs = []
    ball = scene.get("ball")
    if ball is not None:
        albedo = color_bgr(ball.get("color", "orange"))
        objs.append(_sphere(ball, albedo, target=True))
    for o in scene.get("objects", []) or []:
        t = o.get("type", "box")
        col = color_bgr(o.get("color", "grey"))
        if t in ("ball", "sphere"):
            objs.append(_sphere(o, col, target=False))
        elif t == "box":
            objs.append(_box(o, col))
        elif t == "cylinder":
            objs.append(
                {
                    "type": "cylinder",
                    "c": np.array([o["center_cm"][0], o["center_cm"][1], 0.0], float),
                    "r": float(o["radius_cm"]),
                    "h": float(o["height_cm"]),
                    "albedo": col,
                }
            )
        else:
            raise ValueError(f"unknown object type {t!r}; use box, cylinder or ball")
    return objs


def _sphere(o: dict, albedo, target: bool) -> dict:
    """A ball of the scene as a sphere primitive: a centre given on the table (x, y) sits on it."""
    r = float(o.get("radius_cm", 2.0))
    c = list(o["center_cm"])
    if len(c) == 2:
        c = [c[0], c[1], r]
    return {"type": "sphere", "c": np.asarray(c, float), "r": r, "albedo": albedo, "target": target}


def _box(o: dict, albedo) -> dict:
    """A box of the scene, standing on the table, turned by its yaw, as a primitive."""
    sx, sy, sz = (float(v) for v in o["size_cm"])
    yaw = math.radians(float(o.get("yaw_deg", 0.0)))
    Rz = np.array(
        [[math.cos(yaw), -math.sin(yaw), 0], [math.sin(yaw), math.cos(yaw), 0], [0, 0, 1.0]]
    )
    c = np.array([o["center_cm"][0], o["center_cm"][1], sz / 2.0], float)
    return {"type": "box", "c": c, "half": np.array([sx, sy, sz]) / 2.0, "Rz": Rz, "albedo": albedo}


def _hit_sphere(O, D, c, r):
    """Nearest positive ray parameter (inf if missed) for rays O + t D, D not normalised."""
    oc = O - c  # O is a single point (3,)
    a = np.einsum("ij,ij->i", D, D)
    b = D @ oc
    cc = oc @ oc - r * r
    disc = b * b - a * cc
    t = np.full(D.shape[0], np.inf)
    ok = disc >= 0
    if np.any(ok):
        sq = np.sqrt(disc[ok])
        t0 = (-b[ok] - sq) / a[ok]
        t1 = (-b[ok] + sq) / a[ok]
        tt = np.where(t0 > 1e-9, t0, np.where(t1 > 1e-9, t1, np.inf))
        t[ok] = tt
    return t


def _hit_box(O, D, obj, tmin=1e-9):
    """Slab test in the box's frame; O may be (3,) or (N, 3). Returns t (N,) and the hit axis
    (N,)."""
    Rz, c, half = obj["Rz"], obj["c"], obj["half"]
    o = (np.atleast_2d(O) - c) @ Rz  # rotate into the box frame (R^T x == x @ R)
    d = D @ Rz
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / d
        t1 = (-half - o) * inv
        t2 = (half - o) * inv
    tn = np.minimum(t1, t2)
    tf = np.maximum(t1, t2)
    tnear = np.nanmax(tn, axis=1)
    tfar = np.nanmin(tf, axis=1)
    axis = np.nanargmax(tn, axis=1)
    hit = (tnear <= tfar) & (tfar > tmin)
    t = np.where(hit, np.where(tnear > tmin, tnear, tfar), np.inf)
    return t, axis


def _hit_cylinder(O, D, obj, tmin=1e-9):
    """Vertical capped cylinder standing on the table; O (3,) or (N, 3). Returns t and a 'side'
    flag."""
    O2 = np.atleast_2d(O)
    ox, oy, oz = O2[:, 0] - obj["c"][0], O2[:, 1] - obj["c"][1], O2[:, 2]
    dx, dy, dz = D[:, 0], D[:, 1], D[:, 2]
    a = dx * dx + dy * dy
    b = ox * dx + oy * dy
    cc = ox * ox + oy * oy - obj["r"] ** 2
    disc = b * b - a * cc
    t = np.full(D.shape[0], np.inf)
    with np.errstate(invalid="ignore", divide="ignore"):
        sq = np.sqrt(np.maximum(disc, 0))
        ts = (-b - sq) / a
        z = oz + ts * dz
        side = (disc >= 0) & (ts > tmin) & (z >= 0) & (z <= obj["h"])
        t = np.where(side, ts, t)
        tc = (obj["h"] - oz) / dz
        xc, yc = ox + tc * dx, oy + tc * dy
        cap = (tc > tmin) & (xc * xc + yc * yc <= obj["r"] ** 2) & (tc < t)
        t = np.where(cap, tc, t)
    return t, ~cap


def _occlusion(P: np.ndarray, L: np.ndarray, objs: list[dict], own: np.ndarray) -> np.ndarray:
    """Fraction (0..1) of the light blocked for surface points P (N, 3)."""
    occ = np.zeros(P.shape[0])
    if not objs:
        return occ
    S = L[None, :] - P  # segment to the light, t in (0, 1)
    for k, o in enumerate(objs):
        mask = own != k
        if o["type"] == "sphere":
            # Closest approach of the segment to the centre; a penumbra of 10 % of the radius
            # (the light has a size) instead of a hard edge.
            cp = o["c"][None, :] - P
            ss = np.einsum("ij,ij->i", S, S)
            tt = np.einsum("ij,ij->i", cp, S) / ss
            dist2 = np.einsum("ij,ij->i", cp, cp) - tt * tt * ss
            dist = np.sqrt(np.maximum(dist2, 0))
            soft = np.clip((o["r"] * 1.1 - dist) / (o["r"] * 0.2), 0, 1)
            val = np.where((tt > 0) & (tt < 1) & mask, soft, 0.0)
        elif o["type"] == "box":
            t, _ = _hit_box(P, S, o, tmin=1e-6)
            val = ((t < 1) & mask).astype(float)
        else:
            t, _ = _hit_cylinder(P, S, o, tmin=1e-6)
            val = ((t < 1) & mask).astype(float)
        occ = np.maximum(occ, val)
    return occ


def _trace(rig: dict, cam_index: int, rays_cam: np.ndarray, objs: list[dict], tex: np.ndarray):
    """Shade rays given in camera coordinates. Returns BGR radiance (N, 3) in 0..1 and the hit id.

    Hit ids: -2 background (no table), -1 table, k >= 0 index into ``objs``.
    """
    cam = rig["cams"][cam_index]
    p = rig["params"]
    O = cam["origin_table"]
    D = rays_cam @ cam["R_table_from_cam"].T
    n = D.shape[0]
    t_best = np.full(n, np.inf)
    ids = np.full(n, -2, dtype=np.int64)
    with np.errstate(divide="ignore", invalid="ignore"):
        t_tab = np.where(D[:, 2] < 0, -O[2] / D[:, 2], np.inf)
    sel = t_tab < t_best
    t_best[sel], ids[sel] = t_tab[sel], -1
    aux = {}
    for k, o in enumerate(objs):
        if o["type"] == "sphere":
            t = _hit_sphere(O, D, o["c"], o["r"])
        elif o["type"] == "box":
            t, aux[k] = _hit_box(O, D, o)
        else:
            t, aux[k] = _hit_cylinder(O, D, o)
        sel = t < t_best
        t_best[sel], ids[sel] = t[sel], k
    hit = ids > -2
    P = O[None, :] + np.where(hit, t_best, 0.0)[:, None] * D
    normal = np.zeros_like(P)
    albedo = np.zeros_like(P)
    normal[:, 2] = 1.0
    tabm = ids == -1
    if np.any(tabm):
        albedo[tabm] = _sample_texture(tex, P[tabm, 0], P[tabm, 1])
    for k, o in enumerate(objs):
        m = ids == k
        if np.any(m):
            albedo[m] = o["albedo"]
            normal[m] = _normals(o, P[m], aux.get(k, None), m)
    L = rig["light_table"]
    to_l = L[None, :] - P
    dist = np.linalg.norm(to_l, axis=1, keepdims=True)
    lam = np.clip(np.einsum("ij,ij->i", normal, to_l / dist), 0, None)
    shadow = 1.0 - float(p["shadow_strength"]) * _occlusion(P[hit], L, objs, ids[hit])
    lam[hit] *= shadow
    amb = float(p["ambient"])
    # Light falls off gently with distance from the lamp so the table is not flat-shaded.
    fall = (np.linalg.norm(L - np.array([0, 0, 0.0])) / dist[:, 0]) ** 0.5
    radiance = albedo * (amb + (1.0 - amb) * lam * fall)[:, None]
    radiance[~hit] = 0.55  # grey wall beyond the table
    return radiance, ids


def _normals(o: dict, P: np.ndarray, aux: np.ndarray | None, m: np.ndarray) -> np.ndarray:
    """Surface normals of object ``o`` at its hit points ``P`` (table frame); ``aux``: the
    face (box) or side (cylinder) each ray of the trace hit, ``m`` selecting this object's."""
    if o["type"] == "sphere":
        return (P - o["c"]) / o["r"]
    if o["type"] == "box":
        local = (P - o["c"]) @ o["Rz"]
        ax = aux[m]
        nl = np.zeros_like(local)
        nl[np.arange(nl.shape[0]), ax] = np.sign(local[np.arange(nl.shape[0]), ax])
        return nl @ o["Rz"].T
    side = aux[m]
    rad = P - o["c"]
    rad[:, 2] = 0
    nn = rad / np.maximum(np.linalg.norm(rad, axis=1, keepdims=True), 1e-12)
    nn[~side] = [0.0, 0.0, 1.0]
    return nn


def _to_uint8(img: np.ndarray, noise_sigma: float, rng: np.random.Generator) -> np.ndarray:
    """Radiance (0..1) to 8-bit with Gaussian sensor noise, rounded and saturated.

    OpenCV's generator and saturating add are ~5x faster than NumPy's here (the noise was
    a third of a pair's render time); its global generator is seeded from ``rng``, so
    images stay a deterministic function of the seed.
    """
    img = cv2.multiply(img.astype(np.float32), 255.0)
    if noise_sigma > 0:
        noise = np.empty_like(img)
        cv2.setRNGSeed(int(rng.integers(0, 2**31 - 1)))
        cv2.randn(noise, 0.0, float(noise_sigma))
        return cv2.add(img, noise, dtype=cv2.CV_8U)
    return cv2.add(img, 0.0, dtype=cv2.CV_8U)
