"""Batched forward kinematics of a serial arm, built from any URDF through pytorch-kinematics.

Conventions (written once, used everywhere in lfd):

* poses are homogeneous matrices, ``T_a_b`` maps coordinates in frame ``b`` to
  frame ``a`` (column vectors): ``p_a = T_a_b @ p_b``;
* the "world" frame of a kinematic model is the URDF root link's frame;
* configurations are batch-first, ``q: (B, d)``, joint order as in
  ``KinematicModel.joint_names``.
"""

from __future__ import annotations

import copy
import math
import xml.etree.ElementTree as ET
from pathlib import Path

import torch

from lfd.errors import UserInputError
from lfd.robot.device import usable_device
from lfd.robot.robots import BAXTER_LEFT, RobotSpec, resolve_urdf

__all__ = ["KinematicModel", "KinematicsError"]


class KinematicsError(UserInputError):
    """A robot description or an input to the kinematics that cannot be used."""


MOVABLE = ("revolute", "continuous", "prismatic")  # the joint types a chain's configuration holds


def _kinematic_urdf(root: ET.Element) -> bytes:
    """The robot description with only what forward kinematics reads: its joints (without their
    dynamics), its links by name (their visuals, collisions and inertia dropped), nothing else (transmissions,
    Gazebo tags). urdf_parser_py, which pytorch-kinematics parses with, prints every tag it does
    not model to stderr (a material inside a collision, a transmission): not errors for
    kinematics, and without them it has nothing to print."""
    out = ET.Element(root.tag, root.attrib)
    for child in root:
        if child.tag == "joint":
            joint = copy.deepcopy(child)
            for dyn in joint.findall("dynamics"):  # (the Panda's mu_coulomb: "Unknown attribute", per joint)
                joint.remove(dyn)
            if joint.get("type") in MOVABLE and joint.find("axis") is None:  # the URDF's default axis, x;
                ET.SubElement(joint, "axis", {"xyz": "1 0 0"})  # pytorch-kinematics' own default is z
            out.append(joint)
        elif child.tag == "link":
            ET.SubElement(out, "link", child.attrib)
    return ET.tostring(out)


def _three_finite(text: str, what: str) -> list[float]:
    """The three finite numbers of a URDF attribute; ``KinematicsError`` naming ``what`` otherwise."""
    try:
        v = [float(x) for x in text.split()]
    except ValueError:
        v = []
    if len(v) != 3 or not all(math.isfinite(x) for x in v):
        raise KinematicsError(f"{what} is not three finite numbers")
    return v


