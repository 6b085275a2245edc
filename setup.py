"""Packaging of lfd (distribution name ``lfd-landmarks``; the import names are ``lfd`` and ``sim``).

``pip install .`` installs the library and what its Python example needs (torch,
pytorch-kinematics, numpy, scipy, networkx, and example-robot-data for the Baxter URDF);
``pip install ".[sim]"`` adds the simulator (PyBullet), TensorBoard, plots and videos. The
Makefile installs with ``-c constraints.txt``, the versions this project was last tested with.
"""

import re
from pathlib import Path

from setuptools import find_packages, setup

HERE = Path(__file__).resolve().parent


def read_version() -> str:
    """``lfd.__version__``, parsed from ``lfd/__init__.py`` (importing lfd would need torch)."""
    text = (HERE / "lfd" / "__init__.py").read_text(encoding="utf-8")
    match = re.search(r'^__version__\s*=\s*["\']([^"\']+)["\']', text, flags=re.MULTILINE)
    if match is None:
        raise RuntimeError("lfd/__init__.py has no __version__ = '...' line")
    return match.group(1)


# The commands, each a function of the packages (train.py and plan.py at the repository's root are
# thin wrappers of the same functions). lfd-plan needs the simulator: install the [sim] extra.
CONSOLE_SCRIPTS = [
    "lfd-train = lfd.train_cli:cli",
    "lfd-plan = sim.plan_cli:cli",
    "lfd-import = lfd.io.import_csv:cli",
]

setup(
    name="lfd-landmarks",
    version=read_version(),
    description="Learning manipulation tasks from demonstrations with learned virtual landmarks "
                "(Bowen & Alterovitz), with a PyBullet executor",
    packages=find_packages(include=["lfd", "lfd.*", "sim", "sim.*"]),
    package_data={"lfd": ["py.typed"]},
    python_requires=">=3.10",
    # torch is pinned in the Makefile (installed first, CPU build); any recent torch works here.
    install_requires=[
        "torch>=2.1",
        "pytorch-kinematics>=0.7",
        "numpy>=1.24",
        "scipy>=1.10",
        "networkx>=3.0",
        "example-robot-data>=4.0",  # the Baxter URDF and meshes (lfd.robot.robots.BAXTER_LEFT)
    ],
    extras_require={
        # The simulator, TensorBoard, plots and videos: what `make` installs.
        "sim": ["pybullet>=3.2.5", "tensorboard>=2.12", "matplotlib>=3.6", "imageio>=2.30", "tqdm>=4.60"],
        # ruff and mypy run in `make test` (their versions pinned in constraints.txt: their rules change);
        # pytest-xdist runs the suite on every core, filelock lets its workers share one fixture
        "test": ["pytest>=7", "pytest-xdist>=3", "filelock>=3", "hypothesis>=6", "psutil>=5", "ruff>=0.6",
                 "mypy>=1.10"],
        # evaluation sweeps as Ray tasks (lfd-plan --evaluate --executor ray)
        "ray": ["ray>=2.9"],
        # lfd-import reads ROS 1 bags, ROS 2 bags and MCAP files (lfd.io.rosbag; pure Python, no ROS install)
        "ros": ["rosbags>=0.10"],
    },
    entry_points={
        "console_scripts": CONSOLE_SCRIPTS,
        # how lfd-train makes demonstrations when it finds none, without lfd importing sim
        "lfd.demo_generators": ["sim = sim.demos:generate"],
    },
)
