"""TaskModel: Eq. 2/3 kernels against references, gradients, save/load."""

import json
import math

import numpy as np
import pytest
import torch

from lfd.learning.model import (ModelFormatError, TaskModel, reaches_last_step, features_tensor, landmarks_inverse_tensor,
                       logdet_tensor, step_nll_tensor, virtual_inverse_tensor)
from lfd.robot.robots import BAXTER_LEFT
from lfd.learning.synthetic import random_rotation
from lfd.learning.tasks import POWDER


def _random_sigma_inv(T, F, gen, dtype):
    A = torch.randn(T, F, F, generator=gen, dtype=torch.float64)
    Sigma = A @ A.transpose(1, 2) + 0.5 * torch.eye(F, dtype=torch.float64)
    L = torch.linalg.cholesky(Sigma)
    return Sigma.to(dtype), torch.linalg.inv(L).to(dtype)


def _poses(n, rng):
    T = np.tile(np.eye(4), (n, 1, 1))
    for i in range(n):
        T[i, :3, :3] = random_rotation(rng)
        T[i, :3, 3] = rng.normal(size=3)
    return torch.as_tensor(T)


@pytest.mark.parametrize("dtype,tol", [(torch.float64, 1e-9), (torch.float32, 2e-3)])
def test_step_nll_is_twice_gaussian_nll_minus_constant(dtype, tol):
    gen = torch.Generator().manual_seed(0)
    T, F, N = 5, 10, 7
    Sigma, sigma_inv = _random_sigma_inv(T, F, gen, dtype)
    mu = torch.randn(T, F, generator=gen, dtype=torch.float64).to(dtype)
    f = torch.randn(N, F, generator=gen, dtype=torch.float64).to(dtype)
    got = step_nll_tensor(f, mu, sigma_inv)
    ref = torch.stack([torch.distributions.MultivariateNormal(mu[t].double(), Sigma[t].double())
                       .log_prob(f.double()) for t in range(T)], dim=1)
    expected = -2 * ref - F * math.log(2 * math.pi)
    assert got.shape == (N, T)
    assert torch.allclose(got.double(), expected, rtol=tol, atol=tol * 10)
    assert torch.allclose(logdet_tensor(sigma_inv).double(), torch.logdet(Sigma.double()), atol=tol * 10)


def test_logdet_scale_scales_only_the_logdet_term():
    gen = torch.Generator().manual_seed(1)
    _, sigma_inv = _random_sigma_inv(3, 10, gen, torch.float64)
    mu = torch.randn(3, 10, generator=gen, dtype=torch.float64)
    f = torch.randn(4, 10, generator=gen, dtype=torch.float64)
    a, b = step_nll_tensor(f, mu, sigma_inv, 1.0), step_nll_tensor(f, mu, sigma_inv, 0.5)
    assert torch.allclose(a - b, 0.5 * logdet_tensor(sigma_inv)[None].expand(4, 3))


def test_features_match_the_paper_definition():
    rng = np.random.default_rng(0)
    lm = _poses(3, rng)  # (Z, 4, 4)
    T_ee = _poses(4, rng)
    q = torch.randn(4, 7, dtype=torch.float64)
    tool = torch.tensor([0.1, -0.2, 0.3], dtype=torch.float64)
    env = torch.tensor([0.7, 0.5, -0.2], dtype=torch.float64)
    K_inv = virtual_inverse_tensor(env, landmarks_inverse_tensor(lm)[None])[0]
    f = features_tensor(q, T_ee, tool, K_inv)
    ref_K = sum(env[i] * torch.linalg.inv(lm[i]) for i in range(3))
    for n in range(4):
        x = ref_K @ T_ee[n] @ torch.cat([tool, torch.ones(1, dtype=torch.float64)])
        assert torch.allclose(f[n, 7:], x[:3], atol=1e-12)
        assert torch.equal(f[n, :7], q[n])


