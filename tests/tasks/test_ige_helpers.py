"""IsaacGym helper names (quat_axis, torch_rand_float, torch_random_dir_2, tensor_clamp; torch_jit_utils' range and pose
helpers) against formulas written here in numpy, known values, and MuJoCo C's own quaternion functions."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest
import torch

from isaacgymenvs_mw.utils.torch_utils import quat_axis, tensor_clamp, torch_rand_float, torch_random_dir_2


def random_quats(n: int, seed: int = 0) -> np.ndarray:
    q = np.random.default_rng(seed).normal(size=(n, 4))
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def matrix_wxyz(q: np.ndarray) -> np.ndarray:
    """Rotation matrix of a unit quaternion (w, x, y, z), the textbook expansion."""
    w, x, y, z = q
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])


@pytest.mark.parametrize("axis", [0, 1, 2])
def test_quat_axis_is_a_column_of_the_rotation_matrix(axis):
    q = random_quats(16)
    got = quat_axis(torch.tensor(q, dtype=torch.float64), axis).numpy()
    for i in range(len(q)):
        mat = np.zeros(9)
        mujoco.mju_quat2Mat(mat, q[i])  # MuJoCo C reads (w, x, y, z) too
        np.testing.assert_allclose(got[i], mat.reshape(3, 3)[:, axis], atol=1e-12)
        np.testing.assert_allclose(got[i], matrix_wxyz(q[i])[:, axis], atol=1e-12)


def test_quat_axis_reads_w_first():
    """A quarter turn about z (w, x, y, z) = (cos 45°, 0, 0, sin 45°) takes x to y; read as (x, y, z, w) it would
    be a half turn about x, taking x to x."""
    q = torch.tensor([[np.cos(np.pi / 4), 0.0, 0.0, np.sin(np.pi / 4)]], dtype=torch.float64)
    np.testing.assert_allclose(quat_axis(q, 0).numpy(), [[0.0, 1.0, 0.0]], atol=1e-12)
    with pytest.raises(ValueError, match="axis=3 is invalid"):
        quat_axis(q, 3)


def test_torch_rand_float_is_uniform_in_its_bounds():
    torch.manual_seed(0)
    x = torch_rand_float(-2.0, 3.0, (4000, 3), "cpu")
    assert x.shape == (4000, 3) and x.device.type == "cpu" and x.dtype == torch.float32
    values = x.numpy().ravel()
    assert values.min() >= -2.0 and values.max() < 3.0
    # Uniform on [-2, 3): mean 0.5, variance 25 / 12; each fifth of the interval holds a fifth of the draws.
    assert abs(values.mean() - 0.5) < 0.05 and abs(values.var() - 25 / 12) < 0.1
    counts = np.histogram(values, bins=5, range=(-2.0, 3.0))[0] / values.size
    np.testing.assert_allclose(counts, 0.2, atol=0.02)
    torch.manual_seed(0)
    assert torch.equal(torch_rand_float(-2.0, 3.0, (4000, 3), "cpu"), x)  # seeded runs repeat


def test_torch_rand_float_takes_per_column_bounds():
    lower, upper = torch.tensor([0.0, 10.0]), torch.tensor([1.0, 10.5])
    x = torch_rand_float(lower, upper, (1000, 2), "cpu").numpy()
    assert (x >= lower.numpy()).all() and (x < upper.numpy()).all()
    assert x[:, 0].max() - x[:, 0].min() > 0.9 and x[:, 1].max() - x[:, 1].min() < 0.5


def test_torch_random_dir_2_is_a_uniform_unit_direction():
    torch.manual_seed(0)
    d = torch_random_dir_2((8000, 1), "cpu")
    assert d.shape == (8000, 2) and d.dtype == torch.float32
    x, y = d.double().numpy().T
    np.testing.assert_allclose(np.hypot(x, y), 1.0, atol=1e-6)
    # Uniform angle: each eighth of the circle holds an eighth of the draws; E[x] = E[y] = E[xy] = 0, E[x²] = 1/2.
    counts = np.histogram(np.arctan2(y, x), bins=8, range=(-np.pi, np.pi))[0] / x.size
    np.testing.assert_allclose(counts, 1 / 8, atol=0.015)
    assert abs(x.mean()) < 0.03 and abs(y.mean()) < 0.03 and abs((x * y).mean()) < 0.02
    assert abs((x * x).mean() - 0.5) < 0.02
    # The same draws as an angle uniform in [-pi, pi) from the global generator, mapped to (cos, sin).
    torch.manual_seed(0)
    angle = 2 * np.pi * torch.rand(8000, 1).double().numpy()[:, 0] - np.pi
    np.testing.assert_allclose(np.stack([np.cos(angle), np.sin(angle)], axis=1), d.numpy(), atol=1e-5)


def test_torch_random_dir_2_keeps_a_shape_without_trailing_one():
    assert torch_random_dir_2((5, 3), "cpu").shape == (5, 3, 2)
    assert torch_random_dir_2((7,), "cpu").shape == (7, 2)


def test_tensor_clamp_per_element_bounds():
    rng = np.random.default_rng(1)
    t = rng.normal(size=(50, 6)) * 3
    lo = rng.uniform(-2.0, 0.0, size=6)
    hi = rng.uniform(0.0, 2.0, size=6)
    got = tensor_clamp(torch.tensor(t), torch.tensor(lo), torch.tensor(hi)).numpy()
    want = np.where(t < lo, lo, np.where(t > hi, hi, t))
    np.testing.assert_array_equal(got, want)
    # Inverted bounds give the lower one (the max is taken last), as IsaacGym's does.
    inverted = tensor_clamp(torch.tensor([0.0, 5.0, -5.0]), torch.tensor(1.0), torch.tensor(-1.0))
    np.testing.assert_array_equal(inverted.numpy(), [1.0, 1.0, 1.0])


def test_quat_mul_and_conjugate_equal_mujoco_c():
    from isaacgymenvs_mw.utils.torch_utils import quat_conjugate, quat_mul

    rng = np.random.default_rng(8)
    a, b = rng.normal(size=(50, 4)), rng.normal(size=(50, 4))
    a /= np.linalg.norm(a, axis=1, keepdims=True)
    b /= np.linalg.norm(b, axis=1, keepdims=True)
    expected_mul, expected_neg = np.zeros((50, 4)), np.zeros((50, 4))
    for i in range(50):
        mujoco.mju_mulQuat(expected_mul[i], a[i], b[i])
        mujoco.mju_negQuat(expected_neg[i], a[i])
    np.testing.assert_allclose(quat_mul(torch.tensor(a), torch.tensor(b)).numpy(), expected_mul, atol=1e-12)
    np.testing.assert_allclose(quat_conjugate(torch.tensor(a)).numpy(), expected_neg, atol=1e-12)


def test_scale_and_unscale_transform_map_the_range_onto_minus_one_one_and_back():
    from isaacgymenvs_mw.utils.torch_utils import scale_transform, unscale_transform

    lower, upper = torch.tensor([-1.0, 0.0, 2.0], dtype=torch.float64), torch.tensor([3.0, 0.5, 10.0],
                                                                                       dtype=torch.float64)
    # The ends and the midpoint, known values: lower -> -1, upper -> 1, midpoint -> 0; 1.5 times the half-range -> 1.5.
    x = torch.stack([lower, upper, (lower + upper) / 2, (lower + upper) / 2 + 0.75 * (upper - lower)])
    np.testing.assert_allclose(scale_transform(x, lower, upper).numpy(),
                               [[-1, -1, -1], [1, 1, 1], [0, 0, 0], [1.5, 1.5, 1.5]], atol=1e-12)
    y = torch.tensor(np.random.default_rng(3).uniform(-1.2, 1.2, size=(20, 3)))
    lo, hi = lower.numpy(), upper.numpy()
    np.testing.assert_allclose(unscale_transform(y, lower, upper).numpy(), lo + (y.numpy() + 1) / 2 * (hi - lo),
                               atol=1e-12)
    np.testing.assert_allclose(scale_transform(unscale_transform(y, lower, upper), lower, upper).numpy(), y.numpy(),
                               atol=1e-12)


def test_saturate_clamps_into_the_bounds():
    from isaacgymenvs_mw.utils.torch_utils import saturate

    got = saturate(torch.tensor([[-5.0, 0.2, 9.0]]), torch.tensor([-1.0, 0.0, 0.0]), torch.tensor([1.0, 1.0, 2.0]))
    np.testing.assert_array_equal(got.numpy(), np.array([[-1.0, 0.2, 2.0]], dtype=np.float32))


def test_quat_from_euler_xyz_equals_mujoco_c_and_the_product_of_axis_rotations():
    from isaacgymenvs_mw.utils.torch_utils import quat_from_euler_xyz

    angles = np.random.default_rng(5).uniform(-np.pi, np.pi, size=(30, 3))
    got = quat_from_euler_xyz(*torch.tensor(angles).unbind(-1)).numpy()
    for (roll, pitch, yaw), q in zip(angles, got):
        want = np.zeros(4)
        mujoco.mju_euler2Quat(want, np.array([roll, pitch, yaw]), "XYZ")  # extrinsic x, then y, then z
        np.testing.assert_allclose(q, want, atol=1e-12)
        # The same rotation built as qz(yaw) qy(pitch) qx(roll) from MuJoCo's axis-angle quaternions.
        parts = []
        for axis, angle in ((2, yaw), (1, pitch), (0, roll)):
            part = np.zeros(4)
            mujoco.mju_axisAngle2Quat(part, np.eye(3)[axis], angle)
            parts.append(part)
        zy, zyx = np.zeros(4), np.zeros(4)
        mujoco.mju_mulQuat(zy, parts[0], parts[1])
        mujoco.mju_mulQuat(zyx, zy, parts[2])
        np.testing.assert_allclose(q, zyx, atol=1e-12)
    # A pure yaw of 90 degrees turns the body's x axis onto world y.
    q90 = quat_from_euler_xyz(torch.tensor([0.0]), torch.tensor([0.0]), torch.tensor([np.pi / 2]))
    np.testing.assert_allclose(quat_axis(q90, 0).numpy(), [[0.0, 1.0, 0.0]], atol=1e-7)


def test_local_to_world_space_equals_mujoco_c_frame_transform():
    from isaacgymenvs_mw.utils.torch_utils import local_to_world_space

    rng = np.random.default_rng(6)
    pos, quat, offset = rng.normal(size=(20, 3)), random_quats(20, seed=6), rng.normal(size=(20, 3))
    got = local_to_world_space(torch.tensor(offset), torch.tensor(np.concatenate([pos, quat], axis=1))).numpy()
    for i in range(20):
        want = np.zeros(3)
        mujoco.mju_rotVecQuat(want, offset[i], quat[i])  # MuJoCo C, (w, x, y, z)
        np.testing.assert_allclose(got[i], pos[i] + want, atol=1e-12)
        np.testing.assert_allclose(got[i], pos[i] + matrix_wxyz(quat[i]) @ offset[i], atol=1e-12)
