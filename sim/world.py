"""The simulated lab: Baxter, table, containers, obstacles, the held tool and its particles.

``World(task)`` owns one PyBullet client (DIRECT unless ``gui=True``) and passes its id to
every call. Baxter is loaded from example-robot-data at the world origin with identity
orientation and a fixed base, so ``lfd.robot.kinematics`` FK equals PyBullet's link poses. The tool
(spoon or pitcher, ``sim.assets``) is a link fixed to ``left_gripper`` inside the robot's
multibody: it follows ``set_q`` exactly and moves particles under physics.

Landmarks (``sensed_landmarks``): "bowl" first, then 4 distractors -- for ``powder`` the
visual-only markers ``marker_1..4``; for ``pour`` the paper's objects ``scissors``, ``spoon``,
``vase``, ``paper_towels``. Poses have the world orientation and the object's centroid.

Command line: ``python -m sim.world [--task powder|pour] [--gui] [--snapshot FILE.png]``.
"""

from __future__ import annotations

import functools
import os
import re
import socket
import struct
import sys
import tempfile
from pathlib import Path

import numpy as np

from lfd.robot.robots import BAXTER_LEFT, RobotSpec, example_robot_data_share, resolve_urdf
from sim import assets, quiet_stdio
from sim import layout as L
from sim.bullet import p
from sim.particles import ParticleSet, in_bowl_mask, in_tool_mask, particle_positions, remove_particles, spawn_particles

__all__ = ["World", "main", "no_display", "patched_urdf", "pose_to_matrix"]

TASKS = ("powder", "pour")
LANDMARKS = {"powder": ("bowl", "marker_1", "marker_2", "marker_3", "marker_4"),
             "pour": ("bowl", "scissors", "spoon", "vase", "paper_towels")}
_CENTROID_Z = {"bowl": L.BOWL_HEIGHT / 2, "source": L.SOURCE_HEIGHT / 2, "paper_towels": L.PAPER_TOWELS_HEIGHT / 2,
               "vase": L.VASE_HEIGHT / 2, "books": 0.05, "scissors": 0.006, "spoon": 0.006,
               "lamp_shade": L.LAMP_HEIGHT / 2}


def pose_to_matrix(pos, quat_xyzw) -> np.ndarray:
    """PyBullet (position, quaternion xyzw) -> ``T (4, 4)``."""
    T = np.eye(4)
    T[:3, :3] = np.array(p.getMatrixFromQuaternion(quat_xyzw)).reshape(3, 3)
    T[:3, 3] = pos
    return T


def patched_urdf(spec: RobotSpec, task: str, folder: Path) -> Path:
    """A copy of the robot URDF with absolute mesh paths and the tool link spliced in."""
    src = resolve_urdf(spec.urdf)
    text = src.read_text(errors="replace")
    if "package://" in text:
        text = text.replace("package://", str(example_robot_data_share()) + "/")
    if "</robot>" not in text:
        raise ValueError(f"not a URDF robot description: {src}")
    text = text.replace("</robot>", assets.tool_link_urdf(task, spec.end_link) + "</robot>")
    out = folder / "robot_with_tool.urdf"
    out.write_text(text)
    return out


X_ANSWER_S = 5.0  # s: an X server answers its connection set-up in milliseconds, over ssh in well under this
_DISPLAY = re.compile(r"(?:(?P<proto>[A-Za-z]+)/)?(?P<host>[^:/]*):(?P<n>\d+)(?:\.\d+)?")


def no_display(timeout: float | None = None) -> str:
    """Why the PyBullet GUI cannot open here, or ``""``: on Linux, ``DISPLAY`` unset, or an X
    server there that cannot be connected to or does not answer its set-up within ``timeout``
    seconds (default ``X_ANSWER_S``). PyBullet itself exits the process on the first ("cannot
    connect to X server", status 1) and waits for ever on the second. A ``DISPLAY`` of another
    form is left to PyBullet. The probe's outcome is kept per display for this process (the
    command line and then ``World`` ask)."""
    if not sys.platform.startswith("linux"):
        return ""
    display = os.environ.get("DISPLAY")
    if not display:
        return "the PyBullet GUI needs a display (DISPLAY is not set)"
    return _x_problem(display, X_ANSWER_S if timeout is None else timeout)


