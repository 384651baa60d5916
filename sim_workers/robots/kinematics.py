"""Kinematics of a six-joint arm of the Universal Robots geometry, from its standard
Denavit-Hartenberg parameters: forward kinematics, and the closed-form inverse with all of
its (up to) eight branches.

The UR geometry (shoulder and elbow axes parallel, a spherical-free wrist whose three axes
are offset by d4, d5 and d6) has a closed-form inverse: Hawkins, "Analytic inverse
kinematics for the Universal Robots UR-5/UR-10 arms" (2013), the derivation Universal
Robots' own documentation points to. Each branch is a choice of shoulder (left or right),
wrist (up or down) and elbow (up or down): theta1, then theta5, theta6, then the planar
two-link problem for theta2 and theta3, and theta4 from what is left.

Frames: link i's frame is ``T_i = Rz(theta_i) Tz(d_i) Tx(a_i) Rx(alpha_i)`` after link i-1's;
the pose returned by ``forward`` is the flange's in the arm's base frame (4 x 4, metres).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["DH", "Unreachable", "forward", "inverse", "nearest", "rigid_inverse"]

TWO_PI = 2.0 * math.pi


class Unreachable(ValueError):
    """A pose no branch of the inverse reaches, with the reason (`why`)."""

    def __init__(self, why: str) -> None:
        super().__init__(f"unreachable pose: {why}")
        self.why = why


@dataclass(frozen=True)
class DH:
    """Standard Denavit-Hartenberg parameters of a UR-type arm (metres, radians): d1, a2, a3,
    d4, d5, d6; the twists are the geometry's (pi/2, 0, 0, pi/2, -pi/2, 0)."""

    d1: float
    a2: float
    a3: float
    d4: float
    d5: float
    d6: float

    @property
    def d(self) -> np.ndarray:
        return np.array([self.d1, 0.0, 0.0, self.d4, self.d5, self.d6])

    @property
    def a(self) -> np.ndarray:
        return np.array([0.0, self.a2, self.a3, 0.0, 0.0, 0.0])

    @property
    def alpha(self) -> np.ndarray:
        return np.array([math.pi / 2, 0.0, 0.0, math.pi / 2, -math.pi / 2, 0.0])


def _link(theta: float, d: float, a: float, alpha: float) -> np.ndarray:
    ct, st, ca, sa = math.cos(theta), math.sin(theta), math.cos(alpha), math.sin(alpha)
    return np.array([[ct, -st * ca, st * sa, a * ct],
                     [st, ct * ca, -ct * sa, a * st],
                     [0.0, sa, ca, d],
                     [0.0, 0.0, 0.0, 1.0]])


def rigid_inverse(t: np.ndarray) -> np.ndarray:
    """The inverse of a rigid transform (4 x 4): the rotation transposed."""
    out = np.eye(4)
    out[:3, :3] = t[:3, :3].T
    out[:3, 3] = -t[:3, :3].T @ t[:3, 3]
    return out


def frames(dh: DH, q: np.ndarray) -> list[np.ndarray]:
    """The base-frame pose of every link frame 1..6 at joint angles `q` (6,)."""
    out, t = [], np.eye(4)
    for theta, d, a, alpha in zip(np.asarray(q, dtype=np.float64), dh.d, dh.a, dh.alpha):
        t = t @ _link(theta, d, a, alpha)
        out.append(t)
    return out


def forward(dh: DH, q: np.ndarray) -> np.ndarray:
    """The flange's pose (4 x 4) in the base frame at joint angles `q` (6,).

    >>> ur5e = DH(0.1625, -0.425, -0.3922, 0.1333, 0.0997, 0.0996)
    >>> np.round(forward(ur5e, np.zeros(6))[:3, 3], 4).tolist()      # stretched out along -x
    [-0.8172, -0.2329, 0.0628]
    """
    return frames(dh, q)[-1]


def _wrap(x: float) -> float:
    """An angle in [-pi, pi)."""
    return (x + math.pi) % TWO_PI - math.pi


