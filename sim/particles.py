"""Particles: small rigid spheres standing in for powder (spoon) and liquid (pitcher).

They are spawned on a grid inside the tool's cavity (given in the gripper frame, see
``sim.layout``) and counted by where their centres are: inside the bowl, inside the tool, or
elsewhere (spilled).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from sim import layout as L
from sim.bullet import p

__all__ = [
    "ParticleSet",
    "cavity_points",
    "in_bowl_mask",
    "in_tool_mask",
    "particle_positions",
    "remove_particles",
    "spawn_particles",
]

# Contact properties: powder grains do not roll away; liquid drops slide freely.
_MATERIAL = {"powder": dict(lateralFriction=0.6, rollingFriction=0.001, spinningFriction=0.001, restitution=0.0),
             "pour": dict(lateralFriction=0.05, rollingFriction=0.0, spinningFriction=0.0, restitution=0.0)}
_RGBA = {"powder": (0.95, 0.95, 0.85, 1.0), "pour": (0.1, 0.3, 1.0, 1.0)}


@dataclass(frozen=True)
class ParticleSet:
    """The particle bodies of one spawn: ``ids (N,)`` body ids, their ``radius`` and ``task``."""

    ids: tuple[int, ...]
    radius: float
    task: str

    def __len__(self) -> int:
        return len(self.ids)


def cavity_points(task: str, n: int, radius: float) -> np.ndarray:
    """``n`` sphere centres filling the tool cavity bottom-up, gripper frame: ``(n, 3)``.

    Raises ``ValueError`` when ``n`` spheres of ``radius`` do not fit in a few layers.
    """
    if n < 0:
        raise ValueError(f"n_particles must be >= 0, got {n}")
    if not 0.001 <= radius <= 0.02:
        raise ValueError(f"particle_radius must be in [0.001, 0.02] m, got {radius}")
    gap = 2.05 * radius
    if task == "powder":
        hx = L.SPOON_SCOOP_HALF_X - L.SPOON_WALL_THICKNESS - radius * 1.05
        z0 = L.SPOON_SCOOP_Z[0] + L.SPOON_WALL_THICKNESS + radius * 1.05
        z1 = L.SPOON_SCOOP_Z[1] - L.SPOON_WALL_THICKNESS - radius * 1.05
        xs = np.arange(-hx, hx + 1e-9, gap)
        zs = np.arange(z0, z1 + 1e-9, gap)
        layer = np.array([(x, z) for x in xs for z in zs])
        y0, y_max = radius * 1.05, L.SPOON_WALL_HEIGHT + 4 * radius
    elif task == "pour":
        rin = L.PITCHER_RADIUS - radius * 1.05
        g = np.arange(-rin, rin + 1e-9, gap)
        layer = np.array([(x, L.PITCHER_AXIS_Z + z) for x in g for z in g if x * x + z * z <= rin * rin])
        y0, y_max = L.PITCHER_FLOOR_Y + radius * 1.05, L.PITCHER_NOTCH_Y
    else:
        raise ValueError(f"task must be 'powder' or 'pour', got {task!r}")
    if n == 0:
        return np.zeros((0, 3))
    if len(layer) == 0:
        raise ValueError(f"particle_radius {radius} is too large for the {task} tool")
    n_layers = -(-n // len(layer))
    if y0 + (n_layers - 1) * gap > y_max:
        raise ValueError(f"{n} particles of radius {radius} do not fit in the {task} tool "
                         f"(at most {len(layer) * (1 + int((y_max - y0) / gap))})")
    pts = [(x, y0 + k * gap, z) for k in range(n_layers) for (x, z) in layer]
    return np.array(pts[:n], dtype=float)


def spawn_particles(client: int, task: str, T_world_tool: np.ndarray, n: int, radius: float) -> ParticleSet:
    """Create ``n`` spheres resting (after settling) in the tool posed at ``T_world_tool (4, 4)``."""
    p_tool = cavity_points(task, n, radius)  # (n, 3)
    if n == 0:
        return ParticleSet((), radius, task)
    p_world = p_tool @ T_world_tool[:3, :3].T + T_world_tool[:3, 3]  # (n, 3)
    col = p.createCollisionShape(p.GEOM_SPHERE, radius=radius, physicsClientId=client)
    vis = p.createVisualShape(p.GEOM_SPHERE, radius=radius, rgbaColor=_RGBA[task], physicsClientId=client)
    # one body per particle: createMultiBody(batchPositions=...) returns invalid ids once
    # bodies have been removed from the client (PyBullet 3.2.7)
    ids = [p.createMultiBody(L.PARTICLE_MASS, col, vis, basePosition=[float(v) for v in x], physicsClientId=client)
           for x in p_world]
    for b in ids:
        p.changeDynamics(b, -1, physicsClientId=client, **_MATERIAL[task])
    return ParticleSet(tuple(ids), radius, task)


def remove_particles(client: int, particles: ParticleSet) -> None:
    for b in particles.ids:
        p.removeBody(b, physicsClientId=client)


def particle_positions(client: int, particles: ParticleSet) -> np.ndarray:
    """World positions of the particle centres: ``(N, 3)``."""
    if len(particles) == 0:
        return np.zeros((0, 3))
    return np.array([p.getBasePositionAndOrientation(b, physicsClientId=client)[0] for b in particles.ids])


def in_bowl_mask(p_world: np.ndarray, T_world_bowl: np.ndarray) -> np.ndarray:
    """``(N, 3) -> (N,)`` bool: centre inside the bowl's cylinder (floor to rim + 1 cm)."""
    p_bowl = (p_world - T_world_bowl[:3, 3]) @ T_world_bowl[:3, :3]  # (N, 3) in the bowl frame
    radial = np.linalg.norm(p_bowl[:, :2], axis=1)
    return (radial < L.BOWL_RADIUS) & (p_bowl[:, 2] > 0.0) & (p_bowl[:, 2] < L.BOWL_HEIGHT + 0.01)


def in_tool_mask(p_world: np.ndarray, T_world_tool: np.ndarray, task: str) -> np.ndarray:
    """``(N, 3) -> (N,)`` bool: centre inside the tool's cavity (the walls' height + 1 cm)."""
    p_tool = (p_world - T_world_tool[:3, 3]) @ T_world_tool[:3, :3]  # (N, 3) in the gripper frame
    x, y, z = p_tool[:, 0], p_tool[:, 1], p_tool[:, 2]
    if task == "powder":
        z0, z1 = L.SPOON_SCOOP_Z
        # inside the flared cross-section: |x| below the wall line through floor edge and rim
        wall_x = L.SPOON_SCOOP_HALF_X + np.clip(y, 0.0, None) * math.tan(L.SPOON_WALL_FLARE)
        return (np.abs(x) < wall_x) & (z > z0) & (z < z1) & (y > -0.002) & (y < L.SPOON_WALL_HEIGHT + 0.01)
    radial = np.hypot(x, z - L.PITCHER_AXIS_Z)
    return (radial < L.PITCHER_RADIUS) & (y > L.PITCHER_FLOOR_Y - 0.002) & (y < L.PITCHER_RIM_Y + 0.01)