@functools.lru_cache(maxsize=8)
def _x_problem(display: str, timeout: float) -> str:
    """``no_display``'s probe of the X server of ``display``."""
    m = _DISPLAY.fullmatch(display)
    if m is None:
        return ""
    n, host = int(m["n"]), m["host"]
    if m["proto"] not in (None, "tcp", "inet", "unix", "local") or n > 59535:
        return ""
    if m["proto"] in ("unix", "local") or (m["proto"] is None and host in ("", "unix")):
        family = socket.AF_UNIX
        where = [f"\0/tmp/.X11-unix/X{n}", f"/tmp/.X11-unix/X{n}"]  # the abstract socket, then the file
    else:
        family, where = socket.AF_INET, [(host, 6000 + n)]
    why = ""
    for address in where:  # the first that takes the connection decides, as in Xlib
        why = _x_answers(family, address, timeout)
        if not why.startswith("cannot be reached"):
            break
    return why and f"the X server of DISPLAY={display} {why}"


def _x_answers(family: int, address, timeout: float) -> str:
    """Send the X11 connection set-up (no authorization) and wait for any sign of a server: a
    reply (Failed, Success or Authenticate), or the connection closed (ssh's X forwarding closes
    one without the cookie, which PyBullet sends); ``""``, or what went wrong: no connection, or
    nothing at all within ``timeout`` seconds (a hung server)."""
    with socket.socket(family, socket.SOCK_STREAM) as sock:
        sock.settimeout(timeout)
        try:
            sock.connect(address)
        except OSError as e:
            return f"cannot be reached ({e.strerror or e})"
        try:
            sock.sendall(b"l\0" + struct.pack("<HHHH", 11, 0, 0, 0) + b"\0\0")
            sock.recv(1)
        except TimeoutError:
            return f"does not answer (nothing in {timeout:g} s)"
        except OSError:  # reset: something is there and refused this set-up
            pass
    return ""


