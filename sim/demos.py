"""The kinesthetic demonstrator: synthetic human-like demonstrations of the two tasks (Sec. VI).

The bowls are placed at random in the 30-inch square of ``sim.layout``: uniformly, one
independent draw per demonstration (``placement="uniform"``, the powder's default), or as a Latin
hypercube over the whole set (``"stratified"``, the pour's default: each of the ``n`` equal strips
of the square in x, and each in y, holds exactly one bowl, so that 11 demonstrations cannot by
chance leave out the bowls near the robot, where the demonstrator turns the tool up to 45 degrees
to the right; of several such sets, the one the demonstrator faces from the most varied
directions, so that the set tells which point of the tool is held over the bowl;
``DEFAULT_PLACEMENT``, ``bowl_positions``). Per demonstration, 4 distractor landmarks at random in the square
(powder: markers up to 0.3 m above the table; pour: scissors, spoon, vase, paper towels
lifted up to 10 inches), each drawn again while the demonstrated motion would hit it (a person
does not demonstrate through a vase); a hidden task point on the tool (``sim.demo_paths.TASK_POINTS`` or ``task_point``) follows a random path relative
to the bowl (``sim.demo_paths.draw_path``); the arm follows it by IK (``lfd.robot.ik``) seeded from
the previous sample, with a per-demonstration null-space posture. A demonstration is kept
only if every sample is within the joint limits, no joint exceeds its URDF velocity over one
sampling interval, no configuration collides (self, table, containers, distractors), and its
replay under physics (position control, particles in the tool) ends with >= 90 % of the
particles in the bowl and no contact of the arm or tool with anything but particles; otherwise
a new path (posture, timing, distractors) is drawn for the *same* bowl position, so that the
bowls keep their placement over the whole square.

Command line: ``python -m sim.demos --task powder|pour [--n 11] [--seed S]
[--placement uniform|stratified] [--task-point X Y Z] --out DIR`` (``--placement`` defaults to
the task's ``DEFAULT_PLACEMENT``).
"""

from __future__ import annotations

import json
import os
import shutil
import sys
import time
import uuid
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from lfd.cli import ArgumentParser, UsageError, check_seed, path_arg, png_file, run_main, writable_dir
from lfd.learning.demos import save_demonstration
from lfd.learning.demoset import Demonstration
from lfd.learning.tasks import task_from_name
from lfd.robot.ik import IKConfig, solve_ik
from lfd.robot.kinematics import KinematicModel
from lfd.robot.robots import BAXTER_LEFT
from sim import layout as L
from sim.attitude import tilts_of
from sim.bullet import p
from sim.demo_paths import DUMP_NOMINAL, TASK_POINTS, DemoPath, check_roll, draw_path, facing

__all__ = [
    "DEFAULT_PLACEMENT",
    "MIN_IN_BOWL",
    "PLACEMENTS",
    "DemoAttempt",
    "bowl_positions",
    "generate",
    "main",
    "replay",
    "track_path",
]

MIN_IN_BOWL = 0.9
MAX_ATTEMPTS_PER_DEMO = 40
PATH_IK = IKConfig(max_iters=40, min_iters=1, pos_tol=2e-4, rot_tol=2e-3, max_step=0.2)
LIFT_MAX = 0.254  # 10 inches
DISTRACTOR_TRIES = 30
PLACEMENTS = ("uniform", "stratified")
# Each task's default bowl placement. The pour's 11 uniform bowls of seed 0 left the strip of the
# square nearest the robot empty (no bowl at x < 0.56 m); learned from them, the pour succeeded at
# 30 of the 32 bowls of base seed 0 farther than 0.58 m from the shoulder but 6 of the 18 nearer
# ones (README, "Results against the paper").
# The powder's uniform set meets its target and stays as it was measured.
DEFAULT_PLACEMENT = {"powder": "uniform", "pour": "stratified"}
# Latin hypercubes drawn for a stratified set, of which the one with the most varied facing is
# kept: single Latin hypercubes of 11 bowls face them with a spread of 13-25 degrees (seeds 0-7),
# the best of 16 with 28-35 degrees
STRATIFIED_CANDIDATES = 16


