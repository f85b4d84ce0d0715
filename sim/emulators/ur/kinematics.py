"""Forward and inverse kinematics of a UR5e for the controller emulator.

Denavit-Hartenberg parameters from Universal Robots' article "DH parameters for
calculations of kinematics and dynamics" (UR5e column): d1 = 0.1625 m,
a2 = -0.425 m, a3 = -0.3922 m, d4 = 0.1333 m, d5 = 0.0997 m, d6 = 0.0996 m,
alpha = [pi/2, 0, 0, pi/2, -pi/2, 0]. Poses are ``[x, y, z, rx, ry, rz]`` in m and a
rotation vector in rad, as in the RTDE guide's ``actual_TCP_pose``.

The inverse kinematics is numerical (damped least squares from ``q_near``), like the
controller's ``get_inverse_kin(x, qnear, maxPositionError, maxOrientationError)``
(URScript manual): it returns the solution nearest to ``q_near`` or reports none.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from scipy.spatial.transform import Rotation

D = (0.1625, 0.0, 0.0, 0.1333, 0.0997, 0.0996)
A = (0.0, -0.425, -0.3922, 0.0, 0.0, 0.0)
ALPHA = (np.pi / 2, 0.0, 0.0, np.pi / 2, -np.pi / 2, 0.0)


def pose_to_matrix(pose: Sequence[float]) -> np.ndarray:
    """4x4 homogeneous transform of a ``[x, y, z, rx, ry, rz]`` pose."""
    out = np.eye(4)
    out[:3, :3] = Rotation.from_rotvec(np.asarray(pose[3:6], float)).as_matrix()
    out[:3, 3] = pose[:3]
    return out


def matrix_to_pose(matrix: np.ndarray) -> np.ndarray:
    """``[x, y, z, rx, ry, rz]`` of a 4x4 homogeneous transform."""
    return np.array([*matrix[:3, 3], *Rotation.from_matrix(matrix[:3, :3]).as_rotvec()])


def _frames(q: Sequence[float], tcp: Sequence[float]) -> tuple[list[np.ndarray], np.ndarray]:
    """The base and the six joint frames (4x4), and the TCP frame."""
    frames = [np.eye(4)]
    for theta, d, a, alpha in zip(q, D, A, ALPHA):
        ct, st, ca, sa = np.cos(theta), np.sin(theta), np.cos(alpha), np.sin(alpha)
        link = np.array([[ct, -st * ca, st * sa, a * ct], [st, ct * ca, -ct * sa, a * st], [0, sa, ca, d], [0, 0, 0, 1]])
        frames.append(frames[-1] @ link)
    return frames, frames[-1] @ pose_to_matrix(tcp)


def forward(q: Sequence[float], tcp: Sequence[float] = (0.0,) * 6) -> np.ndarray:
    """TCP pose for joint angles ``q`` (rad) with the TCP offset ``tcp`` from the flange
    (URScript ``get_forward_kin``)."""
    return matrix_to_pose(_frames(q, tcp)[1])


def _error(target: np.ndarray, actual: np.ndarray) -> np.ndarray:
    """Position difference (m) and rotation vector (rad) taking ``actual`` to ``target`` (4x4), base frame."""
    rotation = Rotation.from_matrix(target[:3, :3] @ actual[:3, :3].T).as_rotvec()
    return np.array([*(target[:3, 3] - actual[:3, 3]), *rotation])


def pose_error(target: Sequence[float], actual: Sequence[float]) -> np.ndarray:
    """Position difference (m) and rotation vector (rad) taking pose ``actual`` to ``target``, base frame."""
    return _error(pose_to_matrix(target), pose_to_matrix(actual))


def inverse(
    pose: Sequence[float],
    q_near: Sequence[float],
    tcp: Sequence[float] = (0.0,) * 6,
    *,
    max_position_error: float = 1e-6,
    max_orientation_error: float = 1e-6,
    iterations: int = 100,
) -> np.ndarray | None:
    """Joint angles reaching ``pose`` found from ``q_near`` (damped least squares with the
    geometric Jacobian), or None if there is no solution within the given errors (m, rad)."""
    target = pose_to_matrix(pose)
    q = np.array(q_near, float)
    for _ in range(iterations):
        frames, end = _frames(q, tcp)
        error = _error(target, end)
        if np.linalg.norm(error[:3]) <= max_position_error and np.linalg.norm(error[3:]) <= max_orientation_error:
            return q
        jacobian = np.empty((6, 6))
        for k in range(6):
            axis, origin = frames[k][:3, 2], frames[k][:3, 3]
            jacobian[:3, k] = np.cross(axis, end[:3, 3] - origin)
            jacobian[3:, k] = axis
        dq = jacobian.T @ np.linalg.solve(jacobian @ jacobian.T + 1e-4 * np.eye(6), error)
        q += np.clip(dq, -0.5, 0.5)
    return None