class World:
    """The PyBullet scene of one task.

    Parameters
    ----------
    task : "powder" (spoon) or "pour" (pitcher).
    gui : open the PyBullet GUI instead of DIRECT.
    scenario : optional mapping object name -> position ``(x, y)`` on the table, ``(x, y, z)``
        of the body's base, or a ``(4, 4)`` pose; these objects are placed (added if absent).
    n_particles, particle_radius : particles spawned in the tool at ``HOME_Q``
        (defaults from ``layout.PARTICLES``; 0 particles is allowed).
    robot : the arm description (Baxter's left arm).
    """

    def __init__(self, task: str = "powder", gui: bool = False, scenario=None, n_particles: int | None = None,
                 particle_radius: float | None = None, robot: RobotSpec = BAXTER_LEFT):
        if task not in TASKS:
            raise ValueError(f"task must be one of {TASKS}, got {task!r}")
        self.task = task
        self.spec = robot
        n_def, r_def = L.PARTICLES[task]
        n_particles = n_def if n_particles is None else int(n_particles)
        particle_radius = r_def if particle_radius is None else float(particle_radius)
        self._close_callbacks = []
        self.client = None
        why = no_display() if gui else ""
        if why:
            raise RuntimeError(why)
        self.client = p.connect(p.GUI if gui else p.DIRECT)
        if self.client < 0:
            self.client = None
            raise RuntimeError("cannot connect to PyBullet" + (" GUI (is there a display?)" if gui else ""))
        try:
            self._build(n_particles, particle_radius, scenario)
        except BaseException:  # (Ctrl-C too) no half-built client is left connected
            self.close()
            raise

    # --- construction -------------------------------------------------------------------
    def _build(self, n_particles, particle_radius, scenario):
        c = self.client
        p.setGravity(0, 0, L.GRAVITY, physicsClientId=c)
        p.setTimeStep(L.SIM_DT, physicsClientId=c)
        p.configureDebugVisualizer(p.COV_ENABLE_GUI, 0, physicsClientId=c)
        with tempfile.TemporaryDirectory() as tmp:
            urdf = patched_urdf(self.spec, self.task, Path(tmp))
            with quiet_stdio():  # PyBullet reports links without inertia on stdout
                self.robot = p.loadURDF(str(urdf), (0, 0, 0), (0, 0, 0, 1), useFixedBase=True,
                                        flags=p.URDF_USE_INERTIA_FROM_FILE, physicsClientId=c)
        self.joint_index, self.link_index = {}, {"base": -1}
        for j in range(p.getNumJoints(self.robot, physicsClientId=c)):
            info = p.getJointInfo(self.robot, j, physicsClientId=c)
            self.joint_index[info[1].decode()] = j
            self.link_index[info[12].decode()] = j
        missing = [n for n in self.spec.joint_names if n not in self.joint_index]
        if missing or self.spec.end_link not in self.link_index:
            raise ValueError(f"robot {self.spec.name!r}: joints {missing} / end link {self.spec.end_link!r} not in URDF")
        self.arm_joints = tuple(self.joint_index[n] for n in self.spec.joint_names)  # (7,)
        self.ee_link = self.link_index[self.spec.end_link]
        self.tool_link = self.link_index["tool"]
        for name, v in {**L.RIGHT_ARM_TUCK, "head_pan": L.HEAD_PAN}.items():
            if name in self.joint_index:
                p.resetJointState(self.robot, self.joint_index[name], v, physicsClientId=c)
        for name in ("l_gripper_l_finger_joint", "l_gripper_r_finger_joint"):
            if name in self.joint_index:
                # the fingers slide in mirrored directions: the right one's range is [-0.021, 0]
                lo, hi = p.getJointInfo(self.robot, self.joint_index[name], physicsClientId=c)[8:10]
                opening = L.GRIPPER_FINGERS if hi > 0 else -L.GRIPPER_FINGERS
                p.resetJointState(self.robot, self.joint_index[name], float(np.clip(opening, lo, hi)),
                                  physicsClientId=c)
        self._hold_all_joints()
        self.floor = assets.build_floor(c)
        self.table = assets.build_table(c)
        self.objects: dict[str, int] = {}
        self.scene_version = 0  # bumped whenever an object is placed, moved or removed
        self.place_object("bowl", L.BOWL_DEFAULT_XY)
        self.place_object("source", L.SOURCE_DEFAULT_XY)
        for name in LANDMARKS[self.task][1:]:
            self.place_object(name, L.DEFAULT_XY[name])
        for name, where in dict(scenario or {}).items():
            self.place_object(name, where)
        self.set_q(L.HOME_Q)
        self.particles = ParticleSet((), particle_radius, self.task)
        self.respawn_particles(n_particles, particle_radius)

    def _hold_all_joints(self):
        """Position-control every movable joint at its current value (the arm stays put under physics)."""
        c = self.client
        for j in range(p.getNumJoints(self.robot, physicsClientId=c)):
            if p.getJointInfo(self.robot, j, physicsClientId=c)[2] in (p.JOINT_REVOLUTE, p.JOINT_PRISMATIC):
                pos = p.getJointState(self.robot, j, physicsClientId=c)[0]
                p.setJointMotorControl2(self.robot, j, p.POSITION_CONTROL, targetPosition=pos, force=500,
                                        physicsClientId=c)

    # --- lifecycle ----------------------------------------------------------------------
    def on_close(self, callback) -> None:
        """Call ``callback()`` when this world is closed (e.g. to release a collision client)."""
        self._close_callbacks.append(callback)

    def close(self) -> None:
        while self._close_callbacks:
            self._close_callbacks.pop()()
        if self.client is not None and p.isConnected(self.client):
            p.disconnect(self.client)
        self.client = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    # --- the arm ------------------------------------------------------------------------
    def _check_q(self, q) -> np.ndarray:
        q = np.asarray(q, dtype=float)
        if q.shape != (len(self.arm_joints),):
            raise ValueError(f"q must have shape ({len(self.arm_joints)},) for joints "
                             f"{list(self.spec.joint_names)}, got shape {q.shape}")
        return q

    def set_q(self, q) -> None:
        """Teleport the arm to ``q (7,)`` (zero velocity) and hold it there; the tool follows."""
        q = self._check_q(q)
        p.resetJointStatesMultiDof(self.robot, self.arm_joints, [[float(v)] for v in q],
                                   targetVelocities=[[0.0]] * len(q), physicsClientId=self.client)
        self.command_q(q)

    def get_q(self) -> np.ndarray:
        """Current arm configuration ``(7,)``."""
        states = p.getJointStates(self.robot, self.arm_joints, physicsClientId=self.client)
        return np.array([s[0] for s in states])

    def command_q(self, q, force: float = 200.0, qdot=None) -> None:
        """Position-control targets ``q (7,)`` for the arm, reached by ``step``; ``qdot (7,)``, the
        planned joint velocities, is fed forward so the arm does not trail a moving target."""
        q = self._check_q(q)
        kw = {} if qdot is None else {"targetVelocities": self._check_q(qdot).tolist()}
        p.setJointMotorControlArray(self.robot, self.arm_joints, p.POSITION_CONTROL, targetPositions=q.tolist(),
                                    forces=[force] * len(q), physicsClientId=self.client, **kw)

    def step(self, n: int = 1) -> None:
        """Advance physics ``n`` steps of ``layout.SIM_DT``."""
        for _ in range(int(n)):
            p.stepSimulation(physicsClientId=self.client)

    def link_pose(self, link: str | int) -> np.ndarray:
        """``T_world_link (4, 4)`` of a robot link (by name or index), link frame (URDF)."""
        idx = self.link_index[link] if isinstance(link, str) else int(link)
        if idx == -1:
            return pose_to_matrix(*p.getBasePositionAndOrientation(self.robot, physicsClientId=self.client))
        s = p.getLinkState(self.robot, idx, computeForwardKinematics=True, physicsClientId=self.client)
        return pose_to_matrix(s[4], s[5])

    def T_world_gripper(self) -> np.ndarray:
        return self.link_pose(self.ee_link)

    def T_world_tool(self) -> np.ndarray:
        """The tool frame (identical to the gripper frame; the tool geometry is given in it)."""
        return self.link_pose(self.tool_link)

    # --- scene objects ------------------------------------------------------------------
    def place_object(self, name: str, where) -> int:
        """Add (or move) object ``name`` to ``where``: ``(x, y)`` on the table, ``(x, y, z)`` base
        position or ``T_world_object (4, 4)``. Returns the body id."""
        if name not in assets.BUILDERS:
            raise ValueError(f"unknown object {name!r}; known: {', '.join(assets.BUILDERS)}")
        if name not in self.objects:
            self.objects[name] = assets.BUILDERS[name][0](self.client)
        self.move_object(name, where)
        return self.objects[name]

    def move_object(self, name: str, where) -> None:
        """Move a placed object (see ``place_object`` for ``where``)."""
        if name not in self.objects:
            raise ValueError(f"object {name!r} is not in the scene; placed: {sorted(self.objects)}")
        w = np.asarray(where, dtype=float)
        quat = (0, 0, 0, 1)
        if w.shape == (2,):
            z = L.TABLE_TOP_Z
            if name == "lamp_shade":
                z += L.LAMP_BOTTOM_ABOVE_TABLE
            elif name.startswith("marker_"):
                z += L.MARKER_HEIGHT_ABOVE_TABLE
            pos = (w[0], w[1], z)
        elif w.shape == (3,):
            pos = tuple(w)
        elif w.shape == (4, 4):
            pos = tuple(w[:3, 3])
            from scipy.spatial.transform import Rotation
            quat = tuple(Rotation.from_matrix(w[:3, :3]).as_quat())
        else:
            raise ValueError(f"where must be (x, y), (x, y, z) or a (4, 4) pose, got shape {w.shape}")
        p.resetBasePositionAndOrientation(self.objects[name], [float(v) for v in pos], quat,
                                          physicsClientId=self.client)
        self.scene_version += 1

    def remove_object(self, name: str) -> None:
        if name not in self.objects:
            raise ValueError(f"object {name!r} is not in the scene; placed: {sorted(self.objects)}")
        p.removeBody(self.objects.pop(name), physicsClientId=self.client)
        self.scene_version += 1

    def object_kind(self, name: str) -> str:
        """"table", "container", "obstacle", "item" or "marker"."""
        return "table" if name == "table" else assets.BUILDERS[name][1]

    def object_pose(self, name: str) -> np.ndarray:
        """``T_world_object (4, 4)`` of the body's base frame (bottom centre)."""
        body = self.table if name == "table" else self.objects.get(name)
        if body is None:
            raise ValueError(f"object {name!r} is not in the scene; placed: {sorted(self.objects)}")
        return pose_to_matrix(*p.getBasePositionAndOrientation(body, physicsClientId=self.client))

    def sensed_landmarks(self) -> tuple[tuple[str, ...], np.ndarray]:
        """``(names (Z,), T_world_landmark (Z, 4, 4))``: blob centroids, world orientation."""
        names = LANDMARKS[self.task]
        poses = np.tile(np.eye(4), (len(names), 1, 1))
        for k, n in enumerate(names):
            if n not in self.objects:
                raise ValueError(f"landmark object {n!r} was removed from the scene")
            poses[k, :3, 3] = self.object_pose(n)[:3, 3] + (0, 0, _CENTROID_Z.get(n, 0.0))
        return names, poses

    # --- particles ----------------------------------------------------------------------
    def respawn_particles(self, n: int | None = None, radius: float | None = None) -> ParticleSet:
        """Replace the particles by ``n`` new ones resting in the tool at its current pose."""
        n = len(self.particles) if n is None else int(n)
        radius = self.particles.radius if radius is None else float(radius)
        remove_particles(self.client, self.particles)
        self.particles = spawn_particles(self.client, self.task, self.T_world_tool(), n, radius)
        return self.particles

    def particle_positions(self) -> np.ndarray:
        """``(N, 3)`` world positions of the particle centres."""
        return particle_positions(self.client, self.particles)

    def fraction_in_bowl(self, particles: ParticleSet | None = None) -> float:
        pts = particle_positions(self.client, self.particles if particles is None else particles)
        return float(in_bowl_mask(pts, self.object_pose("bowl")).mean()) if len(pts) else 0.0

    def fraction_in_tool(self, particles: ParticleSet | None = None) -> float:
        pts = particle_positions(self.client, self.particles if particles is None else particles)
        return float(in_tool_mask(pts, self.T_world_tool(), self.task).mean()) if len(pts) else 0.0

    def fraction_spilled(self, particles: ParticleSet | None = None) -> float:
        """Neither in the bowl nor in the tool."""
        pts = particle_positions(self.client, self.particles if particles is None else particles)
        if not len(pts):
            return 0.0
        kept = in_bowl_mask(pts, self.object_pose("bowl")) | in_tool_mask(pts, self.T_world_tool(), self.task)
        return float((~kept).mean())

    # --- rendering ----------------------------------------------------------------------
    def render(self, width: int = 960, height: int = 720) -> np.ndarray:
        """An RGB image ``(H, W, 3) uint8`` from ``layout.CAMERA`` with the TinyRenderer."""
        cam = L.CAMERA
        view = p.computeViewMatrixFromYawPitchRoll(cam["target"], cam["distance"], cam["yaw"], cam["pitch"], 0, 2,
                                                   physicsClientId=self.client)
        proj = p.computeProjectionMatrixFOV(50, width / height, 0.05, 10.0, physicsClientId=self.client)
        img = p.getCameraImage(width, height, view, proj, renderer=p.ER_TINY_RENDERER, physicsClientId=self.client)
        return np.reshape(np.asarray(img[2], dtype=np.uint8), (height, width, 4))[:, :, :3]

    def snapshot(self, path: str | Path, width: int = 960, height: int = 720) -> Path:
        """Render to a PNG file at ``path``."""
        import imageio.v2 as imageio
        path = Path(path)
        imageio.imwrite(path, self.render(width, height))
        return path