def bowl_positions(n: int, rng: np.random.Generator, placement: str = "uniform") -> np.ndarray:
    """``n`` bowl positions (n, 2), metres in the world xy plane, inside the 30-inch square.

    ``"uniform"``: independent uniform draws. ``"stratified"``: a Latin hypercube (each of the
    ``n`` equal strips in x, and each in y, holds exactly one point, in a random order), the one
    of ``STRATIFIED_CANDIDATES`` drawn whose bowls the demonstrator faces from the most varied
    directions (the largest standard deviation of ``sim.demo_paths.facing``): only demonstrations
    that face the bowl from different directions tell a point on the tool that stays over the
    bowl from one that is carried round it (docs/EXPERIMENTS.md, *The facing spread decides
    which point the pour learns*).
    """
    if placement not in PLACEMENTS:
        raise ValueError(f"placement must be one of {PLACEMENTS}, got {placement!r}")
    n, c, h = int(n), np.asarray(L.SQUARE_CENTER_XY), L.SQUARE_HALF
    if placement == "uniform":  # this exact expression: a seed gives the bowls it always gave
        return c + rng.uniform(-h, h, (n, 2))  # (n, 2)
    best, best_spread = None, -1.0
    for _ in range(STRATIFIED_CANDIDATES):
        u = np.stack([(rng.permutation(n) + rng.uniform(0.0, 1.0, n)) / n for _ in range(2)], axis=1)  # (n, 2) in [0, 1)
        bowls = c + (2.0 * u - 1.0) * h  # (n, 2)
        spread = float(np.std([facing(b) for b in bowls]))
        if spread > best_spread:
            best, best_spread = bowls, spread
    return best


@dataclass(frozen=True)
class DemoAttempt:
    """One drawn demonstration: joint trajectory, its path, the scene and why it failed (or "")."""

    q: np.ndarray                 # (S, 7)
    path: DemoPath
    placements: dict              # object name -> (x, y, z) base position
    failure: str = ""
    in_bowl: float = float("nan")


def _start_pose(kin: KinematicModel, tool_point: np.ndarray) -> np.ndarray:
    """The task point's position and the yaw at ``HOME_Q`` (tool level over the source): (4,)."""
    T = kin.fk(torch.as_tensor(L.HOME_Q, dtype=kin.dtype)).numpy()
    pos = T[:3, 3] + T[:3, :3] @ tool_point
    return np.r_[pos, np.arctan2(T[1, 2], T[0, 2])]


def track_path(kin: KinematicModel, path: DemoPath, tool_point: np.ndarray, q_rest: np.ndarray,
               dt: float) -> tuple[np.ndarray | None, str]:
    """Joint trajectory ``(S, 7)`` following ``path`` with continuity, or ``(None, reason)``.

    The first sample starts from ``HOME_Q`` and settles towards ``q_rest`` in the null space;
    each later sample is seeded with the previous solution (never re-seeded).
    """
    T = torch.as_tensor(path.T_world_tool, dtype=kin.dtype)
    tp = torch.as_tensor(tool_point, dtype=kin.dtype)
    rest = torch.as_tensor(q_rest, dtype=kin.dtype)
    first = solve_ik(kin, T[0], torch.as_tensor(L.HOME_Q, dtype=kin.dtype), p_ee_tool=tp, q_rest=rest,
                     config=IKConfig(max_iters=300, min_iters=150, nullspace_gain=0.1))
    if not bool(first.success[0]):
        return None, f"no IK at the start (error {float(first.pos_err[0]):.3f} m)"
    cfg = IKConfig(**{**PATH_IK.__dict__, "nullspace_gain": min(0.3, 2.0 * dt)})
    qs = [first.q[0]]
    for i in range(1, len(T)):
        r = solve_ik(kin, T[i], qs[-1], p_ee_tool=tp, q_rest=rest, config=cfg)
        if not bool(r.success[0]):
            return None, (f"IK lost the path at t={path.t[i]:.2f}s (error {float(r.pos_err[0]) * 100:.1f} cm, "
                          f"{float(r.rot_err[0]):.3f} rad)")
        fast = (r.q[0] - qs[-1]).abs() > 0.9 * kin.velocity * dt  # margin for the joint noise
        if bool(fast.any()):  # stop early: this path would be rejected anyway
            j = int(torch.argmax((r.q[0] - qs[-1]).abs() / kin.velocity))
            return None, f"joint {kin.joint_names[j]} too fast at t={path.t[i]:.2f}s"
        qs.append(r.q[0])
    return torch.stack(qs).numpy(), ""


def _smooth_noise(rng, n: int, d: int, sigma: float, width: int) -> np.ndarray:
    """Low-pass Gaussian noise ``(n, d)`` with standard deviation about ``sigma``."""
    raw = rng.normal(0.0, 1.0, (n + 2 * width, d))
    k = np.hanning(2 * width + 1)
    k /= np.sqrt((k ** 2).sum())
    out = np.stack([np.convolve(raw[:, j], k, mode="valid") for j in range(d)], axis=1)[:n]
    return sigma * out


