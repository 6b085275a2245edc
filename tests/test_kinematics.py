"""lfd's batched FK against PyBullet, batching, gradients, and bad robot inputs."""

from __future__ import annotations

import re

import numpy as np
import pybullet as p
import pytest
import torch
from scipy.spatial.transform import Rotation

from lfd.robot.kinematics import KinematicModel, KinematicsError
from lfd.robot.robots import BAXTER_LEFT, RobotSpec, resolve_urdf, robot_from_name

N_CONFIGS = 200
# Measured worst case over the 200 configurations: float64 8e-8 m / 4.5e-7 rad, float32
# 2.1e-7 m / 4.5e-7 rad. The floor is PyBullet's own (single-precision-sized) rounding, not
# lfd's dtype, so float32 needs no looser tolerance than float64: both are held to 1e-5.
TOL = {torch.float64: (1e-5, 1e-5), torch.float32: (1e-5, 1e-5)}


@pytest.fixture(scope="module")
def world(make_world):
    return make_world("powder", n_particles=0)


@pytest.fixture(scope="module")
def kin64():
    return KinematicModel.from_spec(BAXTER_LEFT, dtype=torch.float64)


def pybullet_T_world_gripper(world, q: np.ndarray) -> np.ndarray:
    """PyBullet's ``left_gripper`` link frame (worldLinkFramePosition/Orientation) at ``q``."""
    world.set_q(q)
    s = p.getLinkState(world.robot, world.ee_link, computeForwardKinematics=True, physicsClientId=world.client)
    T = np.eye(4)
    T[:3, :3] = np.array(p.getMatrixFromQuaternion(s[5])).reshape(3, 3)
    T[:3, 3] = s[4]
    return T


@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
def test_fk_matches_pybullet(world, kin64, dtype):
    kin = KinematicModel.from_spec(BAXTER_LEFT, dtype=dtype)
    gen = torch.Generator().manual_seed(0)
    Q = kin64.sample_uniform(N_CONFIGS, generator=gen)  # (N, 7) float64
    T_lfd = kin.fk(Q.to(dtype)).double().numpy()        # (N, 4, 4)
    q_saved = world.get_q()
    try:
        T_pb = np.stack([pybullet_T_world_gripper(world, q) for q in Q.numpy()])
    finally:
        world.set_q(q_saved)
    pos_err = np.linalg.norm(T_lfd[:, :3, 3] - T_pb[:, :3, 3], axis=1)
    R_rel = np.einsum("nji,njk->nik", T_lfd[:, :3, :3], T_pb[:, :3, :3])
    # project onto SO(3) (float32 matrices are slightly non-orthogonal) before the angle
    U, _, Vt = np.linalg.svd(R_rel)
    ang_err = Rotation.from_matrix(U @ Vt).magnitude()
    tol_p, tol_r = TOL[dtype]
    assert pos_err.max() < tol_p, f"max position error {pos_err.max():.2e} m"
    assert ang_err.max() < tol_r, f"max rotation error {ang_err.max():.2e} rad"


def test_batched_fk_equals_single_calls(kin64):
    Q = kin64.sample_uniform(16, generator=torch.Generator().manual_seed(1))
    T_batch = kin64.fk(Q)
    T_loop = torch.stack([kin64.fk(q) for q in Q])
    assert T_batch.shape == (16, 4, 4)
    torch.testing.assert_close(T_batch, T_loop, rtol=0, atol=1e-12)


def test_fk_gradient_matches_finite_differences(kin64):
    q = kin64.sample_uniform(1, generator=torch.Generator().manual_seed(2))[0].requires_grad_(True)
    p_ee = kin64.fk(q)[:3, 3]  # (3,)
    J_auto = torch.stack([torch.autograd.grad(p_ee[i], q, retain_graph=True)[0] for i in range(3)])  # (3, 7)
    h = 1e-6
    J_fd = torch.zeros(3, 7, dtype=torch.float64)
    with torch.no_grad():
        for j in range(7):
            dq = torch.zeros(7, dtype=torch.float64)
            dq[j] = h
            J_fd[:, j] = (kin64.fk(q + dq)[:3, 3] - kin64.fk(q - dq)[:3, 3]) / (2 * h)
    # Measured: |J_auto - J_fd| = 3.3e-8 m/rad, the same for h from 1e-4 to 1e-7, so it is not
    # finite-difference error but a ~5e-8 relative inconsistency inside pytorch-kinematics'
    # derivative (single-precision-sized); far below anything the learner or IK can notice.
    torch.testing.assert_close(J_auto, J_fd, rtol=0, atol=1e-6)


