"""Inverse kinematics on point positions, every frame at once: a body model's named points pulled towards goals,
chosen points kept on or above the floor z = 0, hinges within their limits. Frames are independent, so each is one
small Levenberg-Marquardt system (nv unknowns). Used by retargeting (retarget/solve.py) and by the planting of the
offline physics' held feet (dynamics/planting.py)."""

from __future__ import annotations

import numpy as np

from . import kinematics as kin
from .model import BodyModel

FLOOR_WEIGHT = 1000.0  # a point below the floor, pushed up: a wall, so a point held off its goal never sinks
STEP_TOLERANCE = 1e-6  # stop once no frame's Gauss-Newton step exceeds this (metres or radians)
IK_DAMPING = 1e-4  # Levenberg-Marquardt damping relative to the normal matrix's mean diagonal
CHUNK_FRAMES = 512  # frames solved together: the Jacobians of 14,000 frames at once took 900 MB


def solve_points(body: BodyModel, qpos: np.ndarray, point_ids: np.ndarray, goal: np.ndarray, weights: np.ndarray,
                 floor_ids: np.ndarray, iterations: int, dofs: np.ndarray | None = None,
                 floor_frames: np.ndarray | None = None) -> np.ndarray:
    """(T, nq): qpos (T, nq) moved so that the points point_ids (P,) approach goal (T, P, 3) m, each residual
    times weights (T, P), the points floor_ids (F,) stay on or above z = 0 on the floor_frames (T,) bool (None:
    all), and hinges stay within their limits; at most `iterations` Gauss-Newton steps, moving only the degrees
    of freedom `dofs` (None: all nv). Solved CHUNK_FRAMES at a time, so that memory does not grow with the clip."""
    floor_frames = np.ones(len(qpos), bool) if floor_frames is None else np.asarray(floor_frames, bool)
    if len(qpos) > CHUNK_FRAMES:
        return np.concatenate([solve_points(body, qpos[i:i + CHUNK_FRAMES], point_ids, goal[i:i + CHUNK_FRAMES],
                                            weights[i:i + CHUNK_FRAMES], floor_ids, iterations, dofs,
                                            floor_frames[i:i + CHUNK_FRAMES])
                               for i in range(0, len(qpos), CHUNK_FRAMES)])
    tab = kin.tables(body)
    hinge_q = tab.qadr[tab.hinge_bodies]
    limits = np.array([body.bodies[b].limit for b in tab.hinge_bodies])
    q = np.array(qpos, dtype=float)
    q[:, hinge_q] = np.clip(q[:, hinge_q], limits[:, 0], limits[:, 1])
    all_ids = np.concatenate([point_ids, floor_ids])
    moved = np.arange(body.nv) if dofs is None else np.asarray(dofs)
    P, T, nv = len(point_ids), len(q), len(moved)
    # The wall's active set can make a frame alternate between two poses (one through the floor) instead of
    # settling: each frame keeps its iterate of least cost, not its last.
    best, best_cost = q.copy(), np.full(T, np.inf)
    for iteration in range(iterations + 1):
        pose = kin.forward_kinematics(body, q)
        heights = pose.points[:, floor_ids, 2]
        below = (heights < 0.0) & floor_frames[:, None]  # the wall's active set, found again each iteration
        r = np.concatenate([(weights[..., None] * (pose.points[:, point_ids] - goal)).reshape(T, -1),
                            FLOOR_WEIGHT * np.where(below, heights, 0.0)], axis=1)
        cost = (r ** 2).sum(axis=1)
        lower = cost < best_cost
        best[lower], best_cost[lower] = q[lower], cost[lower]
        if iteration == iterations:
            break
        J_all = kin.point_jacobian(body, pose, all_ids)[..., moved]  # (T, P + F, 3, nv)
        J_goal = weights[..., None, None] * J_all[:, :P]
        J_floor = FLOOR_WEIGHT * below[..., None] * J_all[:, P:, 2]  # (T, F, nv)
        J = np.concatenate([J_goal.reshape(T, -1, nv), J_floor], axis=1)
        H = J.transpose(0, 2, 1) @ J
        g = (J.transpose(0, 2, 1) @ r[..., None])[..., 0]
        damping = IK_DAMPING * np.trace(H, axis1=1, axis2=2)[:, None, None] / nv + 1e-9
        step = np.zeros((T, body.nv))
        step[:, moved] = -np.linalg.solve(H + damping * np.eye(nv), g[..., None])[..., 0]
        q = kin.integrate(body, q, step)
        q[:, hinge_q] = np.clip(q[:, hinge_q], limits[:, 0], limits[:, 1])
        if np.abs(step).max() < STEP_TOLERANCE:
            return q
    return best