def _joint_table(urdf_text: str) -> dict[str, dict]:
    """Per joint of the URDF (the robot's own ``<joint>`` elements, not the ones a ROS
    ``<transmission>`` names): type, lower, upper, velocity (None when absent), mimic (the name of
    the joint it follows, or None).

    As the URDF specification (and urdfdom, and PyBullet) reads them: a ``revolute`` or
    ``prismatic`` joint's missing ``lower`` or ``upper`` is 0; a ``continuous`` joint has no
    position limits, whatever its ``<limit>`` says; a velocity of 0 or less is no velocity limit
    (CAD exporters write ``velocity="0"``; the planner refuses a joint without one).

    Raises ``KinematicsError`` for a repeated joint name, a limit that is not a number, or NaN,
    an origin or axis that is not three finite numbers, a zero axis; ``ET.ParseError`` for text
    that is not XML."""
    root = ET.fromstring(urdf_text)
    table: dict[str, dict] = {}
    for j in root.findall("joint"):  # direct children: <transmission><joint name=...> is not a joint
        name = j.get("name", "")
        if name in table:
            raise KinematicsError(f"the URDF defines joint {name!r} twice")
        lim = j.find("limit")
        mimic = j.find("mimic")
        row: dict = {"type": j.get("type"), "mimic": None if mimic is None else mimic.get("joint", "")}
        for k in ("lower", "upper", "velocity"):
            text = lim.get(k) if lim is not None else None
            try:
                row[k] = None if text is None else float(text)
            except ValueError:
                raise KinematicsError(f"joint {name!r}: limit {k}={text!r} is not a number") from None
            if row[k] is not None and math.isnan(row[k]):
                raise KinematicsError(f"joint {name!r}: limit {k} is NaN")
        if row["type"] == "continuous":
            row["lower"] = row["upper"] = None
        elif row["type"] in ("revolute", "prismatic") and lim is not None:
            row["lower"] = 0.0 if row["lower"] is None else row["lower"]
            row["upper"] = 0.0 if row["upper"] is None else row["upper"]
        if row["velocity"] is not None and not row["velocity"] > 0:
            row["velocity"] = None
        if row["lower"] is not None and row["upper"] is not None and row["lower"] > row["upper"]:
            raise KinematicsError(f"joint {name!r}: lower limit {row['lower']} is above upper {row['upper']}")
        origin = j.find("origin")
        for key in ("xyz", "rpy"):  # (a NaN here made every pose NaN: the fit failed, IK raised)
            text = origin.get(key) if origin is not None else None
            if text is not None:
                _three_finite(text, f"joint {name!r}: origin {key}={text!r}")
        axis = j.find("axis")
        xyz = axis.get("xyz") if axis is not None else None
        if xyz is not None and row["type"] in MOVABLE \
                and not any(_three_finite(xyz, f"joint {name!r}: axis {xyz!r}")):
            raise KinematicsError(f"joint {name!r}: its axis is zero")
        table[name] = row
    return table


def _sample_range(joint: dict) -> tuple[float, float] | None:
    """``(lower, upper)`` to sample a joint from (a row of ``_joint_table``): its limits, and for
    a missing one of a joint that turns, one turn from the other (``[-pi, pi]`` with neither);
    None for a joint that slides without both."""
    lower, upper = joint["lower"], joint["upper"]
    if lower is not None and upper is not None and math.isfinite(lower) and math.isfinite(upper):
        return lower, upper
    if joint["type"] not in ("revolute", "continuous"):
        return None
    if lower is not None and math.isfinite(lower):
        return lower, lower + 2 * math.pi
    if upper is not None and math.isfinite(upper):
        return upper - 2 * math.pi, upper
    return -math.pi, math.pi


