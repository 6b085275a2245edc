"""``lfd-import`` (``python -m lfd.io.import_csv``): recorded demonstrations (CSV files, ROS 1 and ROS 2
bags, MCAP files) into a demonstration set.

    lfd-import RECORDINGS --out DIR --task NAME [--rate HZ] [--time-steps T] [--reference LANDMARK]
               [--robot NAME | --robot-json FILE] [--columns MAPPING.json] [--frame-pose X Y Z QX QY QZ QW]
               [--max-gap S] [--trim-pauses RAD] [--dropouts bridge|refuse] [--outliers drop|refuse]
               [--smooth SECONDS] [--no-plot]
               [--joint-topic TOPIC --landmark-frames A,B --base-frame F --landmark-topics NAME=TOPIC,...
                --split-on-pause S]        (bags: lfd.io.rosbag)

The CSV formats are ``lfd.io.recordings``'s, the bags ``lfd.io.rosbag``'s; both are cleaned and
resampled the same way (``lfd.io.recordings.import_raw``). The set is written into a new folder beside ``--out``
and checked by loading it (``lfd.learning.demos.load_demos``) before it takes ``--out``'s name,
so a refused recording leaves nothing half-written. ``--out`` must not exist yet. Beside the
set go ``import_report.json`` (what the cleaning did to each demonstration and landmark) and
``import.png`` (the same as a picture; needs matplotlib).
"""

from __future__ import annotations

import json
import math
import os
import shutil
import sys
import tempfile
from dataclasses import replace
from pathlib import Path

import numpy as np

from lfd.cli import ArgumentParser, UsageError, check_task_name, path_arg, run_main, writable_dir
from lfd.io.rosbag import add_bag_arguments, bag_options_given, is_bag_input, raws_from_args
from lfd.learning.tasks import MAX_DT

__all__ = ["PLOT", "PROG", "REPORT", "build_parser", "cli", "main", "report_lines"]

PROG = "lfd-import"
REPORT = "import_report.json"  # beside the set: what the cleaning did to each demonstration
PLOT = "import.png"
MAX_RATE = 1000.0  # Hz: resampled faster, a recording is only interpolated (and 1e7 Hz filled the memory)


def build_parser(prog: str = PROG) -> ArgumentParser:
    p = ArgumentParser(prog=prog, description="Turn recorded demonstrations (joint and landmark CSVs, one folder "
                                              "or file pair per demonstration, or ROS bags) into an lfd "
                                              "demonstration set.")
    p.add_argument("recordings", type=path_arg, metavar="RECORDINGS",
                   help="folder of DEMO/joints.csv + DEMO/landmarks.csv, or DEMO_joints.csv + DEMO_landmarks.csv; or a "
                        "ROS bag, an MCAP file, a ROS 2 bag folder, or a folder of those (one per demonstration)")
    p.add_argument("--out", type=path_arg, required=True, metavar="DIR", help="the demonstration set to write (new folder)")
    p.add_argument("--task", required=True, metavar="NAME", help="the task's name, written to task.json")
    p.add_argument("--rate", type=float, default=10.0, metavar="HZ", help="samples per second after resampling")
    p.add_argument("--time-steps", type=int, default=24, metavar="T", help="the task model's time steps (task.json)")
    p.add_argument("--reference", default=None, metavar="LANDMARK",
                   help="the landmark a person would name for the task (the 'manual' baseline; default: the "
                        "first landmark of the first recording)")
    robot = p.add_mutually_exclusive_group()
    robot.add_argument("--robot", default="baxter_left", metavar="NAME",
                       help="a built-in robot (lfd.robot.robots): baxter_left or panda")
    robot.add_argument("--robot-json", type=path_arg, default=None, metavar="FILE",
                       help="your robot: a JSON RobotSpec (name, urdf, end_link, joint_names)")
    p.add_argument("--columns", type=path_arg, default=None, metavar="MAPPING.json",
                   help='joint CSV columns other than time + URDF joint names: {"time": "t", "joints": '
                        '{"left_s0": "j0", ...}, "degrees": false} (default: none)')
    p.add_argument("--frame-pose", type=float, nargs=7, default=None, metavar=("X", "Y", "Z", "QX", "QY", "QZ", "QW"),
                   help="the landmark CSVs' frame in the robot's base frame (default: they are in the base frame)")
    p.add_argument("--max-gap", type=float, default=0.5, metavar="S",
                   help="longest time allowed between two readings, seconds")
    p.add_argument("--trim-pauses", type=float, default=0.0, metavar="RAD",
                   help="leave out the start (end) while every joint stays within RAD of where it starts (ends): "
                        "the pauses before and after the motion (default: 0, keep all)")
    p.add_argument("--dropouts", choices=("bridge", "refuse"), default="bridge",
                   help="missing readings (NaN, empty, all-zero poses, zero quaternions): bridge them like the "
                        "recorder's gaps, up to --max-gap (default), or refuse the recording")
    p.add_argument("--outliers", choices=("drop", "refuse"), default="drop",
                   help="a landmark reading farther from its neighbours than 5 m/s carries it: drop it and report "
                        "it (default), or refuse the recording")
    p.add_argument("--smooth", type=float, default=0.0, metavar="SECONDS",
                   help="smooth tracked landmarks with a Savitzky-Golay filter over this window (default: 0, not "
                        "smoothed; the report gives each landmark's jitter)")
    p.add_argument("--no-plot", action="store_true",
                   help="do not draw import.png (what was done to each demonstration) beside the set")
    add_bag_arguments(p)  # RECORDINGS may be ROS bags (lfd.io.rosbag; the [ros] extra)
    return p


