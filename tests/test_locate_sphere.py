"""Sphere geometry of the sphere-aware disparity (nodes/disparity/_common.py)."""

import math

import cv2
import numpy as np
import pytest

from nodes.contracts.sphere import ellipse_to_conic, sphere_from_silhouette

K = np.array([[700.0, 0, 320.0], [0, 700.0, 240.0], [0, 0, 1]])


def silhouette_points(C, r, n=720):
    """Image points of the sphere's outline (tangent cone boundary), exact."""
    C = np.asarray(C, float)
    d = np.linalg.norm(C)
    a = C / d
    alpha = math.asin(r / d)
    e1 = np.cross(a, [0, 1.0, 0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(a, e1)
    t = np.linspace(0, 2 * np.pi, n, endpoint=False)
    rays = math.cos(alpha) * a[None] + math.sin(alpha) * (
        np.cos(t)[:, None] * e1 + np.sin(t)[:, None] * e2
    )
    p = (K @ rays.T).T
    return (p[:, :2] / p[:, 2:]).astype(np.float32)


@pytest.mark.parametrize("C", [(0, 0, 40.0), (12, -8, 35.0), (-15, 10, 30.0), (20, 14, 60.0)])
def test_centre_image_from_silhouette_is_exact(C):
    r = 2.0
    pts = silhouette_points(C, r)
    (cu, cv_), (w, h), ang = cv2.fitEllipse(pts)
    a, b = max(w, h) / 2, min(w, h) / 2
    if h > w:
        ang += 90.0
    E = ellipse_to_conic((cu, cv_), (a, b), ang)
    # Every outline point lies on the conic.
    hom = np.hstack([pts, np.ones((len(pts), 1))])
    assert np.abs(np.einsum("ij,jk,ik->i", hom, E, hom)).max() < 1e-3
    res = sphere_from_silhouette(E, K)
    true = K @ np.asarray(C)
    true = true[:2] / true[2]
    assert np.allclose(res["center_px"], true, atol=2e-3)
    # Distance from the known radius.
    assert r / math.sin(res["half_angle_rad"]) == pytest.approx(np.linalg.norm(C), rel=1e-4)
    assert res["anisotropy"] < 1e-3
    # The ellipse centre is NOT the centre image off axis (the bias the estimator removes).
    if np.hypot(C[0], C[1]) > 5:
        assert np.hypot(cu - true[0], cv_ - true[1]) > 0.1


def test_non_sphere_conic_is_flagged():
    E = ellipse_to_conic((320, 240), (40, 15), 0.0)  # far too elongated for a centred sphere
    assert sphere_from_silhouette(E, K)["anisotropy"] > 0.5


def test_centroid_disparity_refuses_a_ball_too_large_and_near_for_its_silhouette_centroid():
    """(a 5 cm ball at ~31 cm: every pair found 0.76-0.80 cm too near, sigma_z 0.004 cm; the bias is
    Z tan^2(alpha), read from the silhouette's size) -- refused with the estimator that has no
    bias."""
    from nodes.disparity.centroid import CentroidParams, centroid

    f_px, baseline_cm = 560.0, 8.0
    rect = {"f_px": f_px, "baseline_cm": baseline_cm}

    def seg(radius_cm, z_cm):
        r_px = f_px * radius_cm / z_cm
        d = f_px * baseline_cm / z_cm

        def region(u):
            return {
                "area_px": math.pi * r_px**2,
                "centroid_px": [u, 240.0],
                "sigma_centroid_px": 0.02,
            }

        return {
            "id": "p",
            "found": True,
            "left": region(320.0 + d / 2),
            "right": region(320.0 - d / 2),
        }

    big = centroid(CentroidParams(), seg(5.0, 31.5), rect)["disparity"]
    assert not big["found"] and "disparity.ellipse" in big["reason"], big["reason"]
    assert "~0.79 cm too near" in big["reason"], big["reason"]
    # the shipped rig's nearest ball
    usual = centroid(CentroidParams(), seg(2.0, 30.0), rect)["disparity"]
    assert usual["found"] and 0.1 < usual["sphere_bias_cm"] < 0.2
    lenient = centroid(CentroidParams(max_sphere_bias_cm=1.0), seg(5.0, 31.5), rect)["disparity"]
    assert lenient["found"]


def test_a_working_range_set_on_the_segmenter_holds_down_the_chain():
    """(`--set segment.working_range_cm=[80,220]` alone: the disparity and locate nodes kept their
    own 20-80 cm and refused every far ball, 2/20 found; now they take the upstream record's unless
    set)"""
    from nodes.disparity.centroid import CentroidParams, centroid
    from nodes.locators.triangulate import TriangulateParams, triangulate

    f_px, baseline_cm, z_cm = 560.0, 8.0, 150.0
    rect = {
        "f_px": f_px,
        "baseline_cm": baseline_cm,
        "P1": [[f_px, 0, 320, 0], [0, f_px, 240, 0], [0, 0, 1, 0]],
        "P2": [[f_px, 0, 320, -f_px * baseline_cm], [0, f_px, 240, 0], [0, 0, 1, 0]],
        "Q": [[1, 0, 0, -320], [0, 1, 0, -240], [0, 0, 0, f_px], [0, 0, 1 / baseline_cm, 0]],
        "R1": np.eye(3).tolist(),
        "image_size": [640, 480],
    }
    d = f_px * baseline_cm / z_cm

    def region(u):
        return {"area_px": math.pi * 7.5**2, "centroid_px": [u, 240.0], "sigma_centroid_px": 0.02}

    seg = {
        "id": "p",
        "found": True,
        "left": region(320.0 + d),
        "right": region(320.0),
        "working_range_cm": [80.0, 220.0],
    }
    disp = centroid(CentroidParams(), seg, rect)["disparity"]
    assert disp["found"] and disp["working_range_cm"] == [80.0, 220.0], disp.get("reason")
    loc = triangulate(TriangulateParams(), disp, rect)["location"]
    assert loc["found"] and abs(loc["z_cm"] - z_cm) < 1.0, loc.get("reason")
    # set on the node: it wins
    own = centroid(CentroidParams(working_range_cm=(20, 80)), seg, rect)["disparity"]
    assert not own["found"] and "working range [20.0, 80.0]" in own["reason"]
