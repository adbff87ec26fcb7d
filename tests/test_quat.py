"""Quaternion utilities against scipy.spatial.transform (scalar-last there, scalar-first here)."""

import itertools

import numpy as np
import pytest
from scipy.spatial.transform import Rotation, Slerp

from jaxstyle.motion import quat

TAIT_BRYAN = ["".join(p) for p in itertools.permutations("xyz")]


def to_scipy(q):
    return Rotation.from_quat(np.concatenate([q[..., 1:], q[..., :1]], axis=-1))


def from_scipy(r):
    x = r.as_quat()
    return np.concatenate([x[..., 3:], x[..., :3]], axis=-1)


def same_rotation(a, b, atol=1e-10):
    """Quaternions equal up to sign."""
    d = np.minimum(np.abs(a - b).max(-1), np.abs(a + b).max(-1))
    return np.all(d < atol)


@pytest.fixture
def rng():
    return np.random.default_rng(0)


def random_quats(rng, n):
    return from_scipy(Rotation.random(n, random_state=rng))


def test_mul_matches_scipy_composition(rng):
    a, b = random_quats(rng, 100), random_quats(rng, 100)
    assert same_rotation(quat.mul(a, b), from_scipy(to_scipy(a) * to_scipy(b)))


def test_rotate_and_matrix_match_scipy(rng):
    q = random_quats(rng, 100)
    v = rng.normal(size=(100, 3))
    np.testing.assert_allclose(quat.rotate(q, v), to_scipy(q).apply(v), atol=1e-12)
    np.testing.assert_allclose(quat.to_matrix(q), to_scipy(q).as_matrix(), atol=1e-12)


def test_from_matrix_round_trip_including_180_degrees(rng):
    q = random_quats(rng, 200)
    # Rotations by ~180 degrees about each axis exercise every Shepperd branch.
    q = np.concatenate([q, np.eye(4), quat.from_axis_angle(rng.normal(size=(20, 3)), np.full(20, np.pi))])
    m = to_scipy(q).as_matrix()
    assert same_rotation(quat.from_matrix(m), q, atol=1e-9)
    assert np.all(quat.from_matrix(m)[:, 0] >= 0)


def test_inverse_and_conjugate(rng):
    q = random_quats(rng, 50)
    assert same_rotation(quat.mul(q, quat.inverse(q)), quat.identity((50,)))
    assert same_rotation(quat.inverse(q), from_scipy(to_scipy(q).inv()))
    np.testing.assert_allclose(quat.inverse(2.0 * q), 0.5 * quat.conjugate(q), atol=1e-12)


@pytest.mark.parametrize("order", TAIT_BRYAN)
def test_from_euler_matches_scipy_intrinsic(rng, order):
    angles = rng.uniform(-180, 180, size=(100, 3))
    ours = quat.from_euler(angles, order, degrees=True)
    theirs = from_scipy(Rotation.from_euler(order.upper(), angles, degrees=True))
    assert same_rotation(ours, theirs)


@pytest.mark.parametrize("order", ["x", "zy", "xzx", "zyxz", "yyx"])
def test_from_euler_any_length(rng, order):
    angles = rng.uniform(-3, 3, size=(10, len(order)))
    expected = quat.identity((10,))
    for i, ax in enumerate(order):
        expected = from_scipy(to_scipy(expected) * Rotation.from_euler(ax.upper(), angles[:, i, None]))
    assert same_rotation(quat.from_euler(angles, order), expected)


@pytest.mark.parametrize("order", TAIT_BRYAN)
def test_to_euler_matches_scipy_and_round_trips(rng, order):
    q = random_quats(rng, 300)
    ours = quat.to_euler(q, order, degrees=True)
    theirs = to_scipy(q).as_euler(order.upper(), degrees=True)
    np.testing.assert_allclose(ours, theirs, atol=1e-7)
    assert same_rotation(quat.from_euler(ours, order, degrees=True), q, atol=1e-9)


