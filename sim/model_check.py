"""Can a learned model plan in the simulated scenarios? Checked before any simulation starts.

A model plans only where every landmark it kept is sensed, with the arm it was learned on. A
model trained on another landmark set (another task's demonstrations, your own objects) or for
another robot would otherwise build a roadmap and report ``missing_landmark`` (or fail inside
the simulator); ``plan.py`` and ``benchmarks/soak.py`` ask here first, so it is one line on stderr
and exit status 2 (``lfd.cli.UsageError``) naming what is missing and what the scenarios provide.
"""

from __future__ import annotations

import inspect
from pathlib import Path

from lfd.cli import UsageError
from lfd.learning.model import TaskModel
from lfd.robot.robots import RobotSpec, resolve_urdf

__all__ = ["MODEL_FILES", "check_models_for_task", "is_trained", "load_checked_model", "model_mismatch",
           "scenario_provides"]


def scenario_provides(task: str) -> tuple[tuple[str, ...], RobotSpec]:
    """``(landmark names, robot)`` of the simulated ``task``: what ``World(task)`` senses and loads."""
    from sim.world import LANDMARKS, World
    return tuple(LANDMARKS[task]), inspect.signature(World).parameters["robot"].default


def model_mismatch(model: TaskModel, task: str) -> str | None:
    """Why ``model`` cannot plan in the ``task`` scenarios (``None`` when it can)."""
    from sim.world import TASKS
    if task not in TASKS:
        return f"a model of task {task!r}; the simulator has scenarios of {', '.join(TASKS)} only"
    names, robot = scenario_provides(task)
    mine = model.robot
    if (mine.end_link, tuple(mine.joint_names)) != (robot.end_link, tuple(robot.joint_names)):
        return (f"learned for robot {mine.name!r} (end link {mine.end_link!r}, joints {list(mine.joint_names)}); "
                f"the {task} scenarios simulate {robot.name!r} (end link {robot.end_link!r}, joints "
                f"{list(robot.joint_names)})")
    missing = [n for n in model.landmark_names if n not in names]
    if missing:
        return (f"the model needs landmark(s) {missing}, which the {task} scenarios do not sense; "
                f"they provide {list(names)} (was it trained on other demonstrations' landmarks?)")
    return None


def load_checked_model(model_dir: str | Path, task: str | None = None,
                       what: str = "--model") -> tuple[TaskModel, str]:
    """Load the model in ``model_dir`` and check it fits the scenarios of ``task`` (default: the
    model's own task; a model that names none is refused); ``(model, task)``.

    Raises ``UsageError`` (or ``lfd.learning.model.ModelFormatError``) with a message that starts
    ``"{what} {model_dir}: "``.
    """
    model_dir = Path(model_dir)
    if not model_dir.exists():  # named as such, not by the config.json it lacks
        raise UsageError(f"{what} {model_dir}: no such folder")
    if not (model_dir / "config.json").is_file():
        raise UsageError(f"{what} {model_dir}: no config.json (train one with train.py)")
    model = TaskModel.load(model_dir)
    if model.task is None:  # it was planned as powder at 0.1 s per step, whatever it had learned
        raise UsageError(f"{what} {model_dir}: the model names no task (its demonstrations had no task.json), "
                         f"so neither its scenes nor its time step are known; add a task.json to the "
                         f"demonstrations (lfd.learning.tasks.TaskSpec: name, dt, ...) and train again")
    try:
        resolve_urdf(model.robot.urdf)
    except FileNotFoundError as e:
        raise UsageError(f"{what} {model_dir}: its config.json names the robot description "
                         f"{model.robot.urdf!r}, which is not on this machine ({e})") from e
    own = model.task.name
    if task is not None and own != task:
        raise UsageError(f"{what} {model_dir}: a model of task {own!r}, not {task!r}")
    task = own
    why = model_mismatch(model, task)
    if why:
        raise UsageError(f"{what} {model_dir}: {why}")
    return model, task


MODEL_FILES = ("model.pt", "config.json")  # what TaskModel.save writes and load reads


def is_trained(model_dir: Path) -> bool:
    """Whether ``model_dir`` holds a trained model (``MODEL_FILES``); an evaluation trains the
    variants whose folders do not."""
    return all((Path(model_dir) / name).is_file() for name in MODEL_FILES)


def check_models_for_task(model_dirs, task: str, what: str = "--models") -> list[int | None]:
    """Check every already trained model among ``model_dirs`` (``is_trained``) against the ``task`` scenarios;
    the other folders are left to be trained. Returns each folder's number of time steps, ``None``
    for a folder still to be trained."""
    steps: list[int | None] = []
    for d in map(Path, model_dirs):
        steps.append(load_checked_model(d, task, what=what)[0].time_steps if is_trained(d) else None)
    return steps