def _robot(args):
    import json

    from lfd.robot.robots import RobotSpec, robot_from_name
    try:
        if args.robot_json is not None:
            spec = RobotSpec.from_dict(json.loads(args.robot_json.read_text()))
            if not spec.urdf.startswith("example-robot-data:"):  # stored in every .npz: absolute, not
                spec = replace(spec, urdf=str(Path(spec.urdf).expanduser().resolve()))  # the cwd's
            return spec
        return robot_from_name(args.robot)
    except (OSError, ValueError, RecursionError) as e:  # (JSON nested too deep: RecursionError)
        raise UsageError(f"--robot{'-json' if args.robot_json else ''}: {e}") from e


def _frame(pose) -> np.ndarray | None:
    if pose is None:
        return None
    from scipy.spatial.transform import Rotation
    q = np.asarray(pose[3:])
    if not np.all(np.isfinite(pose)):
        raise UsageError(f"--frame-pose needs 7 finite numbers, got {list(pose)}")
    if abs(np.linalg.norm(q) - 1) > 1e-3:
        raise UsageError(f"--frame-pose: the quaternion {q.tolist()} is not unit")
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = Rotation.from_quat(q).as_matrix(), pose[:3]
    return T


def main(argv=None, prog: str = PROG) -> int:
    """Import the recordings; 0 on success. ``UsageError`` / ``RecordingError`` on bad input."""
    from lfd.io.recordings import ImportSettings, JointColumns, import_raw, import_recordings
    from lfd.learning.demos import load_demos, save_demos
    from lfd.learning.tasks import TaskSpec

    args = build_parser(prog).parse_args(argv)
    check_task_name(args.task)
    if args.out.exists():
        raise UsageError(f"--out {args.out}: exists already; choose a new folder")
    if not (math.isfinite(args.max_gap) and args.max_gap > 0) or not (math.isfinite(args.trim_pauses)
                                                                      and args.trim_pauses >= 0):
        raise UsageError(f"--max-gap must be positive and --trim-pauses at least 0, got {args.max_gap}, "
                         f"{args.trim_pauses}")
    if not (math.isfinite(args.smooth) and args.smooth >= 0):
        raise UsageError(f"--smooth must be a window of 0 seconds or more, got {args.smooth}")
    if not (1.0 / MAX_DT <= args.rate <= MAX_RATE) or args.time_steps < 2:
        raise UsageError(f"--rate must be within [{1.0 / MAX_DT:g}, {MAX_RATE:g}] Hz and --time-steps at least 2, "
                         f"got {args.rate}, {args.time_steps}")
    robot = _robot(args)
    if is_bag_input(args.recordings):  # ROS bags: read into RawRecordings, then cleaned as the CSVs are
        notes: list[str] = []
        raws = raws_from_args(args.recordings, args, robot, notes=notes)
        for note in notes:
            print(f"note: {note}")
        settings = ImportSettings(rate=args.rate, max_gap=args.max_gap, trim=args.trim_pauses, dropouts=args.dropouts,
                                  outliers=args.outliers, smooth=args.smooth)
        ds, report = import_raw(raws, robot, settings, str(args.recordings))
    else:
        given = bag_options_given(args)
        if given:
            raise UsageError(f"{', '.join(given)}: for ROS bags, and {args.recordings} holds CSV recordings")
        columns = JointColumns.load(args.columns) if args.columns else None
        ds, report = import_recordings(args.recordings, robot, args.rate, columns=columns,
                                       T_base_frame=_frame(args.frame_pose), max_gap=args.max_gap,
                                       trim=args.trim_pauses, dropouts=args.dropouts, outliers=args.outliers,
                                       smooth=args.smooth)
    short = [(r["name"], r["samples"]) for r in report if r["samples"] < args.time_steps]
    if short:
        raise UsageError(f"{args.recordings}: demonstration(s) {short} have fewer samples at {args.rate:g} Hz than "
                         f"--time-steps {args.time_steps}: record longer, raise --rate or lower --time-steps")
    reference = args.reference or ds.landmark_names[0]
    if reference not in ds.landmark_names:
        raise UsageError(f"--reference {reference}: not among the recorded landmarks {list(ds.landmark_names)}")
    try:
        task = TaskSpec(name=args.task, dt=1.0 / args.rate, time_steps=args.time_steps, reference_landmark=reference)
    except ValueError as e:
        raise UsageError(f"--task: {e}") from e
    ds = replace(ds, task=task)
    writable_dir(args.out.parent)
    tmp = Path(tempfile.mkdtemp(prefix=f".{args.out.name}-", dir=args.out.parent))
    umask = os.umask(0)
    os.umask(umask)
    tmp.chmod(0o777 & ~umask)  # mkdtemp's folder is private; the set gets a folder's usual mode
    try:
        files = [p.name for p in save_demos(tmp, ds)]
        load_demos(tmp)  # every check of the format, before the set takes its name
        for r, file in zip(report, files):
            r["file"] = file
        (tmp / REPORT).write_text(json.dumps({"settings": _settings_record(args), "demonstrations": report},
                                             indent=1) + "\n")
        tmp.rename(args.out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    for line in report_lines(report, args.rate):
        print(line)
    print(f"wrote {len(ds.demos)} demonstrations of {args.task!r} (landmarks {list(ds.landmark_names)}, "
          f"robot {robot.name}) to {args.out}; what was done to each: {args.out / REPORT}", file=sys.stdout)
    if not args.no_plot:
        _plot(ds, report, args.out / PLOT)
    return 0


def _settings_record(args) -> dict:
    return {"rate": args.rate, "max_gap": args.max_gap, "trim_pauses": args.trim_pauses, "dropouts": args.dropouts,
            "outliers": args.outliers, "smooth": args.smooth, "frame_pose": args.frame_pose}


def report_lines(report: list[dict], rate: float) -> list[str]:
    """The console's account of an import: a line per demonstration, then a line per landmark
    (and the joints) over all demonstrations, saying what the cleaning did."""
    lines = []
    for r in report:  # (later messages name the file, not the recording)
        trimmed = f", trimmed {r['trimmed_start_s']:g} s + {r['trimmed_end_s']:g} s" \
            if r["trimmed_start_s"] or r["trimmed_end_s"] else ""
        lines.append(f"{r['name']} -> {r['file']}: {r['raw_samples']} {r.get('unit', 'row')}s -> {r['samples']} samples at "
                     f"{rate:g} Hz{trimmed}; landmarks {r['landmarks']}")
    joints = [r["joints"] for r in report]
    if any(j["dropouts"] or j["merged"] for j in joints):
        lines.append(f"  joints: {sum(j['dropouts'] for j in joints)} missing readings bridged, "
                     f"{sum(j['merged'] for j in joints)} rows of a repeated time stamp merged; longest gap "
                     f"{max(j['longest_gap_s'] for j in joints):.3g} s")
    for name in report[0]["tracks"]:
        tr = [r["tracks"][name] for r in report]
        if all(x["rate_hz"] is None and x["readings"] == 1 for x in tr):
            lines.append(f"  {name}: read once per demonstration (held still)")
            continue
        rates = [x["rate_hz"] for x in tr if x["rate_hz"] is not None]
        jitter = [x["jitter_mm"] for x in tr if x["jitter_mm"] is not None]
        parts = [f"{sum(x['readings'] for x in tr)} readings"]
        if rates:
            parts.append(f"tracker {np.median(rates):.1f} Hz")
        parts.append(f"{sum(x['dropouts'] for x in tr)} dropouts bridged (longest gap "
                     f"{max(x['longest_gap_s'] for x in tr):.3g} s)")
        parts.append(f"{sum(x['repeated'] for x in tr)} repeated + {sum(x['merged'] for x in tr)} near-simultaneous "
                     "readings merged")
        out = [f"{r['name']} {x['outlier_where']}" for r, x in zip(report, (r["tracks"][name] for r in report))
               if x["outliers"]]
        parts.append(f"{sum(x['outliers'] for x in tr)} outliers dropped" + (f" ({'; '.join(out)})" if out else ""))
        if jitter:
            parts.append(f"jitter {np.median(jitter):.1f} mm RMS (median)")
        if any(x["smoothed_s"] for x in tr):
            parts.append(f"smoothed over {max(x['smoothed_s'] for x in tr):g} s")
        lines.append(f"  {name}: " + ", ".join(parts))
    return lines


def _plot(ds, report, path: Path) -> None:
    """``import.png`` beside the set; a note instead when matplotlib is not installed."""
    try:
        import matplotlib  # noqa: F401  (a [sim] extra; lfd-import runs without it)
    except ImportError:
        print(f"(no {path.name}: matplotlib is not installed; pip install matplotlib, or lfd-landmarks[sim])")
        return
    from lfd.plots import plot_import
    print(f"drew what was imported: {plot_import(ds, report, path)}")


def cli() -> None:
    """The ``lfd-import`` console script."""
    run_main(main, prog=PROG)


if __name__ == "__main__":
    cli()