def check_motion(kin: KinematicModel, q: np.ndarray, dt: float) -> str:
    """"" when ``q (S, 7)`` is within the joint limits and under the velocity limits, else why not."""
    lo, hi, vel = kin.lower.numpy(), kin.upper.numpy(), kin.velocity.numpy()
    if np.any(q < lo) or np.any(q > hi):
        j = int(np.argmax(((q < lo) | (q > hi)).any(axis=0)))
        return f"joint {kin.joint_names[j]} outside its limits"
    step = np.abs(np.diff(q, axis=0)).max(axis=0)  # (7,)
    if np.any(step > vel * dt):
        j = int(np.argmax(step / (vel * dt)))
        return f"joint {kin.joint_names[j]} too fast ({step[j] / dt:.2f} > {vel[j]:.2f} rad/s)"
    return ""


def _place_scene(world, task: str, bowl_xy, rng, Q: np.ndarray, collides) -> tuple[dict, str]:
    """Place the bowl, then draw the 4 distractors one at a time out of the arm's way.

    Each distractor is drawn uniformly in the square (lifted at random) and drawn again, up to
    ``DISTRACTOR_TRIES`` times, while ``collides(Q)`` reports a collision of the configurations
    ``Q (S, 7)`` with it (the others are parked below the floor meanwhile): a person does not
    demonstrate through a vase. Returns name -> base position and "" or why it failed.
    """
    from sim.world import LANDMARKS
    c, h = np.asarray(L.SQUARE_CENTER_XY), L.SQUARE_HALF
    placements = {"bowl": (float(bowl_xy[0]), float(bowl_xy[1]), L.TABLE_TOP_Z)}
    world.place_object("bowl", placements["bowl"])
    others = LANDMARKS[task][1:]
    for k, name in enumerate(others):  # park the distractors out of the scene
        world.place_object(name, (0.0, 0.0, L.FLOOR_Z - 2.0 - k))
    if np.any(collides(Q)):
        return placements, "collision with the bowl or the source container"
    for name in others:
        for _ in range(DISTRACTOR_TRIES):
            xy = c + rng.uniform(-h, h, 2)
            lift = rng.uniform(0.0, 0.3) if task == "powder" else rng.uniform(0.0, LIFT_MAX)
            placements[name] = (float(xy[0]), float(xy[1]), L.TABLE_TOP_Z + lift)
            world.place_object(name, placements[name])
            if not np.any(collides(Q)):
                break
        else:
            return placements, f"no place for the {name} out of the arm's way"
    return placements, ""


def _contacts(world, particle_ids: set) -> list[str]:
    names = []
    for cp in p.getContactPoints(bodyA=world.robot, physicsClientId=world.client):
        other = cp[2]
        if other in (world.robot, world.floor) or other in particle_ids:  # the pedestal stands on the floor
            continue
        names.append(next((n for n, b in world.objects.items() if b == other),
                          "table" if other == world.table else f"body {other}"))
    return names


def replay(world, q: np.ndarray, dt: float, settle: float = 0.3, hold: float = 0.6) -> tuple[float, list[str]]:
    """Replay ``q (S, 7)`` under physics with fresh particles in the tool.

    The arm is teleported to ``q[0]``, particles are spawned and settle for ``settle`` seconds,
    then position targets interpolated along the trajectory are commanded every physics step,
    and the final configuration is held for ``hold`` seconds. Returns the fraction of particles
    in the bowl and the names of the bodies the arm or tool touched (particles excluded).
    """
    world.set_q(q[0])
    world.respawn_particles()
    pid = set(world.particles.ids)
    world.step(int(settle / L.SIM_DT))
    n_steps = int(round((len(q) - 1) * dt / L.SIM_DT))
    s = np.arange(1, n_steps + 1) * L.SIM_DT / dt  # (n,) fractional sample index
    i0 = np.minimum(np.floor(s).astype(int), len(q) - 2)
    f = (s - i0)[:, None]
    targets = (1 - f) * q[i0] + f * q[i0 + 1]  # (n, 7)
    hits = []
    for k, qk in enumerate(targets):
        world.command_q(qk)
        world.step(1)
        if k % 6 == 0:
            hits += _contacts(world, pid)
    world.command_q(q[-1])
    world.step(int(hold / L.SIM_DT))
    hits += _contacts(world, pid)
    return world.fraction_in_bowl(), sorted(set(hits))