def test_jacobian_with_pose_is_fk_and_jacobian(kin64):
    """``jacobian(q, with_pose=True)`` (one forward pass, used by IK and the projection) returns
    the same pose as ``fk`` and the same Jacobian, whose linear rows match finite differences."""
    Q = kin64.sample_uniform(8, generator=torch.Generator().manual_seed(3))
    J, T_world_ee = kin64.jacobian(Q, with_pose=True)
    torch.testing.assert_close(T_world_ee, kin64.fk(Q), rtol=0, atol=1e-12)
    torch.testing.assert_close(J, kin64.jacobian(Q), rtol=0, atol=1e-12)
    h = 1e-6
    for j in range(kin64.dof):
        dq = torch.zeros(kin64.dof, dtype=torch.float64)
        dq[j] = h
        Tp, Tm = kin64.fk(Q + dq), kin64.fk(Q - dq)  # (8, 4, 4)
        fd = (Tp[:, :3, 3] - Tm[:, :3, 3]) / (2 * h)  # (8, 3)
        torch.testing.assert_close(J[:, :3, j], fd, rtol=0, atol=1e-6)
        # angular rows: dR/dq_j R^T = skew(omega_j)
        W = (Tp[:, :3, :3] - Tm[:, :3, :3]) / (2 * h) @ T_world_ee[:, :3, :3].transpose(1, 2)  # (8, 3, 3)
        omega = torch.stack([W[:, 2, 1], W[:, 0, 2], W[:, 1, 0]], dim=1)  # (8, 3)
        torch.testing.assert_close(J[:, 3:, j], omega, rtol=0, atol=1e-6)


def test_unknown_robot_name():
    with pytest.raises(ValueError, match="unknown robot 'nope'.*baxter_left"):
        robot_from_name("nope")


def test_nonexistent_urdf_path(tmp_path):
    missing = tmp_path / "missing.urdf"
    with pytest.raises(FileNotFoundError, match="URDF file not found"):
        resolve_urdf(str(missing))
    with pytest.raises(KinematicsError, match="URDF file not found"):
        KinematicModel(missing, "left_gripper")
    spec = RobotSpec("ghost", str(missing), "left_gripper", BAXTER_LEFT.joint_names)
    with pytest.raises(KinematicsError, match="URDF file not found"):
        KinematicModel.from_spec(spec)


def test_wrong_configuration_length(kin64, world):
    with pytest.raises(KinematicsError, match=r"7 joint values.*got shape \(6,\)"):
        kin64.fk(torch.zeros(6, dtype=torch.float64))
    with pytest.raises(ValueError, match=r"q must have shape \(7,\).*got shape \(8,\)"):
        world.set_q(np.zeros(8))


def test_to_leaves_the_original_model_alone():
    kin = KinematicModel.from_spec(BAXTER_LEFT, dtype=torch.float64)
    kin.to(dtype=torch.float32)
    assert kin.fk(torch.zeros(7, dtype=torch.float64)).dtype == torch.float64


def _edited_baxter(tmp_path, old: str, new: str):
    from lfd.robot.robots import resolve_urdf
    text = resolve_urdf(BAXTER_LEFT.urdf).read_text()
    assert old in text
    path = tmp_path / "baxter.urdf"
    path.write_text(text.replace(old, new, 1))
    return KinematicModel(path, BAXTER_LEFT.end_link, BAXTER_LEFT.joint_names)


def test_a_transmission_does_not_erase_a_joints_limits(tmp_path):
    """A ROS <transmission> names joints too; it made left_s0's limits and velocity infinite."""
    ref = KinematicModel.from_spec(BAXTER_LEFT)
    kin = _edited_baxter(tmp_path, "</robot>", '<transmission name="t"><type>SimpleTransmission</type>'
                         '<joint name="left_s0"><hardwareInterface>x</hardwareInterface></joint>'
                         '<actuator name="m"><mechanicalReduction>1</mechanicalReduction></actuator></transmission></robot>')
    for k in ("lower", "upper", "velocity"):
        assert torch.equal(getattr(kin, k), getattr(ref, k)), k


def test_the_urdf_is_read_without_the_parsers_complaints(tmp_path, capfd):
    """The Baxter description holds tags urdf_parser_py does not model (Gazebo, transmissions, a
    material inside a collision): reading it prints nothing, and the parser's module-level error
    hook is the library's own afterwards. FK equals the full description's (test_fk_matches_pybullet
    checks the values)."""
    from pytorch_kinematics.urdf_parser_py.xml_reflection import core

    hook = core.on_error
    kin = _edited_baxter(tmp_path, "</robot>", '<gazebo reference="left_hand"><material>Gazebo/Red</material></gazebo></robot>')
    assert capfd.readouterr().err == "" and core.on_error is hook
    q = torch.zeros(3, 7, dtype=torch.float64)
    q[1] = 0.3
    q[2, ::2] = -0.5
    assert torch.allclose(kin.fk(q), KinematicModel.from_spec(BAXTER_LEFT).fk(q), atol=1e-12)
    from lfd.robot.robots import PANDA  # its joints' dynamics carry attributes the parser lacks (mu_coulomb)
    capfd.readouterr()
    KinematicModel.from_spec(PANDA)
    assert capfd.readouterr().err == ""