@pytest.mark.parametrize("order", TAIT_BRYAN)
def test_to_euler_at_gimbal_lock(rng, order):
    angles = rng.uniform(-180, 180, size=(50, 3))
    angles[:25, 1] = 90.0
    angles[25:, 1] = -90.0
    q = quat.from_euler(angles, order, degrees=True)
    back = quat.to_euler(q, order, degrees=True)
    assert np.isfinite(back).all()
    assert same_rotation(quat.from_euler(back, order, degrees=True), q, atol=1e-7)


def test_euler_order_validation():
    with pytest.raises(ValueError, match="Tait-Bryan"):
        quat.to_euler(quat.identity((1,)), "xyx")
    with pytest.raises(ValueError, match="letters"):
        quat.from_euler(np.zeros(3), "abc")
    with pytest.raises(ValueError, match="components"):
        quat.from_euler(np.zeros(2), "xyz")


def test_slerp_matches_scipy(rng):
    q = random_quats(rng, 2)
    t = np.linspace(0, 1, 11)
    ours = quat.slerp(np.broadcast_to(q[0], (11, 4)), np.broadcast_to(q[1], (11, 4)), t)
    theirs = from_scipy(Slerp([0, 1], to_scipy(q))(t))
    assert same_rotation(ours, theirs, atol=1e-10)


def test_slerp_takes_short_arc_and_handles_equal_inputs(rng):
    q = random_quats(rng, 5)
    np.testing.assert_allclose(quat.slerp(q, -q, 0.5), q, atol=1e-12)  # -q is the same rotation
    np.testing.assert_allclose(quat.slerp(q, q, 0.3), q, atol=1e-12)


def test_forward_up_and_back(rng):
    q = random_quats(rng, 100)
    m = to_scipy(q).as_matrix()
    np.testing.assert_allclose(quat.forward(q), m[:, :, 2], atol=1e-12)
    np.testing.assert_allclose(quat.up(q), m[:, :, 1], atol=1e-12)
    noisy_up = quat.up(q) + 0.05 * rng.normal(size=(100, 3))
    assert same_rotation(quat.from_forward_up(2.0 * quat.forward(q), quat.up(q)), q, atol=1e-9)
    back = quat.from_forward_up(quat.forward(q), noisy_up)
    np.testing.assert_allclose(quat.forward(back), quat.forward(q), atol=1e-12)


def test_between_maps_u_to_v(rng):
    u = rng.normal(size=(50, 3))
    v = rng.normal(size=(50, 3))
    v[0] = -u[0]  # opposite directions
    v[1] = u[1]
    q = quat.between(u, v)
    got = quat.rotate(q, u / np.linalg.norm(u, axis=1, keepdims=True))
    np.testing.assert_allclose(got, v / np.linalg.norm(v, axis=1, keepdims=True), atol=1e-9)


def test_functions_accept_jax_arrays_under_jit(rng):
    import jax
    import jax.numpy as jnp

    jax.config.update("jax_enable_x64", True)
    try:
        q = random_quats(rng, 8)
        v = rng.normal(size=(8, 3))
        got = jax.jit(lambda q, v: quat.rotate(quat.mul(q, q), v))(jnp.asarray(q), jnp.asarray(v))
        np.testing.assert_allclose(np.asarray(got), quat.rotate(quat.mul(q, q), v), atol=1e-12)
        e = jax.jit(lambda q: quat.to_euler(q, "zyx"))(jnp.asarray(q))
        np.testing.assert_allclose(np.asarray(e), quat.to_euler(q, "zyx"), atol=1e-12)
    finally:
        jax.config.update("jax_enable_x64", False)


def test_from_euler_writes_into_a_view(rng):
    angles = rng.uniform(-400, 400, size=(6, 5, 3))  # beyond +-180 exercises the wrap
    buf = np.zeros((6, 7, 4))
    quat.from_euler(angles, "yxz", degrees=True, out=buf[:, 1:6])
    expected = from_scipy(Rotation.from_euler("YXZ", angles.reshape(-1, 3), degrees=True)).reshape(6, 5, 4)
    assert same_rotation(buf[:, 1:6], expected)
    assert np.all(buf[:, [0, 6]] == 0)