def test_attitude_features_are_the_gripper_axes_in_the_virtual_frame():
    """'attitude': Eq. 2's features, then ``K_virt^-1`` applied to the gripper's x and y axes as
    directions (no translation), x first."""
    rng = np.random.default_rng(1)
    lm, T_ee = _poses(2, rng), _poses(4, rng)
    q = torch.randn(4, 7, dtype=torch.float64)
    tool = torch.tensor([0.1, -0.2, 0.3], dtype=torch.float64)
    env = torch.tensor([0.6, 0.4], dtype=torch.float64)
    K_inv = virtual_inverse_tensor(env, landmarks_inverse_tensor(lm)[None])[0]
    f = features_tensor(q, T_ee, tool, K_inv, "attitude")
    assert f.shape == (4, 16)
    assert torch.equal(f[:, :10], features_tensor(q, T_ee, tool, K_inv))
    ref_K = sum(env[i] * torch.linalg.inv(lm[i]) for i in range(2))
    for n in range(4):
        for k in range(2):
            axis = torch.cat([T_ee[n, :3, k], torch.zeros(1, dtype=torch.float64)])
            assert torch.allclose(f[n, 10 + 3 * k:13 + 3 * k], (ref_K @ axis)[:3], atol=1e-12)


def test_features_gradients_match_finite_differences():
    rng = np.random.default_rng(2)
    lm_inv = landmarks_inverse_tensor(_poses(3, rng))[None].expand(5, 3, 4, 4)
    T_ee = _poses(5, rng)
    q = torch.randn(5, 7, dtype=torch.float64)

    def fn(tool, env):
        return features_tensor(q, T_ee, tool, virtual_inverse_tensor(env, lm_inv))

    tool = torch.randn(3, dtype=torch.float64, requires_grad=True)
    env = torch.randn(3, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(fn, (tool, env))
    gen = torch.Generator().manual_seed(3)
    _, si = _random_sigma_inv(4, 10, gen, torch.float64)
    si = si.requires_grad_(True)
    mu = torch.randn(4, 10, dtype=torch.float64, requires_grad=True)
    f = torch.randn(6, 10, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(step_nll_tensor, (f, mu, si))


def _model(Z=2, T=4):
    gen = torch.Generator().manual_seed(5)
    _, si = _random_sigma_inv(T, 10, gen, torch.float64)
    lt = torch.log(torch.full((T, 3), 1 / 3, dtype=torch.float64))
    env = torch.full((Z,), 1.0 / Z, dtype=torch.float64)
    return TaskModel(torch.tensor([0.0, 0.0, 0.2], dtype=torch.float64), env,
                     torch.randn(T, 10, generator=gen, dtype=torch.float64), si, lt,
                     landmark_names=("bowl", "cup")[:Z], robot=BAXTER_LEFT, task=POWDER,
                     all_landmark_names=("bowl", "cup", "vase"), covariance="block")


def test_step_nll_computes_fk_when_no_pose_given():
    m = _model()
    q = torch.zeros(3, 7, dtype=torch.float64)
    lm = torch.eye(4, dtype=torch.float64).expand(2, 4, 4)
    a = m.step_nll(q, None, lm)
    b = m.step_nll(q, m.kin.fk(q), lm)
    assert a.shape == (3, 4)
    assert torch.allclose(a, b)
    with pytest.raises(ValueError, match=r"landmarks must have shape \(2, 4, 4\)"):
        m.step_nll(q, None, lm[:1])
    with pytest.raises(ValueError, match=r"landmarks are needed: the poses \(2, 4, 4\)"):
        m.step_nll(q)
    picked = m.select_landmarks(["vase", "cup", "bowl"], torch.stack([2 * torch.eye(4, dtype=torch.float64),
                                                                      3 * torch.eye(4, dtype=torch.float64),
                                                                      torch.eye(4, dtype=torch.float64)]))
    assert picked[0, 0, 0] == 1 and picked[1, 0, 0] == 3


def test_save_load_round_trip(tmp_path):
    m = _model()
    m.save(tmp_path)
    state = torch.load(tmp_path / "model.pt", weights_only=True)
    assert set(state) == {"tool", "env", "mu", "sigma_inv", "log_trans"}
    back = TaskModel.load(tmp_path)
    for k in ("tool", "env", "mu", "sigma_inv", "log_trans"):
        assert torch.equal(getattr(back, k), getattr(m, k))
    assert back.landmark_names == ("bowl", "cup")
    assert back.all_landmark_names == ("bowl", "cup", "vase")
    assert back.task == POWDER and back.robot == BAXTER_LEFT and back.covariance == "block"
    q = torch.zeros(2, 7, dtype=torch.float64)
    lm = torch.eye(4, dtype=torch.float64).expand(2, 4, 4)
    assert torch.allclose(back.step_nll(q, None, lm), m.step_nll(q, None, lm))
    f32 = TaskModel.load(tmp_path, dtype=torch.float32)
    assert f32.mu.dtype == torch.float32 and back.feature_set == "paper"


def test_attitude_model_round_trip_and_shape_check(tmp_path):
    """An 'attitude' model (F = d + 9) saves and loads as one; the paper's shape is refused for it."""
    m = _model()
    gen = torch.Generator().manual_seed(6)
    _, si = _random_sigma_inv(4, 16, gen, torch.float64)
    mu = torch.randn(4, 16, generator=gen, dtype=torch.float64)
    att = TaskModel(m.tool, m.env, mu, si, m.log_trans, m.landmark_names, BAXTER_LEFT, feature_set="attitude")
    assert (att.dof, att.n_task_features) == (7, 9)
    att.save(tmp_path)
    back = TaskModel.load(tmp_path)
    assert back.feature_set == "attitude" and torch.equal(back.mu, mu)
    q = torch.randn(3, 7, generator=gen, dtype=torch.float64)
    lm = torch.eye(4, dtype=torch.float64).expand(2, 4, 4)
    assert torch.allclose(back.step_nll(q, None, lm), att.step_nll(q, None, lm))
    with pytest.raises(ValueError, match=r"mu must have shape \(4, 10\)"):
        TaskModel(m.tool, m.env, mu, si, m.log_trans, m.landmark_names, BAXTER_LEFT)


def test_load_rejects_foreign_files(tmp_path):
    with pytest.raises(ModelFormatError, match="missing config.json"):
        TaskModel.load(tmp_path)
    (tmp_path / "config.json").write_text(json.dumps({"format": "something-else"}))
    torch.save({"a": torch.zeros(1)}, tmp_path / "model.pt")
    with pytest.raises(ModelFormatError, match="not an lfd task model config"):
        TaskModel.load(tmp_path)
    _model().save(tmp_path)
    (tmp_path / "model.pt").write_bytes(b"not a zip file")
    with pytest.raises(ModelFormatError, match="cannot be read"):
        TaskModel.load(tmp_path)


def test_load_refuses_a_config_of_another_model(tmp_path):
    """A config.json copied beside another model's model.pt: its time steps disagree."""
    m = _model()
    m.save(tmp_path)
    assert TaskModel.load(tmp_path).time_steps == m.time_steps
    cfg = json.loads((tmp_path / "config.json").read_text())
    cfg["time_steps"] = m.time_steps + 3
    (tmp_path / "config.json").write_text(json.dumps(cfg))
    with pytest.raises(ModelFormatError, match=rf"different models \(time_steps {m.time_steps + 3} in "
                                               rf"config.json, {m.time_steps} in model.pt\)"):
        TaskModel.load(tmp_path)


def test_reaches_last_step_follows_the_permitted_transitions():
    lt = np.log(np.tile([0.5, 0.4, 0.1], (6, 1)))  # offsets 0, 1, 2
    lt[-1] = [0.0, -np.inf, -np.inf]
    offsets = (0, 1, 2)
    assert reaches_last_step(lt, offsets, [2], 0)              # 1 -> 3 skips step 2
    assert not reaches_last_step(lt, offsets, [2, 3], 0)       # two in a row: no offset of 3
    assert reaches_last_step(lt, offsets, [2, 3], 4)           # already past them
    assert reaches_last_step(lt, offsets, [0], 0)              # the robot is at step 0 already
    no_skip = lt.copy()
    no_skip[:, 2] = -np.inf
    assert not reaches_last_step(no_skip, offsets, [2], 0)
    assert not reaches_last_step(lt, offsets, [5], 0)          # the last step itself


def test_a_model_whose_transitions_never_reach_the_last_step_is_refused():
    T, F = 4, len(BAXTER_LEFT.joint_names) + 3
    args = (torch.zeros(3), torch.ones(1), torch.zeros(T, F), torch.eye(F).repeat(T, 1, 1))
    stay = torch.log(torch.tensor([[1.0, 0.0, 0.0]] * T))  # offsets 0, 1, 2: only staying permitted
    with pytest.raises(ValueError, match="no sequence of time steps from the first to the last"):
        TaskModel(*args, stay, ["bowl"], BAXTER_LEFT)
    ends = stay.clone()
    ends[:-1, 1] = 0.0  # every step but the last may move on (the last may only stay)
    assert TaskModel(*args, ends, ["bowl"], BAXTER_LEFT).time_steps == T


def test_the_kinematic_model_follows_the_models_dtype_and_must_be_its_robots(tmp_path):
    """The README's ``model.kin = KinematicModel.from_spec(model.robot)`` (float64) on a model
    loaded as float32 failed inside the step cost; it is converted. Another robot's kinematics
    were taken and planned with; refused. A dtype given as a string was reported as a damaged
    model folder."""
    from lfd.robot.kinematics import KinematicModel
    from lfd.robot.robots import PANDA

    _model().save(tmp_path)
    f32 = TaskModel.load(tmp_path, dtype=torch.float32)
    f32.kin = KinematicModel.from_spec(f32.robot)
    assert f32.kin.dtype == torch.float32
    lm = torch.eye(4, dtype=torch.float32).expand(2, 4, 4)
    assert f32.step_nll(torch.zeros(2, 7, dtype=torch.float32), None, lm).dtype == torch.float32
    with pytest.raises(ValueError, match=r"the kinematic model's joints \['panda_joint1'.*are not those of the "
                                         r"model's robot 'baxter_left'"):
        f32.kin = KinematicModel.from_spec(PANDA)
    with pytest.raises(ValueError, match="are not those of the model's robot"):  # the caller's, not the files' fault
        TaskModel.load(tmp_path, kin=KinematicModel.from_spec(PANDA))
    with pytest.raises(TypeError, match="dtype must be torch.float64 or torch.float32, got 'float32'"):
        TaskModel.load(tmp_path, dtype="float32")
    for half in (torch.float16, torch.bfloat16):  # torch's inverse raised, or the folder was called inconsistent
        with pytest.raises(TypeError, match=f"dtype must be torch.float64 or torch.float32, got {half}"):
            TaskModel.load(tmp_path, dtype=half)
        with pytest.raises(TypeError, match="dtype must be torch.float64 or torch.float32"):
            f32.to(half)
    with pytest.raises(ValueError, match="device must be a torch device .* got 'gpu'"):
        TaskModel.load(tmp_path, device="gpu")


def test_a_device_this_machine_lacks_is_refused_where_it_is_given(tmp_path):
    """``cuda`` without a GPU (``mps`` without Apple's) raised torch's "Torch not compiled with
    CUDA enabled" from deep inside the first tensor's move; now a ValueError names the device
    where it is given: ``usable_device``, ``KinematicModel``, ``TaskModel.load`` and ``.to``."""
    from lfd.robot.device import usable_device
    from lfd.robot.kinematics import KinematicModel
    assert usable_device("cpu") == torch.device("cpu")
    missing = [d for d, ok in (("cuda", torch.cuda.is_available()), ("mps", torch.backends.mps.is_available()))
               if not ok]
    for bad, why in [*((d, "is_available\\(\\) is False") for d in missing), ("meta", "holds no data"),
                     ("gpu", "must be a torch device")]:
        with pytest.raises(ValueError, match=why):
            usable_device(bad)
        with pytest.raises(ValueError, match=why):
            KinematicModel.from_spec(device=bad)
    if torch.cuda.is_available():
        with pytest.raises(ValueError, match="CUDA device"):
            usable_device(f"cuda:{torch.cuda.device_count()}")
    if missing:
        model = _model()
        model.save(tmp_path)
        with pytest.raises(ValueError, match="is_available"):
            TaskModel.load(tmp_path, device=missing[0])
        with pytest.raises(ValueError, match="is_available"):
            model.to(device=missing[0])
