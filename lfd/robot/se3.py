"""Small SE(3) helpers on homogeneous 4x4 matrices (numpy)."""

from __future__ import annotations

import numpy as np

__all__ = ["rigid_errors"]


def rigid_errors(T: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """How far ``T: (..., 4, 4)`` is from a rigid transform.

    Returns (orthonormality error ``|R^T R - I|_max``, ``|det R - 1|``, bottom-row error), each ``(...)``.
    """
    T = np.asarray(T, dtype=np.float64)
    R = T[..., :3, :3]
    ortho = np.abs(np.swapaxes(R, -1, -2) @ R - np.eye(3)).max(axis=(-1, -2))
    det = np.abs(np.linalg.det(R) - 1.0)
    bottom = np.abs(T[..., 3, :] - np.array([0.0, 0.0, 0.0, 1.0])).max(axis=-1)
    return ortho, det, bottom