AIM_POINT = "aim over the bowl"  # ground_truth.json reference point: see _aim_point


def _aim_point(kin: KinematicModel, q: np.ndarray, bowl_xy) -> np.ndarray:
    """``(3,)`` the gripper-frame point that sat over the bowl's centre, at its rim's height, when the
    demonstration ``q (S, 7)`` tilted the tool most (``sim.attitude``): where the demonstrator aimed
    the powder or the stream, as the gripper carried it (the pour's stream leaves the spout ahead
    of it, so this is not the spout)."""
    T, tilt = tilts_of(kin, q)  # (S, 4, 4), (S,)
    i = int(np.argmax(tilt))
    p_world = np.array([bowl_xy[0], bowl_xy[1], L.TABLE_TOP_Z + L.BOWL_HEIGHT])
    return T[i, :3, :3].T @ (p_world - T[i, :3, 3])


def _draw_one(world, kin, fns, task, bowl_xy, tool_point, dt, rng, roll_deg=None) -> DemoAttempt:
    path = draw_path(task, bowl_xy, _start_pose(kin, tool_point), dt, rng, tool_point=tool_point,
                     roll_deg=roll_deg)
    lo, hi = kin.lower.numpy(), kin.upper.numpy()
    # redundancy resolved differently per demonstration
    q_rest = L.HOME_Q + rng.normal(0.0, 0.3, 7) + np.r_[0, 0, 0, -0.3, 0, 0, 0]
    q_rest = np.clip(q_rest, lo + 0.1, hi - 0.3)
    q, why = track_path(kin, path, tool_point, q_rest, dt)
    if q is None:
        return DemoAttempt(np.zeros((0, 7)), path, {}, why)
    q = q + _smooth_noise(rng, len(q), 7, 0.003, max(2, int(0.3 / dt)))  # small joint noise
    q = np.clip(q, lo, hi)
    why = check_motion(kin, q, dt)
    if why:
        return DemoAttempt(q, path, {}, why)
    stride = max(1, int(round(0.05 / dt)))
    Qc = np.concatenate([q[::stride], q[-1:]])
    world.place_object("bowl", (float(bowl_xy[0]), float(bowl_xy[1]), L.TABLE_TOP_Z))
    if np.any(fns["static"].batch_collision_fn(Qc)):
        return DemoAttempt(q, path, {}, "collision with the robot or the table")
    placements, why = _place_scene(world, task, bowl_xy, rng, Qc, fns["all"].batch_collision_fn)
    if why:
        return DemoAttempt(q, path, placements, why)
    in_bowl, hits = replay(world, q, dt)
    if hits:
        return DemoAttempt(q, path, placements, f"replay touched {', '.join(hits)}", in_bowl)
    if in_bowl < MIN_IN_BOWL:
        return DemoAttempt(q, path, placements, f"replay put {in_bowl:.0%} in the bowl", in_bowl)
    return DemoAttempt(q, path, placements, "", in_bowl)


