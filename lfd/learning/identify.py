"""What a demonstration set can determine, checked before the fit.

* **Too few demonstrations.** With one demonstration every landmark stands in one place (or
  follows one path), so sum-to-one mixtures of them explain it about equally: learning the
  environment landmark from one is refused (``check_learnable``).
* **The tool point along an axis that never turns.** The tool point ``p`` (gripper frame)
  enters the features as ``A_n R_n p`` (``R_n`` the gripper's orientation at observation n,
  ``A_n`` the linear part of the learned ``K_virt^-1`` there); a component of ``p`` along a
  direction ``u`` that every ``A_n R_n`` maps to the same vector only shifts every feature by one
  constant, which the means absorb: the data cannot place it. ``unobservable_axes`` finds those
  directions from ``R_n' = A_n R_n`` (after the fit), from the spread of ``R_n' u`` over the
  observations (the eigenvectors of ``mean_n (R_n' - R_mean)^T (R_n' - R_mean)`` whose root eigenvalue is under
  ``MIN_TURN``, about 3 degrees of turning). ``FitConfig.tool_radius`` then keeps the tool point
  within the tool's size (``lfd.learning.em``), so an unobservable axis cannot run off to metres.
* **Landmarks that never move relative to each other.** Two landmarks whose relative pose is
  the same in every demonstration (and sample) cannot be told apart: their weights trade freely.
* **Fewer placements than weights.** With landmarks that stand still in each demonstration, the
  demonstrations beyond the first fix at most 3 coordinates each of the ``Z - 1`` free weights
  (the task's point must come out in one place of the virtual frame): 2 demonstrations of the 5
  powder landmarks learned weights 2.19, -1.29, 1.31, 3.47, -4.67 and a tool point on the bound.
* **A tool point on the bound.** The learned tool point ends on ``FitConfig.tool_radius``: the
  bound, not the data, placed it.

``identifiability_notes`` gives the warnings the fit reports (``FitResult.warnings``). What the
data determine only loosely, measured after the fit (standard errors, landmarks that explain the
demonstrations about equally, a tool point beyond the tool's size): ``lfd.learning.uncertainty``.
"""

from __future__ import annotations

import math

import numpy as np

from lfd.learning.fitconfig import FitError

__all__ = ["MIN_TURN", "check_learnable", "identifiability_notes", "rigidly_attached", "unobservable_axes"]

MIN_TURN = 0.05  # rad (~3 deg): the least rms turn of a unit lever for a tool-point axis to count as seen
ON_BOUND = 0.99  # a learned tool point this share of FitConfig.tool_radius away lies on the bound
RIGID_SPREAD = (0.005, np.deg2rad(0.5))  # m, rad: a relative pose that varies less is "the same"


def check_learnable(demoset, cfg) -> None:
    """``FitError`` when the environment landmark is to be learned from one demonstration.

    Also when its landmarks were tracked while they moved: measured on a handover-like set
    (``make_synthetic(landmark_motion=0.4)``, one demonstration), the weights came out 0.37,
    0.32, 0.32 and the tool point 27 cm off, so one is not enough there either."""
    if cfg.env == "learn" and len(demoset.demos) < 2 and len(demoset.landmark_names) > 1:
        raise FitError("learning the environment landmark needs at least 2 demonstrations: with one, every "
                       "mixture of the landmarks explains it equally (give more demonstrations, or fix the "
                       "landmark: --env manual)")


def unobservable_axes(R: np.ndarray, min_turn: float = MIN_TURN) -> np.ndarray:
    """``(k, 3)`` unit directions of the gripper frame along which a tool point cannot be placed
    from orientations ``R (N, 3, 3)`` (k = 0..3)."""
    D = R - R.mean(axis=0)  # (N, 3, 3)
    M = np.einsum("nji,njk->ik", D, D) / len(R)  # (3, 3) mean (R_n - R_mean)^T (R_n - R_mean)
    lam, vec = np.linalg.eigh(M)
    axes = vec[:, np.sqrt(np.clip(lam, 0, None)) < min_turn].T  # (k, 3)
    signs = np.sign(axes[np.arange(len(axes)), np.abs(axes).argmax(axis=1)])  # largest component positive
    return axes * signs[:, None]


