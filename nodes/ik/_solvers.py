"""Inverse kinematics of the arm model (``nodes/contracts/arm.py``): closed form and damped least
squares.

Each solver has a scalar form (one target -> one pose or an :class:`Unreachable` error naming why)
and a vectorised batch form (N targets -> N poses + a status code per target), both on the same
forward kinematics (:func:`nodes.contracts.arm.fk`).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from nodes.contracts.arm import JOINTS, fk, fk_jacobian, geometry, joint, limits_rad
from stereograph.api import NodeError

OK, TOO_FAR, TOO_CLOSE, LIMITS, NO_CONVERGENCE = 0, 1, 2, 3, 4
STATUS_WORDS = {
    OK: "ok",
    TOO_FAR: "beyond reach",
    TOO_CLOSE: "inside minimum reach",
    LIMITS: "outside joint limits",
    NO_CONVERGENCE: "no convergence",
}
_TWO_PI = 2.0 * math.pi
_LIMIT_EPS = 1e-9  # rad: a pose computed exactly on a limit must not be refused by round-off


class Unreachable(NodeError):
    """The target cannot be reached; the message says by how much or which joint limit."""


def _wrap(a):
    """Angle(s) wrapped into (-pi, pi]."""
    return (
        a - _TWO_PI * np.floor((a + math.pi) / _TWO_PI)
        if isinstance(a, np.ndarray)
        else a - _TWO_PI * math.floor((a + math.pi) / _TWO_PI)
    )


def _distance_error(model, p, d_shoulder, too_far: bool) -> Unreachable:
    h0, r0, l1, a, b, reach = geometry(model)
    l2 = math.hypot(a, b)
    p_txt = ", ".join(f"{v:.2f}" for v in p)
    if too_far:
        return Unreachable(
            f"unreachable: distance {d_shoulder:.2f} cm > reach {reach:.2f} cm "
            f"(target [{p_txt}] cm in the arm-base frame, distance measured from the "
            "shoulder axis)",
            hint="move the object closer to the arm, or check the hand-eye transform and the "
            "link lengths.",
        )
    return Unreachable(
        f"unreachable: distance {d_shoulder:.2f} cm < minimum reach {abs(l1 - l2):.2f} cm "
        f"(target [{p_txt}] cm is too close to the shoulder axis)",
        hint="move the object further from the arm base.",
    )


# =========================================================================== analytic
def _candidates(elbow: str, allow_back: bool) -> list[tuple[int, int]]:
    """(branch sign, elbow sign) pairs in order of preference; elbow sign -1 = up."""
    pref = {"up": [-1], "down": [1], "auto": [-1, 1]}[elbow]
    out = [(1, e) for e in pref]
    if allow_back:
        out += [(-1, e) for e in pref]
    return out


def configuration(model: dict[str, Any], p, q) -> tuple[int, int]:
    """The arm configuration of joint angles ``q`` (rad) reaching tool point ``p``: (branch, elbow)
    with branch +1 reaching forwards, -1 backwards over the base, elbow -1 up, +1 down (as
    :func:`_candidates`)."""
    x, y, _ = (float(v) for v in p)
    _, _, _, a, b, _ = geometry(model)
    branch = 1 if math.cos(float(q[0]) - math.atan2(y, x)) >= 0 or math.hypot(x, y) < 1e-9 else -1
    psi = _wrap(float(q[2]) + math.atan2(b, a))
    # (0: stretched, either)
    return branch, (0 if abs(psi) < 1e-6 else -1 if psi * branch < 0 else 1)


def analytic_ik(
    model: dict[str, Any],
    p,
    elbow: str = "auto",
    allow_back: bool = True,
    config: tuple[int, int] | None = None,
) -> np.ndarray:
    """Closed-form IK for one target.

    yaw = atan2(y, x) (or that + 180 deg when reaching backwards over the base), then the planar
    two-link problem in the arm's vertical plane by the law of cosines, with the tool offset folded
    into an effective forearm of length ``hypot(forearm + tool_along, tool_normal)``.

    Parameters
    ----------
    model : dict
        ArmModel.
    p : array_like, shape (3,)
        Target tool point (cm, arm-base frame).
    elbow : {"up", "down", "auto"}
        Elbow configuration; ``auto`` prefers elbow-up and falls back to elbow-down when elbow-up
        would leave the joint limits.
    allow_back : bool
        Also try reaching backwards over the base (yaw + 180 deg) when the front pose is not within
        the joint limits.
    config : (branch, elbow), optional
        Only this configuration (see :func:`configuration`): the points of one straight move must
        share one, or the arm swings between them.

    Returns
    -------
    ndarray, shape (3,)
        ``[yaw, shoulder, elbow]`` (rad), within the joint limits.

    Raises
    ------
    Unreachable
        ``"unreachable: distance X cm > reach Y cm"``, or the joint limit that every candidate
        pose violates.
    """
    x, y, z = (float(v) for v in p)
    h0, r0, l1, a, b, reach = geometry(model)
    l2 = math.hypot(a, b)
    delta = math.atan2(b, a)
    lo, hi = limits_rad(model)
    rho = math.hypot(x, y)
    yaw_front = math.atan2(y, x)
    violations = []
    for branch, esign in [config] if config is not None else _candidates(elbow, allow_back):
        r = rho * branch
        q0 = yaw_front if branch > 0 else _wrap(yaw_front + math.pi)
        dx, dz = r - r0, z - h0
        d2 = dx * dx + dz * dz
        D = (d2 - l1 * l1 - l2 * l2) / (2.0 * l1 * l2)
        if D > 1.0 + 1e-12 or D < -1.0 - 1e-12:
            if branch > 0:
                raise _distance_error(model, (x, y, z), math.sqrt(d2), D > 1.0)
            continue
        D = min(1.0, max(-1.0, D))
        # "up" keeps the elbow above the shoulder-target line: psi < 0 in front, > 0 behind.
        psi = esign * branch * math.atan2(math.sqrt((1.0 - D) * (1.0 + D)), D)
        q1 = _wrap(math.atan2(dz, dx) - math.atan2(l2 * math.sin(psi), l1 + l2 * math.cos(psi)))
        q2 = _wrap(psi - delta)
        q = (q0, q1, q2)
        bad = [i for i in range(3) if not (lo[i] - _LIMIT_EPS <= q[i] <= hi[i] + _LIMIT_EPS)]
        if not bad:
            return np.array(q)
        i = bad[0]
        violations.append(
            f"{JOINTS[i]} {math.degrees(q[i]):.1f} deg outside [{math.degrees(lo[i]):.1f}, "
            f"{math.degrees(hi[i]):.1f}] deg ({'back' if branch < 0 else 'front'}, "
            f"elbow {'up' if esign < 0 else 'down'})"
        )
    p_txt = ", ".join(f"{v:.2f}" for v in (x, y, z))
    raise Unreachable(
        f"unreachable within joint limits: target [{p_txt}] cm needs "
        + ("; or ".join(violations) or "a pose out of reach in this configuration"),
        hint="widen the joint limits in the arm model if the hardware allows it, set elbow: "
        "auto, or move "
        "the object.",
    )


def analytic_ik_batch(
    model: dict[str, Any], P, elbow: str = "auto", allow_back: bool = True
) -> tuple[np.ndarray, np.ndarray]:
    """Vectorised :func:`analytic_ik` for N targets.

    Parameters
    ----------
    P : array_like, shape (N, 3)
        Targets (cm, arm-base frame).

    Returns
    -------
    q : ndarray, shape (N, 3)
        Joint angles (rad); NaN where no pose exists.
    status : ndarray of int, shape (N,)
        ``OK`` (0), ``TOO_FAR`` (1), ``TOO_CLOSE`` (2) or ``LIMITS`` (3) per target.
    """
    P = np.asarray(P, dtype=float).reshape(-1, 3)
    h0, r0, l1, a, b, reach = geometry(model)
    l2 = math.hypot(a, b)
    delta = math.atan2(b, a)
    lo, hi = limits_rad(model)
    n = len(P)
    rho = np.hypot(P[:, 0], P[:, 1])
    yaw_front = np.arctan2(P[:, 1], P[:, 0])
    q = np.full((n, 3), np.nan)
    status = np.full(n, LIMITS, dtype=np.int64)
    done = np.zeros(n, dtype=bool)
    dz = P[:, 2] - h0
    for branch, esign in _candidates(elbow, allow_back):
        dx = branch * rho - r0
        D = (dx * dx + dz * dz - l1 * l1 - l2 * l2) / (2.0 * l1 * l2)
        if branch > 0:
            status[D > 1.0 + 1e-12] = TOO_FAR
            status[D < -1.0 - 1e-12] = TOO_CLOSE
            done |= (status == TOO_FAR) | (status == TOO_CLOSE)
        inside = np.abs(D) <= 1.0 + 1e-12
        Dc = np.clip(D, -1.0, 1.0)
        psi = esign * branch * np.arctan2(np.sqrt((1.0 - Dc) * (1.0 + Dc)), Dc)
        q0 = yaw_front if branch > 0 else _wrap(yaw_front + math.pi)
        q1 = _wrap(np.arctan2(dz, dx) - np.arctan2(l2 * np.sin(psi), l1 + l2 * np.cos(psi)))
        q2 = _wrap(psi - delta)
        cand = np.stack([q0, q1, q2], axis=1)
        within = np.all((cand >= lo - _LIMIT_EPS) & (cand <= hi + _LIMIT_EPS), axis=1)
        take = ~done & inside & within
        q[take] = cand[take]
        status[take] = OK
        done |= take
    return q, status


# =========================================================================== numeric
def _seeds(model: dict[str, Any], n_random: int, rng: np.random.Generator) -> np.ndarray:
    lo, hi = limits_rad(model)
    home = np.array([math.radians(joint(model, n).get("home_deg", 0.0)) for n in JOINTS])
    seeds = [np.clip(home, lo, hi), (lo + hi) / 2.0]
    seeds += list(rng.uniform(lo, hi, size=(n_random, 3)))
    return np.array(seeds)


def numeric_ik_batch(
    model: dict[str, Any],
    P,
    *,
    tol_cm: float = 1e-5,
    max_iter: int = 100,
    damping_cm: float = 1.0,
    n_random_seeds: int = 12,
    seed: int = 0,
    q_init=None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Damped-least-squares IK (Levenberg-Marquardt step control, joint limits by projection).

    Each iteration takes ``dq = J^T (J J^T + lambda^2 I)^-1 e`` with the chain's Jacobian, clips
    ``q`` into the joint limits, and keeps the step only if the position error drops (then
    ``lambda`` halves; otherwise it doubles). Targets that stall (a local minimum against a limit)
    are restarted from the next seed: ``q_init``, the four poses of a coarse joint-space grid whose
    tool points lie nearest the target, the home pose, the middle of the limits, then
    ``n_random_seeds`` seeded random poses. Only the forward kinematics and its Jacobian are used,
    so the method carries over to chains without a closed form.

    Parameters
    ----------
    P : array_like, shape (N, 3)
        Targets (cm, arm-base frame).
    tol_cm : float
        Convergence tolerance on the tool-point position (cm).
    max_iter : int
        Iterations per seed.
    damping_cm : float
        Initial damping ``lambda`` (cm; the Jacobian is in cm/rad).
    q_init : array_like, shape (N, 3) or (3,), optional
        First seed (rad), e.g. the previous waypoint's pose.

    Returns
    -------
    q : ndarray, shape (N, 3)
        Joint angles (rad), within limits; the best found where not converged.
    status : ndarray of int, shape (N,)
        ``OK``, ``TOO_FAR`` (beyond the chain's reach) or ``NO_CONVERGENCE``.
    err_cm : ndarray, shape (N,)
        Remaining position error (cm).
    """
    P = np.asarray(P, dtype=float).reshape(-1, 3)
    lo, hi = limits_rad(model)
    rng = np.random.default_rng(seed)
    seed_list = _seed_list(model, P, (lo, hi), n_random_seeds, rng, q_init)
    q_best = np.clip(seed_list[0], lo, hi)
    err_best = np.linalg.norm(fk(model, q_best) - P, axis=1)
    todo = err_best > tol_cm
    eye = np.eye(3)
    for k in range(len(seed_list)):
        idx = np.flatnonzero(todo)
        if idx.size == 0:
            break
        q = q_best[idx].copy() if k == 0 else np.clip(seed_list[k][idx], lo, hi)
        e = P[idx] - fk(model, q)
        en = np.linalg.norm(e, axis=1)
        lam = np.full(idx.size, float(damping_cm))
        for _ in range(max_iter):
            active = en > tol_cm
            if not active.any():
                break
            J = fk_jacobian(model, q)
            JJt = J @ np.swapaxes(J, 1, 2) + (lam**2)[:, None, None] * eye
            dq = np.einsum("nji,nj->ni", J, np.linalg.solve(JJt, e[:, :, None])[:, :, 0])
            q_new = np.clip(q + dq, lo, hi)
            e_new = P[idx] - fk(model, q_new)
            en_new = np.linalg.norm(e_new, axis=1)
            better = active & (en_new < en)
            q[better], e[better], en[better] = q_new[better], e_new[better], en_new[better]
            lam = np.where(better, np.maximum(lam * 0.5, 1e-6), np.minimum(lam * 2.0, 1e4))
        improve = en < err_best[idx]
        q_best[idx[improve]] = q[improve]
        err_best[idx[improve]] = en[improve]
        todo = err_best > tol_cm
    status = np.where(err_best <= tol_cm, OK, NO_CONVERGENCE)
    # Name the cause when it is geometric: beyond the chain's reach from the shoulder axis.
    h0, r0, l1, a, b, reach = geometry(model)
    d_sh = _shoulder_distance(model, P)
    status[(status != OK) & (d_sh > reach + tol_cm)] = TOO_FAR
    return q_best, status, err_best