@pytest.mark.parametrize("old,new,fragment", [
    ('lower="-1.70167993878"', 'lower="abc"', "limit lower='abc' is not a number"),  # was a ValueError traceback
    ('lower="-1.70167993878"', 'lower="nan"', "limit lower is NaN"),  # switched the limit check off
    ('lower="-1.70167993878"', 'lower="2.5"', "lower limit 2.5 is above upper"),
    # a NaN in a joint's origin made every pose NaN: learning failed with a Cholesky message, IK raised
    ('rpy="1.57079632679 0 1.57079632679" xyz="0.102 0 0"', 'rpy="1.57079632679 0 1.57079632679" xyz="nan 0 0"',
     "origin xyz='nan 0 0' is not three finite numbers"),  # (right_e0, the first joint with that origin)
    ('rpy="1.57079632679 0 1.57079632679" xyz="0.102 0 0"', 'rpy="1.57 0" xyz="0.102 0 0"',
     "origin rpy='1.57 0' is not three finite numbers"),
])
def test_a_urdf_with_bad_limits_is_refused(tmp_path, old, new, fragment):
    with pytest.raises(KinematicsError, match=re.escape(fragment)):
        _edited_baxter(tmp_path, old, new)


def test_a_scalar_configuration_is_refused_by_name(kin64):
    with pytest.raises(KinematicsError, match=r"7 joint values.*got shape \(\)"):  # was an IndexError
        kin64.fk(0.5)


_ARM3 = """<?xml version="1.0"?>
<robot name="arm3">
  <link name="base"/><link name="l1"/><link name="l2"/><link name="l3"/><link name="tool0"/>
  <joint name="j1" type="revolute"><parent link="base"/><child link="l1"/><origin xyz="0 0 0.1"/>
    <axis xyz="0 0 1"/><limit lower="-2" upper="2" velocity="1.5" effort="10"/></joint>
  <joint name="j2" type="{kind}"><parent link="l1"/><child link="l2"/><origin xyz="0 0 0.3"/>
    <axis xyz="0 1 0"/>{limit}</joint>
  <joint name="j3" type="revolute"><parent link="l2"/><child link="l3"/><origin xyz="0.3 0 0"/>
    <axis xyz="0 1 0"/><limit lower="-2" upper="2" velocity="1.5" effort="10"/></joint>
  <joint name="tool_joint" type="fixed"><parent link="l3"/><child link="tool0"/><origin xyz="0.1 0 0"/></joint>
</robot>
"""


def arm3(tmp_path, kind="continuous", limit='<limit velocity="1.0" effort="10"/>') -> RobotSpec:
    """A user's 3-joint arm whose middle joint is ``kind`` with ``limit`` (tests of other robots)."""
    path = tmp_path / f"arm3_{kind}.urdf"
    path.write_text(_ARM3.format(kind=kind, limit=limit))
    return RobotSpec("arm3", str(path), "tool0", ("j1", "j2", "j3"))


def test_a_joint_that_turns_without_limits_is_sampled_over_one_turn(tmp_path):
    """A continuous joint has no limits (inf), and uniform samples of it were NaN (the roadmap's
    build then failed in scipy's k-d tree); it is sampled over one turn, the limited joints within
    their limits. A joint that slides without limits cannot be sampled: refused by name."""
    kin = KinematicModel.from_spec(arm3(tmp_path))
    assert kin.lower[1] == -np.inf and kin.upper[1] == np.inf
    Q = kin.sample_uniform(2000, generator=torch.Generator().manual_seed(0)).numpy()
    assert np.all(np.isfinite(Q))
    assert Q[:, 1].min() < -3.1 and Q[:, 1].max() > 3.1 and np.all(np.abs(Q[:, 1]) <= np.pi)
    assert np.all(np.abs(Q[:, [0, 2]]) <= 2.0) and np.abs(Q[:, [0, 2]]).max() > 1.99
    free = KinematicModel.from_spec(arm3(tmp_path, "revolute", ""))  # no <limit> at all (the spec wants one)
    Q = free.sample_uniform(500, generator=torch.Generator().manual_seed(0)).numpy()  # one turn
    assert np.all(np.abs(Q[:, 1]) <= np.pi) and np.abs(Q[:, 1]).max() > 3.1
    slides = KinematicModel.from_spec(arm3(tmp_path, "prismatic", ""))
    with pytest.raises(KinematicsError, match=r"joint\(s\) \['j2'\] slide without limits .*pass your own sample_fn"):
        slides.sample_uniform(3)