def generate(task: str, out_dir, n: int = 11, seed: int = 0, task_point=None, progress: bool = True,
             keep_attempts: list | None = None, placement: str | None = None,
             roll_deg: float | None = None) -> list[Path]:
    """Generate ``n`` demonstrations of ``task`` into ``out_dir``; returns the ``.npz`` paths.

    Writes ``demo_000.npz`` ... (``lfd.learning.demos`` format), ``task.json`` and ``ground_truth.json``
    into a hidden folder beside ``out_dir`` and moves them into it when all are drawn, so that an
    interrupted or failed run leaves no partial set that would later pass for a whole one
    (``tool_point``, ``bowl_landmark``, ``task``, ``reference_points`` (the aim over the bowl, ``_aim_point``),
    the demonstrator's ``roll_deg``, plus the bowl positions and durations).
    ``task_point``: (3,) metres in the gripper frame, default ``TASK_POINTS[task]``.
    ``keep_attempts``: a list that receives the kept ``DemoAttempt`` objects (for tests/plots).
    ``placement``: how the bowls are spread over the square (``bowl_positions``); None: the
    task's ``DEFAULT_PLACEMENT``. ``roll_deg``: the demonstrator's nominal roll while dumping or
    pouring (``sim.demo_paths.draw_path``; None: the task's ``DUMP_NOMINAL``).

    Raises
    ------
    ValueError
        unknown task or placement, ``n < 1``, a task point that is not 3 finite numbers.
    RuntimeError
        when a demonstration cannot be drawn in ``MAX_ATTEMPTS_PER_DEMO`` attempts.
    """
    spec = task_from_name(task)
    placement = DEFAULT_PLACEMENT.get(task, "uniform") if placement is None else placement
    if int(n) < 1:
        raise ValueError(f"n must be at least 1, got {n}")
    tool_point = np.asarray(TASK_POINTS[task] if task_point is None else task_point, dtype=float)
    if tool_point.shape != (3,) or not np.all(np.isfinite(tool_point)):
        raise ValueError(f"task_point must be 3 finite numbers (metres, gripper frame), got {task_point!r}")
    if np.linalg.norm(tool_point) > 0.5:
        raise ValueError(f"task_point {tool_point.tolist()} is more than 0.5 m from the gripper")
    if placement not in PLACEMENTS:
        raise ValueError(f"placement must be one of {PLACEMENTS}, got {placement!r}")
    roll_deg = check_roll(roll_deg)
    out_dir = Path(out_dir)
    out_dir.parent.mkdir(parents=True, exist_ok=True)
    work = out_dir.parent / f".{out_dir.name}.partial-{os.getpid()}-{uuid.uuid4().hex[:8]}"
    work.mkdir()
    threads = torch.get_num_threads()
    try:
        torch.set_num_threads(1)
        t_all = time.time()
        names = _generate_into(work, task, spec, int(n), seed, tool_point, progress, keep_attempts, placement,
                               roll_deg)
        paths = _publish(work, out_dir, names)
        if progress:
            print(f"{n} {task} demonstrations in {out_dir} ({time.time() - t_all:.0f} s)", flush=True)
        return paths
    finally:
        torch.set_num_threads(threads)
        shutil.rmtree(work, ignore_errors=True)


def _publish(work: Path, out_dir: Path, names: list[str]) -> list[Path]:
    """Move the finished set from ``work`` into ``out_dir``: one rename when ``out_dir`` is new or
    empty, else file by file with ``task.json`` and ``ground_truth.json`` last."""
    if out_dir.is_dir() and not any(out_dir.iterdir()):
        out_dir.rmdir()
    if not out_dir.exists():
        work.rename(out_dir)
    else:
        for name in [*names, "task.json", "ground_truth.json"]:
            os.replace(work / name, out_dir / name)
    return [out_dir / name for name in names]


def _generate_into(out_dir: Path, task: str, spec, n: int, seed: int, tool_point: np.ndarray, progress: bool,
                   keep_attempts: list | None, placement: str, roll_deg: float | None) -> list[str]:
    """``generate``'s drawing and writing into ``out_dir``; returns the demonstrations' file names."""
    from sim.collision import make_collision_fns
    from sim.world import World

    rng = np.random.default_rng(seed)
    # each bowl is kept through its attempts: redrawing one after a failure would bias the bowl
    # positions towards the easy part of the square. A stratified set is drawn up front; uniform
    # bowls are drawn one per demonstration, as before the option existed, so that a seed still
    # gives the same uniform demonstrations
    all_bowls = bowl_positions(n, rng, placement) if placement == "stratified" else None  # (n, 2)
    kin = KinematicModel.from_spec(BAXTER_LEFT, dtype=torch.float64)
    paths, bowls, durations, attempts_used, aims = [], [], [], [], []
    with World(task) as world:
        fns = {"static": make_collision_fns(world, obstacles=False),
               "all": make_collision_fns(world, obstacles=True)}
        for i in range(n):
            t0 = time.time()
            bowl_xy = all_bowls[i] if all_bowls is not None else bowl_positions(1, rng, "uniform")[0]
            for attempt in range(1, MAX_ATTEMPTS_PER_DEMO + 1):
                a = _draw_one(world, kin, fns, task, bowl_xy, tool_point, spec.dt, rng, roll_deg)
                if not a.failure:
                    break
                if progress:
                    print(f"  demo {i + 1}/{n}: attempt {attempt} rejected: {a.failure}", flush=True)
            else:
                raise RuntimeError(f"could not draw demonstration {i + 1} (bowl at ({bowl_xy[0]:.2f}, {bowl_xy[1]:.2f})) in "
                                   f"{MAX_ATTEMPTS_PER_DEMO} attempts "
                                   f"(last: {a.failure})")
            names, poses = world.sensed_landmarks()
            demo = Demonstration(q=a.q, dt=spec.dt, landmarks=poses, name=f"demo_{i:03d}")
            paths.append(save_demonstration(out_dir / f"demo_{i:03d}.npz", demo, BAXTER_LEFT.joint_names,
                                            names, BAXTER_LEFT).name)
            bowls.append([float(v) for v in a.path.bowl_xy])
            aims.append(_aim_point(kin, a.q, a.path.bowl_xy))
            durations.append(a.path.duration)
            attempts_used.append(attempt)
            if keep_attempts is not None:
                keep_attempts.append(a)
            if progress:
                print(f"demo {i + 1}/{n}: {a.path.duration:.1f} s, {len(a.q)} samples, bowl at "
                      f"({a.path.bowl_xy[0]:.2f}, {a.path.bowl_xy[1]:.2f}), {a.in_bowl:.0%} in the bowl, "
                      f"attempt {attempt}, {time.time() - t0:.1f} s", flush=True)
    spec.save(out_dir / "task.json")
    truth = {"tool_point": tool_point.tolist(), "bowl_landmark": "bowl", "task": task,
             "bowl_xy": bowls, "durations": durations, "attempts": attempts_used, "seed": int(seed),
             "placement": placement,
             "roll_deg": DUMP_NOMINAL[task][1] if roll_deg is None else roll_deg,
             "reference_points": {AIM_POINT: np.mean(aims, axis=0).round(5).tolist()}}
    (out_dir / "ground_truth.json").write_text(json.dumps(truth, indent=2) + "\n")
    return paths