def _landmarks_still(demoset) -> bool:
    """Whether every landmark stands still (``RIGID_SPREAD``'s distance) within each demonstration."""
    Z = len(demoset.landmark_names)
    for d in demoset.demos:
        pos = np.asarray(d.landmarks).reshape(-1, Z, 4, 4)[:, :, :3, 3]  # (S, Z, 3)
        if np.linalg.norm(pos - pos[:1], axis=-1).max() >= RIGID_SPREAD[0]:
            return False
    return True


def rigidly_attached(demoset) -> list[tuple[str, str]]:
    """Landmark pairs whose relative pose is the same throughout the set (``RIGID_SPREAD``)."""
    poses = np.concatenate([np.asarray(d.landmarks).reshape(-1, len(demoset.landmark_names), 4, 4)
                            for d in demoset.demos])  # (R, Z, 4, 4)
    names, out = demoset.landmark_names, []
    for i in range(len(names)):
        for j in range(i + 1, len(names)):
            rel = np.linalg.inv(poses[:, i]) @ poses[:, j]  # (R, 4, 4)
            dt = np.linalg.norm(rel[:, :3, 3] - rel[:, :3, 3].mean(axis=0), axis=1).max()
            cos = (np.einsum("nii->n", rel[:, :3, :3].transpose(0, 2, 1) @ rel[0, :3, :3]) - 1) / 2
            dr = np.arccos(np.clip(cos, -1, 1)).max()
            if len(rel) > 1 and dt < RIGID_SPREAD[0] and dr < RIGID_SPREAD[1]:
                out.append((names[i], names[j]))
    return out


def identifiability_notes(demoset, R_virt_ee: np.ndarray, cfg, tool=None) -> list[str]:
    """Warnings about what the set cannot determine. ``R_virt_ee (N, 3, 3)``: the end link's
    orientation in the learned virtual landmark's frame at every observation (``A R_world_ee``,
    ``A`` the linear part of ``K_virt^-1``): a tool point component is placed when that turns,
    whether the gripper or the landmarks turned; ``tool (3,)``: the learned tool point."""
    notes = []
    if cfg.tool == "learn":
        axes = unobservable_axes(np.asarray(R_virt_ee))
        if not len(axes) and tool is not None and np.linalg.norm(tool) >= ON_BOUND * cfg.tool_radius:
            notes.append(f"the learned tool point lies on the tool radius bound ({cfg.tool_radius:g} m, "
                         f"--tool-radius): the bound placed it, not the demonstrations (too few, or too alike; "
                         f"or a tool longer than the bound)")
        if len(axes):
            dirs = ", ".join("(" + ", ".join(f"{round(x, 2) + 0.0:+.2f}" for x in a) + ")" for a in axes)
            what = ("the gripper's orientation hardly changes: the tool point cannot be placed in any direction"
                    if len(axes) == 3 else f"the gripper's orientation varies too little to place the tool point "
                    f"along {dirs} (gripper frame)")
            notes.append(f"{what}; it is only held within the tool radius {cfg.tool_radius:g} m "
                         f"(FitConfig.tool_radius, --tool-radius), anywhere up to it along "
                         f"{'that axis' if len(axes) == 1 else 'those axes'}: turn the tool while demonstrating")
    if cfg.env == "learn":
        Z, M = len(demoset.landmark_names), len(demoset.demos)
        if Z > 1 and 3 * (M - 1) < Z - 1 and _landmarks_still(demoset):
            notes.append(f"{M} demonstrations for {Z} landmarks: with the landmarks standing still, the demonstrations "
                         f"beyond the first fix at most {3 * (M - 1)} of the {Z - 1} free landmark weights, so the "
                         f"data do not determine the environment landmark; give at least "
                         f"{1 + math.ceil((Z - 1) / 3)} demonstrations, or fix the landmark (--env manual)")
        for a, b in rigidly_attached(demoset):
            notes.append(f"landmarks {a!r} and {b!r} keep the same relative pose in every demonstration: their "
                         f"weights cannot be told apart (the environment landmark may mix them arbitrarily)")
    return notes
