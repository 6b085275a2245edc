"""Small SE(3) helpers on homogeneous 4x4 matrices (numpy)."""

from __future__ import annotations

import numpy as np

__all__ = ["RIGID_TOLERANCE", "not_rigid", "rigid_errors"]

RIGID_TOLERANCE = 1e-4  # |R^T R - I|, |det R - 1| and bottom-row error allowed in a pose


def rigid_errors(T: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """How far ``T: (..., 4, 4)`` is from a rigid transform.

    Returns (orthonormality error ``|R^T R - I|_max``, ``|det R - 1|``, bottom-row error), each ``(...)``.
    """
    T = np.asarray(T, dtype=np.float64)
    R = T[..., :3, :3]
    ortho = np.abs(np.swapaxes(R, -1, -2) @ R - np.eye(3)).max(axis=(-1, -2))
    with np.errstate(invalid="ignore"):  # a NaN pose (not sensed) gives NaN errors
        det = np.abs(np.linalg.det(R) - 1.0)
    bottom = np.abs(T[..., 3, :] - np.array([0.0, 0.0, 0.0, 1.0])).max(axis=-1)
    return ortho, det, bottom


def not_rigid(T: np.ndarray, tol: float = RIGID_TOLERANCE) -> np.ndarray:
    """``(...)`` True where ``T: (..., 4, 4)`` is further than ``tol`` from a rigid transform
    (any of ``rigid_errors``); NaN poses count as rigid (not sensed is said otherwise)."""
    ortho, det, bottom = rigid_errors(T)
    return (ortho > tol) | (det > tol) | (bottom > tol)