class KinematicModel:
    """Forward kinematics of the chain from the URDF root to ``end_link``.

    Parameters
    ----------
    urdf_path : path of the URDF file.
    end_link : name of the link whose pose ``fk`` returns.
    joint_names : the controlled joints, in order; checked against the chain.
        Defaults to the chain's movable joints.
    dtype, device : of every tensor this object holds and returns.

    Raises
    ------
    KinematicsError
        unknown end link, joints not on the chain, unreadable URDF.
    """

    def __init__(self, urdf_path: str | Path, end_link: str, joint_names=None,
                 dtype: torch.dtype = torch.float64, device: str | torch.device = "cpu"):
        import pytorch_kinematics as pk  # heavy import, kept local to construction

        urdf_path = Path(urdf_path)
        if not urdf_path.is_file():
            raise KinematicsError(f"URDF file not found: {urdf_path}")
        text = urdf_path.read_text(errors="replace")
        try:
            joints = _joint_table(text)
        except ET.ParseError as e:
            raise KinematicsError(f"cannot parse URDF {urdf_path}: {e}") from e
        root = ET.fromstring(text)
        links = {ln.get("name") for ln in root.iter("link")}
        if end_link not in links:
            raise KinematicsError(f"end link {end_link!r} is not a link of {urdf_path.name}")
        try:
            chain = pk.build_serial_chain_from_urdf(_kinematic_urdf(root), end_link)
        except Exception as e:  # pytorch-kinematics raises bare exceptions for bad chains
            raise KinematicsError(f"cannot build a chain to {end_link!r} from {urdf_path}: {e}") from e
        chain_joints = list(chain.get_joint_parameter_names())
        mimics = [f"{n} (follows {joints[n]['mimic']!r})" for n in chain_joints if joints.get(n, {}).get("mimic")]
        if mimics:  # each would be a joint of its own: sampled, solved for and planned apart from its leader
            raise KinematicsError(f"the chain to {end_link!r} has mimic joint(s) {', '.join(mimics)}, which lfd's "
                                  "kinematics do not model; give a URDF whose chain has only independent joints")
        if joint_names is None:
            joint_names = chain_joints
        joint_names = tuple(joint_names)
        if list(joint_names) != chain_joints:
            unknown = [n for n in joint_names if n not in joints]
            if unknown:
                raise KinematicsError(f"unknown joint name(s) {unknown} in {urdf_path.name}")
            raise KinematicsError(
                f"joints {list(joint_names)} are not the movable joints of the chain to "
                f"{end_link!r}, which are {chain_joints}")
        self.urdf_path = urdf_path
        self.end_link = end_link
        self.joint_names = joint_names
        self.dtype = dtype
        self.device = usable_device(device)
        self._chain = chain.to(dtype=dtype, device=self.device)
        inf = float("inf")
        self.lower = torch.tensor([joints[n]["lower"] if joints[n]["lower"] is not None else -inf
                                   for n in joint_names], dtype=dtype, device=self.device)  # (d,)
        self.upper = torch.tensor([joints[n]["upper"] if joints[n]["upper"] is not None else inf
                                   for n in joint_names], dtype=dtype, device=self.device)  # (d,)
        self.velocity = torch.tensor([joints[n]["velocity"] if joints[n]["velocity"] is not None else inf
                                      for n in joint_names], dtype=dtype, device=self.device)  # (d,)
        # where ``sample_uniform`` draws each joint: its limits; a joint that turns without them
        # (``continuous``) over one turn, which holds every angle modulo 2 pi; None for a joint that
        # slides without them (it cannot be sampled)
        self._sample_range = tuple(_sample_range(joints[n]) for n in joint_names)

    @classmethod
    def from_spec(cls, spec: RobotSpec = BAXTER_LEFT, dtype: torch.dtype = torch.float64,
                  device: str | torch.device = "cpu") -> KinematicModel:
        """The model of a ``RobotSpec`` (Baxter's left arm by default)."""
        try:
            path = resolve_urdf(spec.urdf)
        except FileNotFoundError as e:
            raise KinematicsError(str(e)) from e
        return cls(path, spec.end_link, spec.joint_names, dtype=dtype, device=device)

    @property
    def dof(self) -> int:
        return len(self.joint_names)

    def to(self, dtype: torch.dtype | None = None, device=None) -> KinematicModel:
        """A copy of this model with another dtype and/or device."""
        new = object.__new__(KinematicModel)
        new.__dict__.update(self.__dict__)
        new.dtype = dtype or self.dtype
        new.device = usable_device(device) if device is not None else self.device
        # pytorch-kinematics converts a chain in place: convert a copy, never the original.
        new._chain = copy.deepcopy(self._chain).to(dtype=new.dtype, device=new.device)
        for k in ("lower", "upper", "velocity"):
            setattr(new, k, getattr(self, k).to(dtype=new.dtype, device=new.device))
        return new

    def _check_q(self, q: torch.Tensor) -> torch.Tensor:
        if not torch.is_tensor(q):
            q = torch.as_tensor(q, dtype=self.dtype, device=self.device)
        if q.dim() == 0 or q.shape[-1] != self.dof:  # (a scalar was an IndexError)
            raise KinematicsError(
                f"expected configurations with {self.dof} joint values {list(self.joint_names)}, "
                f"got shape {tuple(q.shape)}")
        return q.to(dtype=self.dtype, device=self.device)

    def fk(self, q) -> torch.Tensor:
        """End-link pose ``T_world_ee``.

        ``q: (B, d)`` or ``(d,)`` -> ``(B, 4, 4)`` or ``(4, 4)``; differentiable in ``q``.
        """
        q = self._check_q(q)
        single = q.dim() == 1
        qb = q.reshape(-1, self.dof)  # (B, d)
        T_world_ee = self._chain.forward_kinematics(qb).get_matrix()  # (B, 4, 4)
        if single:
            return T_world_ee[0]
        return T_world_ee.reshape(*q.shape[:-1], 4, 4)

    @property
    def frame_names(self) -> tuple[str, ...]:
        """The chain's frames (URDF link names), root first, the end link last: the order of
        ``frame_poses``."""
        return tuple(self._chain.get_frame_names(exclude_fixed=False))

    def frame_poses(self, q) -> torch.Tensor:
        """Poses ``T_world_frame (B, L, 4, 4)`` of every frame of the chain (``frame_names``'
        order) from one forward pass: ``q (B, d)``."""
        qb = self._check_q(q).reshape(-1, self.dof)
        frames = self._chain.forward_kinematics(qb, end_only=False)  # {name: Transform3d}
        return torch.stack([frames[n].get_matrix().expand(len(qb), 4, 4) for n in self.frame_names], dim=1)

    def frame_origins(self, q) -> tuple[torch.Tensor, torch.Tensor]:
        """Origins of every frame of the chain ``(B, L, 3)`` (root to end link, world frame) and
        the end-link pose ``T_world_ee (B, 4, 4)``, from one forward pass: ``q (B, d)``. The arm
        lies within the union of the segments between consecutive origins grown by the links'
        radii (used to bound the space a motion sweeps)."""
        T_world_frame = self.frame_poses(q)  # (B, L, 4, 4)
        return T_world_frame[:, :, :3, 3], T_world_frame[:, -1]

    def jacobian(self, q, with_pose: bool = False) -> torch.Tensor | tuple[torch.Tensor, torch.Tensor]:
        """Geometric Jacobian of the end link in the world frame: ``(B, d) -> (B, 6, d)``
        (rows: linear velocity, then angular velocity; a single ``(d,)`` gives ``(1, 6, d)``).
        With ``with_pose``, also ``T_world_ee (B, 4, 4)`` from the same forward pass:
        ``(J, T_world_ee)``, one FK instead of two."""
        q = self._check_q(q).reshape(-1, self.dof)
        if not with_pose:
            return self._chain.jacobian(q)
        J, T_world_ee = self._chain.jacobian(q, ret_eef_pose=True)
        return J, (T_world_ee.get_matrix() if hasattr(T_world_ee, "get_matrix") else T_world_ee)

    def within_limits(self, q, tol: float = 0.0) -> torch.Tensor:
        """``(B, d) -> (B,)`` bool: every joint within its URDF limits (+- ``tol``)."""
        q = self._check_q(q)
        return ((q >= self.lower - tol) & (q <= self.upper + tol)).all(dim=-1)

    def sample_uniform(self, n: int, generator: torch.Generator | None = None) -> torch.Tensor:
        """``n`` configurations uniform within the joint limits: ``(n, d)``; a joint that turns
        without limits (``continuous``) over one turn, ``[-pi, pi]``.

        Raises ``KinematicsError`` for a joint that slides without limits (a prismatic joint
        whose URDF gives none): no range to draw from; a planner needs its own ``sample_fn``."""
        unbounded = [name for name, r in zip(self.joint_names, self._sample_range) if r is None]
        if unbounded:
            raise KinematicsError(f"joint(s) {unbounded} slide without limits in {self.urdf_path.name}: no range to "
                                  "sample them from; give them limits, or pass your own sample_fn to the planner")
        lo, hi = (torch.tensor(x, dtype=self.dtype, device=self.device) for x in zip(*self._sample_range))  # (d,)
        u = torch.rand(n, self.dof, generator=generator, dtype=self.dtype, device="cpu").to(self.device)
        return lo + u * (hi - lo)
