"""The README's "Using lfd from Python" example runs as written (with its model folder pointed at a
small saved model) and plans without importing the simulator."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import torch

from lfd.learning.model import TaskModel
from lfd.robot.robots import BAXTER_LEFT
from lfd.learning.tasks import POWDER

ROOT = Path(__file__).resolve().parent.parent


def _readme_example() -> str:
    text = (ROOT / "README.md").read_text()
    section = text.split("## Using lfd from Python", 1)[1].split("\n## ", 1)[0]
    blocks = re.findall(r"```python\n(.*?)```", section, flags=re.S)
    assert len(blocks) == 1, "the section should hold one Python example"
    return blocks[0]


def _small_model(out: Path) -> Path:
    """A 4-step model whose steps ask for the home posture region (saved as train.py saves)."""
    T, d = 4, 7
    mu = torch.zeros(T, d + 3, dtype=torch.float64)
    mu[:, :d] = torch.tensor([0.0, -0.55, 0.0, 0.75, 0.0, 1.26, 0.0], dtype=torch.float64)
    mu[:, d:] = torch.tensor([0.0, 0.0, 0.3], dtype=torch.float64)  # tool point 0.3 m above the bowl
    sigma_inv = torch.diag(torch.tensor([2.0] * d + [10.0] * 3, dtype=torch.float64)).repeat(T, 1, 1)
    log_trans = torch.log(torch.tensor([[0.5, 0.4, 0.1]] * T, dtype=torch.float64))
    model = TaskModel(torch.tensor([0.0, 0.0, 0.1], dtype=torch.float64), torch.ones(1, dtype=torch.float64),
                      mu, sigma_inv, log_trans, ["bowl"], BAXTER_LEFT, task=POWDER, covariance="block")
    model.save(out)
    return out


def test_readme_python_example_plans_without_the_simulator(tmp_path):
    code = _readme_example()
    load = 'TaskModel.load("runs/powder/models/learn-learn")'  # where `make demo` writes the model
    assert load in code and "import sim" not in code and "from sim" not in code
    model_dir = _small_model(tmp_path / "model")
    code = code.replace(load, f"TaskModel.load({str(model_dir)!r})")
    code = code.replace("n_vertices=500", "n_vertices=120")  # the same calls, a smaller roadmap
    check = ("\nimport sys\n"
             "assert not any(m == 'sim' or m.startswith('sim.') for m in sys.modules), 'sim imported'\n"
             "assert 'pybullet' not in sys.modules, 'pybullet imported'\n"
             "assert result.status == 'ok', result.message\n"
             "assert result.configurations.shape[1] == 7 and result.time_steps[-1] == model.time_steps - 1\n")
    r = subprocess.run([sys.executable, "-c", "import numpy as np\nnp.random.seed(0)\n" + code + check],
                       cwd=tmp_path, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    assert r.stdout.startswith("ok "), r.stdout