def _seed_list(model: dict[str, Any], P: np.ndarray, limits, n_random_seeds: int, rng, q_init):
    """Starting poses, each ``(N, 3)`` rad: the caller's guess, then the poses of a coarse
    joint-space grid whose tool points lie nearest the target (only FK is needed, so this carries
    over to any chain), then home, the middle of the limits and seeded random poses."""
    lo, hi = limits
    n = len(P)
    from scipy.spatial import cKDTree

    grid = np.stack(
        np.meshgrid(
            *[np.linspace(lo[i], hi[i], g) for i, g in enumerate((24, 13, 13))], indexing="ij"
        ),
        axis=-1,
    ).reshape(-1, 3)
    n_near = 4
    near = cKDTree(fk(model, grid)).query(P, k=n_near)[1].reshape(n, n_near)
    per_target = [grid[near[:, k]] for k in range(n_near)]
    generic = _seeds(model, n_random_seeds, rng)
    if q_init is not None:
        per_target.insert(0, np.broadcast_to(np.asarray(q_init, float), (n, 3)).copy())
    seed_list = per_target + [np.tile(g, (n, 1)) for g in generic]
    return seed_list


def _shoulder_distance(model, P) -> np.ndarray:
    """Distance (cm) from the shoulder axis circle to each target, the quantity the reach bounds."""
    h0, r0, *_ = geometry(model)
    P = np.asarray(P, dtype=float).reshape(-1, 3)
    return np.hypot(np.hypot(P[:, 0], P[:, 1]) - r0, P[:, 2] - h0)