def main(argv=None) -> int:
    ap = ArgumentParser(prog="python -m sim.demos", description="Generate simulated kinesthetic demonstrations.")
    ap.add_argument("--task", required=True, help="powder or pour")
    ap.add_argument("--n", type=int, default=11, help="number of demonstrations (default 11)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--placement", choices=PLACEMENTS, default=None,
                    help="bowl positions over the square: independent uniform draws or a Latin hypercube "
                         "(the most varied facing of 16) "
                         f"(default: the task's, {DEFAULT_PLACEMENT})")
    ap.add_argument("--task-point", type=float, nargs=3, metavar=("X", "Y", "Z"),
                    help="hidden tool point, metres in the gripper frame (default: the task's)")
    ap.add_argument("--roll", type=float, default=None, metavar="DEG",
                    help="the demonstrator's nominal roll while dumping or pouring, degrees, each "
                         "demonstration within a few degrees of it (default: the task's, "
                         f"{ {k: v[1] for k, v in DUMP_NOMINAL.items()} })")
    ap.add_argument("--out", type=path_arg, required=True, help="output folder")
    ap.add_argument("--plot", metavar="FILE.png", help="also draw the paths relative to the bowl")
    ap.add_argument("--quiet", action="store_true", help="no progress output")
    args = ap.parse_args(argv)
    if args.task not in TASK_POINTS:
        raise UsageError(f"--task must be powder or pour, got {args.task!r}")
    if args.n < 1:
        raise UsageError(f"--n must be at least 1, got {args.n}")
    check_seed(args.seed)  # was a numpy traceback after the folder was made
    if args.task_point is not None and (not np.all(np.isfinite(args.task_point))
                                        or np.linalg.norm(args.task_point) > 0.5):
        raise UsageError(f"--task-point must be 3 finite numbers within 0.5 m of the gripper, got {args.task_point}")
    try:
        check_roll(args.roll)
    except ValueError as e:
        raise UsageError(f"--roll: {e}") from None
    if args.plot is not None:  # checked before the minutes of drawing, not when the figure is saved
        png_file(args.plot, "--plot")
    from lfd.learning.demos import demo_files
    if demo_files(args.out):  # the new set would mix with the old one, its ground truth with neither
        raise UsageError(f"--out {args.out} already holds demonstrations; give an empty or new folder")
    out = writable_dir(args.out)
    kept = []
    try:
        generate(args.task, out, n=args.n, seed=args.seed, task_point=args.task_point, progress=not args.quiet,
                 keep_attempts=kept, placement=args.placement, roll_deg=args.roll)
    except RuntimeError as e:  # not bad input: the demonstrator could not do the task here
        print(f"python -m sim.demos: {e}", file=sys.stderr)
        return 1
    if args.plot:
        from sim.demo_plot import plot_demos
        plot_demos(kept, args.task_point or TASK_POINTS[args.task], args.plot, f"{args.task}: {args.n} demonstrations")
    return 0


if __name__ == "__main__":
    run_main(main, prog="python -m sim.demos")
