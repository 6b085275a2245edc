"""Where robot descriptions come from.

The default robot is Baxter's left arm, described by the ``baxter_description``
shipped in the ``example-robot-data`` registry package (installed under
``site-packages/cmeel.prefix/share/example-robot-data``). Nothing is copied or
downloaded: the URDF is read in place and its ``package://`` mesh URIs resolve
relative to the ``share`` folder.
"""

from __future__ import annotations

import site
import sys
from dataclasses import dataclass
from pathlib import Path

__all__ = ["BAXTER_LEFT", "PANDA", "RobotSpec", "example_robot_data_share", "resolve_urdf", "robot_from_name"]

BAXTER_LEFT_JOINTS = ("left_s0", "left_s1", "left_e0", "left_e1", "left_w0", "left_w1", "left_w2")


@dataclass(frozen=True)
class RobotSpec:
    """A robot arm: its URDF source, the end link, and the controlled joints.

    ``urdf`` is either a filesystem path or ``"example-robot-data:<relative path>"``,
    which names a file inside the installed example-robot-data package.
    """

    name: str
    urdf: str
    end_link: str
    joint_names: tuple[str, ...]

    def to_dict(self) -> dict:
        return {"name": self.name, "urdf": self.urdf, "end_link": self.end_link,
                "joint_names": list(self.joint_names)}

    @classmethod
    def from_dict(cls, d: dict) -> RobotSpec:
        if isinstance(d, dict) and isinstance(d.get("joint_names"), (str, bytes)):  # not split into letters
            raise ValueError(f"robot description: joint_names must be a list of joint names, got the string "  # noqa: TRY004 (a user's file)
                             f"{d['joint_names']!r}")
        try:
            return cls(name=str(d["name"]), urdf=str(d["urdf"]), end_link=str(d["end_link"]),
                       joint_names=tuple(str(j) for j in d["joint_names"]))
        except (KeyError, TypeError) as e:
            raise ValueError(f"robot description needs name, urdf, end_link, joint_names; got {d!r}") from e


BAXTER_LEFT = RobotSpec(
    name="baxter_left",
    urdf="example-robot-data:robots/baxter_description/urdf/baxter.urdf",
    end_link="left_gripper",
    joint_names=BAXTER_LEFT_JOINTS,
)

PANDA = RobotSpec(  # Franka Emika Panda, its hand the end link (the fingers are not controlled)
    name="panda",
    urdf="example-robot-data:robots/panda_description/urdf/panda.urdf",
    end_link="panda_hand",
    joint_names=tuple(f"panda_joint{i}" for i in range(1, 8)),
)

_ROBOTS = {r.name: r for r in (BAXTER_LEFT, PANDA)}


def robot_from_name(name: str) -> RobotSpec:
    """The built-in robot called ``name`` (``ValueError`` naming the known ones otherwise)."""
    if name not in _ROBOTS:
        raise ValueError(f"unknown robot {name!r}; known robots: {', '.join(sorted(_ROBOTS))}")
    return _ROBOTS[name]


def example_robot_data_share() -> Path:
    """The ``share`` folder of the installed example-robot-data package.

    Raises ``FileNotFoundError`` when the package is not installed.
    """
    candidates = [Path(p) for p in sys.path if p] + [Path(p) for p in site.getsitepackages()]
    for base in candidates:
        share = base / "cmeel.prefix" / "share"
        if (share / "example-robot-data").is_dir():
            return share
    raise FileNotFoundError(
        "the example-robot-data package is not installed (pip install example-robot-data); "
        "it provides the Baxter URDF")


def resolve_urdf(urdf: str) -> Path:
    """Turn a ``RobotSpec.urdf`` string into an existing file path."""
    if urdf.startswith("example-robot-data:"):
        path = example_robot_data_share() / "example-robot-data" / urdf.split(":", 1)[1]
    else:
        path = Path(urdf).expanduser()
    if not path.is_file():
        raise FileNotFoundError(f"URDF file not found: {path}")
    return path