def numeric_ik(model: dict[str, Any], p, **kw) -> np.ndarray:
    """Scalar :func:`numeric_ik_batch`: one target -> ``[yaw, shoulder, elbow]`` (rad) or
    Unreachable."""
    q, status, err = numeric_ik_batch(model, np.asarray(p, float)[None, :], **kw)
    if status[0] == OK:
        return q[0]
    p_txt = ", ".join(f"{float(v):.2f}" for v in p)
    d = float(_shoulder_distance(model, p)[0])
    if status[0] == TOO_FAR:
        raise _distance_error(model, [float(v) for v in p], d, True)
    lo, hi = limits_rad(model)
    at_limit = [
        f"{JOINTS[i]} at {'min' if abs(q[0, i] - lo[i]) < 1e-6 else 'max'} "
        f"{math.degrees(q[0, i]):.1f} deg"
        for i in range(3)
        if abs(q[0, i] - lo[i]) < 1e-6 or abs(q[0, i] - hi[i]) < 1e-6
    ]
    why = f"; closest pose misses by {err[0]:.3f} cm" + (
        f" with {', '.join(at_limit)}" if at_limit else ""
    )
    raise Unreachable(
        f"unreachable within joint limits: target [{p_txt}] cm (distance {d:.2f} cm from "
        f"the shoulder axis){why}",
        hint="widen the joint limits in the arm model if the hardware allows it, or move the "
        "object.",
    )