def inverse(dh: DH, pose: np.ndarray, wrist_hint: float = 0.0, eps: float = 1e-9) -> np.ndarray:
    """Every branch of the inverse: (k, 6) joint angles in [-pi, pi) whose flange pose is
    `pose` (4 x 4), k <= 8. Raises ``Unreachable`` when no branch exists: the wrist centre
    inside the shoulder's cylinder of radius d4, or the elbow unable to span the distance.
    At a wrist singularity (theta5 = 0 or pi, the first and last wrist axes aligned) theta6
    is free: `wrist_hint` is taken for it.
    """
    t = np.asarray(pose, dtype=np.float64)
    d1, a2, a3, d4, d6 = dh.d1, dh.a2, dh.a3, dh.d4, dh.d6
    p05 = t @ np.array([0.0, 0.0, -d6, 1.0])
    r = math.hypot(p05[0], p05[1])
    if r < abs(d4) - eps:
        raise Unreachable(f"the wrist centre is {r:.4f} m from the base axis, inside the shoulder offset "
                          f"d4 = {abs(d4):.4f} m")
    psi = math.atan2(p05[1], p05[0])
    phi = math.acos(max(-1.0, min(1.0, d4 / max(r, eps))))
    sols = []
    t60 = rigid_inverse(t)
    for s1 in (1.0, -1.0):
        th1 = psi + s1 * phi + math.pi / 2
        c1, sn1 = math.cos(th1), math.sin(th1)
        c5 = (t[0, 3] * sn1 - t[1, 3] * c1 - d4) / d6
        if abs(c5) > 1.0 + 1e-7:
            continue
        for s5 in (1.0, -1.0):
            th5 = s5 * math.acos(max(-1.0, min(1.0, c5)))
            s5v = math.sin(th5)
            if abs(s5v) < 1e-9:
                th6 = wrist_hint
            else:
                th6 = math.atan2((-t60[1, 0] * sn1 + t60[1, 1] * c1) / s5v,
                                 (t60[0, 0] * sn1 - t60[0, 1] * c1) / s5v)
            t01 = _link(th1, d1, 0.0, math.pi / 2)
            t45 = _link(th5, dh.d5, 0.0, -math.pi / 2)
            t56 = _link(th6, d6, 0.0, 0.0)
            t14 = rigid_inverse(t01) @ t @ rigid_inverse(t56) @ rigid_inverse(t45)
            p13 = t14 @ np.array([0.0, -d4, 0.0, 1.0])
            n = math.hypot(p13[0], p13[1])
            c3 = (n * n - a2 * a2 - a3 * a3) / (2.0 * a2 * a3)
            if abs(c3) > 1.0 + 1e-7:
                continue
            for s3 in (1.0, -1.0):
                th3 = s3 * math.acos(max(-1.0, min(1.0, c3)))
                th2 = -math.atan2(p13[1], -p13[0]) + math.asin(max(-1.0, min(1.0, a3 * math.sin(th3) / n)))
                t12 = _link(th2, 0.0, a2, 0.0)
                t23 = _link(th3, 0.0, a3, 0.0)
                t34 = rigid_inverse(t23) @ rigid_inverse(t12) @ t14
                th4 = math.atan2(t34[1, 0], t34[0, 0])
                sols.append([_wrap(x) for x in (th1, th2, th3, th4, th5, th6)])
    if not sols:
        raise Unreachable("the elbow cannot span the distance from the shoulder to the wrist "
                          f"(|a2| + |a3| = {abs(a2) + abs(a3):.4f} m)")
    return np.array(sols)


def nearest(branches: np.ndarray, current: np.ndarray, low: np.ndarray, high: np.ndarray) -> np.ndarray:
    """The branch, each angle shifted by whole turns to lie nearest `current` within
    [`low`, `high`], that moves the joints least (largest single joint move first, then the
    sum). Raises ``Unreachable`` when no branch fits the limits."""
    current = np.asarray(current, dtype=np.float64)
    best, best_key = None, None
    for q in np.asarray(branches, dtype=np.float64):
        shifted = current + (q - current + math.pi) % TWO_PI - math.pi      # nearest turn
        for j in range(len(shifted)):            # that turn out of range: the other side's
            if shifted[j] > high[j]:
                shifted[j] -= TWO_PI
            elif shifted[j] < low[j]:
                shifted[j] += TWO_PI
        if np.any(shifted < low - 1e-12) or np.any(shifted > high + 1e-12):
            continue
        move = np.abs(shifted - current)
        key = (float(move.max()), float(move.sum()))
        if best_key is None or key < best_key:
            best, best_key = shifted, key
    if best is None:
        raise Unreachable("every branch is outside the joint limits")
    return best