def _pybullet_joint(urdf_path, q: float):
    """PyBullet's reading of a one-joint URDF: its limits and the end link's position at ``q``."""
    client = p.connect(p.DIRECT)
    try:
        robot = p.loadURDF(str(urdf_path), useFixedBase=True, physicsClientId=client)
        info = p.getJointInfo(robot, 0, physicsClientId=client)
        p.resetJointState(robot, 0, q, physicsClientId=client)
        pos = p.getLinkState(robot, 1, computeForwardKinematics=True, physicsClientId=client)[4]
        return (info[8], info[9]), np.array(pos)
    finally:
        p.disconnect(client)


@pytest.mark.parametrize("joint,expect_limits,same_in_pybullet", [
    ('<joint name="j" type="revolute"><parent link="base"/><child link="l1"/>'
     '<limit upper="1" velocity="1" effort="1"/></joint>', (0.0, 1.0), True),  # no <axis>: x; no lower: 0
    ('<joint name="j" type="revolute"><parent link="base"/><child link="l1"/><axis xyz="0 1 0"/>'
     '<limit lower="-0.5" velocity="1" effort="1"/></joint>', (-0.5, 0.0), False),  # (PyBullet: upper -1, unlimited)
    ('<joint name="j" type="continuous"><parent link="base"/><child link="l1"/><axis xyz="1 0 0"/>'
     '<limit lower="-1" upper="1" velocity="1" effort="1"/></joint>', (-np.inf, np.inf), False),  # ignored
])
def test_the_urdf_defaults_are_read_as_the_specification_says(tmp_path, joint, expect_limits, same_in_pybullet):
    """A joint without ``<axis>`` turns about x (the URDF's default, and PyBullet's; pytorch-kinematics'
    own is z, and lfd's FK put the end link 0.5 m up where PyBullet has it at (0, -0.42, 0.27)); a
    missing ``lower`` or ``upper`` of a revolute joint is 0, as urdfdom reads it (lfd had one turn
    below the other limit: 6 rad past what PyBullet allows with ``upper`` alone); a continuous
    joint has no position limits."""
    path = tmp_path / "one.urdf"
    path.write_text('<?xml version="1.0"?><robot name="one"><link name="base"/><link name="l1"/><link name="ee"/>'
                    + joint + '<joint name="f" type="fixed"><parent link="l1"/><child link="ee"/>'
                    '<origin xyz="0 0 0.5"/></joint></robot>')
    kin = KinematicModel(path, "ee")
    assert (float(kin.lower[0]), float(kin.upper[0])) == expect_limits
    for q in (0.7, -0.4):
        pb_limits, pb_pos = _pybullet_joint(path, q)
        assert np.abs(kin.fk(torch.tensor([q], dtype=torch.float64))[:3, 3].numpy() - pb_pos).max() < 1e-6
    if same_in_pybullet:
        assert pb_limits == pytest.approx(expect_limits)


def test_a_mimic_joint_on_the_chain_and_a_velocity_of_zero_are_not_taken_as_they_are(tmp_path):
    """A joint that mimics another was an independent joint (sampled, solved for and planned on
    its own, breaking the linkage): refused by name. ``velocity="0"`` (CAD exporters) is no
    velocity limit (plan timing divided by it: edges were dropped), which the planner refuses."""
    mimic = tmp_path / "mimic.urdf"
    mimic.write_text(
        '<?xml version="1.0"?><robot name="m"><link name="base"/><link name="l1"/><link name="l2"/>'
        '<joint name="j1" type="revolute"><parent link="base"/><child link="l1"/><axis xyz="0 0 1"/>'
        '<limit lower="-1" upper="1" velocity="1" effort="1"/></joint>'
        '<joint name="j2" type="revolute"><parent link="l1"/><child link="l2"/><origin xyz="0.5 0 0"/>'
        '<axis xyz="0 0 1"/><limit lower="-3" upper="3" velocity="1" effort="1"/>'
        '<mimic joint="j1" multiplier="2" offset="0.1"/></joint></robot>')
    with pytest.raises(KinematicsError, match=r"mimic joint\(s\) j2 \(follows 'j1'\)"):
        KinematicModel(mimic, "l2")
    assert KinematicModel(mimic, "l1").joint_names == ("j1",)  # a chain that stops before it
    kin = KinematicModel.from_spec(arm3(tmp_path, "revolute", '<limit lower="-1" upper="1" velocity="0" effort="1"/>'))
    assert kin.velocity[1] == np.inf and kin.velocity[0] == 1.5