def main(argv=None) -> int:
    from lfd.cli import ArgumentParser, UsageError, png_file

    ap = ArgumentParser(prog="python -m sim.world", description="Show or render the simulated lab.")
    ap.add_argument("--task", default="powder", help="powder (spoon) or pour (pitcher)")
    ap.add_argument("--gui", action="store_true", help="open the PyBullet GUI")
    ap.add_argument("--snapshot", metavar="FILE.png", help="render headless to this PNG")
    ap.add_argument("--steps", type=int, default=120, help="physics steps before rendering")
    ap.add_argument("--obstacles", action="store_true",
                    help="place the four obstacles (paper towels, lamp shade, vase, books) at their default places")
    args = ap.parse_args(argv)
    if args.task not in TASKS:
        raise UsageError(f"--task must be one of {', '.join(TASKS)}, got {args.task!r}")
    if args.steps < 0:
        raise UsageError(f"--steps must be >= 0, got {args.steps}")
    if args.snapshot:
        png_file(args.snapshot, "--snapshot")
    why = no_display() if args.gui else ""
    if why:
        raise UsageError(f"--gui: {why}; use --snapshot")
    try:
        scenario = {n: L.DEFAULT_XY[n] for n in ("paper_towels", "lamp_shade", "vase", "books")} if args.obstacles else None
        world = World(args.task, gui=args.gui, scenario=scenario)
    except (ValueError, FileNotFoundError, RuntimeError) as e:
        raise UsageError(str(e)) from e
    with world:
        world.step(args.steps)
        if args.snapshot:
            try:
                world.snapshot(args.snapshot)
            except OSError as e:
                raise UsageError(f"cannot write {args.snapshot}: {e.strerror or e}") from e
            print(args.snapshot)
        if args.gui:
            import time
            print("close the window or press Ctrl-C to quit")
            try:
                while p.isConnected(world.client):
                    world.step()
                    time.sleep(L.SIM_DT)
            except (KeyboardInterrupt, p.error):
                pass
    return 0


if __name__ == "__main__":
    from lfd.cli import run_main
    run_main(main, prog="python -m sim.world")
