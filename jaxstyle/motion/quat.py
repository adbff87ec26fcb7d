"""Quaternion and rotation utilities shared across jaxstyle.

Conventions (used everywhere in the project):

* A quaternion is stored as ``(w, x, y, z)`` in the last axis (scalar first), shape ``(..., 4)``.
  Note that :mod:`scipy.spatial.transform` uses scalar-last ``(x, y, z, w)``.
* Rotations act on column vectors: ``rotate(q, v) == to_matrix(q) @ v``.
* ``mul(a, b)`` is the rotation "first ``b``, then ``a``", so a child's global rotation is
  ``mul(parent_global, child_local)``.
* Euler orders are strings of axis letters read left to right as *intrinsic* rotations, which is
  what BVH channel lists mean: channels ``Zrotation Yrotation Xrotation`` give
  ``R = Rz(a0) @ Ry(a1) @ Rx(a2)``, i.e. ``from_euler(angles, "zyx")``.  This equals scipy's
  upper-case (intrinsic) sequence ``"ZYX"``.
* Forward is local +Z and up is local +Y (the Y-up convention of both papers' data).

Every function works on NumPy arrays and, unchanged, on JAX arrays (the array module is picked
from the input), so the same code serves the NumPy motion pipeline and jitted JAX code.
"""

from __future__ import annotations

import numpy as np

_AXIS_INDEX = {"x": 0, "y": 1, "z": 2}

FORWARD = (0.0, 0.0, 1.0)
UP = (0.0, 1.0, 0.0)


def _xp(*arrays):
    """Returns ``jax.numpy`` if any input is a JAX array, else ``numpy``."""
    for a in arrays:
        if type(a).__module__.startswith("jax"):
            import jax.numpy as jnp

            return jnp
    return np


def identity(shape=(), dtype=np.float64) -> np.ndarray:
    """Identity quaternions of the given batch shape: ``(*shape, 4)``."""
    q = np.zeros((*shape, 4), dtype=dtype)
    q[..., 0] = 1.0
    return q


def normalize(q, eps: float = 1e-12):
    """Unit quaternions (``q / |q|``); a zero quaternion stays zero rather than becoming NaN."""
    xp = _xp(q)
    n = xp.sqrt(xp.sum(q * q, axis=-1, keepdims=True))
    return q / xp.maximum(n, eps)


def mul(a, b):
    """Hamilton product ``a * b`` (apply ``b`` first, then ``a``); broadcasts over leading axes."""
    xp = _xp(a, b)
    aw, ax, ay, az = a[..., 0], a[..., 1], a[..., 2], a[..., 3]
    bw, bx, by, bz = b[..., 0], b[..., 1], b[..., 2], b[..., 3]
    return xp.stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ],
        axis=-1,
    )


def conjugate(q):
    """Conjugate ``(w, -x, -y, -z)``."""
    xp = _xp(q)
    return xp.concatenate([q[..., :1], -q[..., 1:]], axis=-1)


def inverse(q):
    """Inverse rotation (the conjugate divided by the squared norm)."""
    xp = _xp(q)
    return conjugate(q) / xp.sum(q * q, axis=-1, keepdims=True)


def rotate(q, v):
    """Rotates vectors ``v`` (``(..., 3)``) by unit quaternions ``q`` (``(..., 4)``)."""
    xp = _xp(q, v)
    w = q[..., :1]
    u = q[..., 1:]
    t = 2.0 * xp.cross(u, v)
    return v + w * t + xp.cross(u, t)


def from_axis_angle(axis, angle):
    """Quaternion for a rotation of ``angle`` radians about ``axis`` (normalised here)."""
    xp = _xp(axis, angle)
    axis = xp.asarray(axis)
    angle = xp.asarray(angle)
    axis = axis / xp.linalg.norm(axis, axis=-1, keepdims=True)
    half = 0.5 * angle[..., None]
    return xp.concatenate([xp.cos(half), xp.sin(half) * axis], axis=-1)


def to_matrix(q):
    """Rotation matrices ``(..., 3, 3)`` of unit quaternions ``(..., 4)``."""
    xp = _xp(q)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    xx, yy, zz = x * x, y * y, z * z
    xy, xz, yz = x * y, x * z, y * z
    wx, wy, wz = w * x, w * y, w * z
    rows = [
        [1 - 2 * (yy + zz), 2 * (xy - wz), 2 * (xz + wy)],
        [2 * (xy + wz), 1 - 2 * (xx + zz), 2 * (yz - wx)],
        [2 * (xz - wy), 2 * (yz + wx), 1 - 2 * (xx + yy)],
    ]
    return xp.stack([xp.stack(r, axis=-1) for r in rows], axis=-2)


def from_matrix(m):
    """Unit quaternions (``w >= 0``) of rotation matrices ``(..., 3, 3)``.

    Uses the numerically stable branch of Shepperd's method: for each matrix, the largest of
    ``4w^2, 4x^2, 4y^2, 4z^2`` (from the trace and diagonal) is used as the divisor.
    """
    xp = _xp(m)
    m00, m01, m02 = m[..., 0, 0], m[..., 0, 1], m[..., 0, 2]
    m10, m11, m12 = m[..., 1, 0], m[..., 1, 1], m[..., 1, 2]
    m20, m21, m22 = m[..., 2, 0], m[..., 2, 1], m[..., 2, 2]
    # Four candidate (unnormalised) quaternions, each exact up to scale; pick the best conditioned.
    cands = xp.stack(
        [
            xp.stack([1 + m00 + m11 + m22, m21 - m12, m02 - m20, m10 - m01], axis=-1),
            xp.stack([m21 - m12, 1 + m00 - m11 - m22, m01 + m10, m02 + m20], axis=-1),
            xp.stack([m02 - m20, m01 + m10, 1 - m00 + m11 - m22, m12 + m21], axis=-1),
            xp.stack([m10 - m01, m02 + m20, m12 + m21, 1 - m00 - m11 + m22], axis=-1),
        ],
        axis=-2,
    )  # (..., 4 candidates, 4)
    diag = xp.stack([1 + m00 + m11 + m22, 1 + m00 - m11 - m22, 1 - m00 + m11 - m22, 1 - m00 - m11 + m22], axis=-1)
    best = xp.argmax(diag, axis=-1)
    q = xp.take_along_axis(cands, best[..., None, None], axis=-2)[..., 0, :]
    q = normalize(q)
    return q * xp.where(q[..., :1] < 0, -1.0, 1.0)


def _check_order(order: str) -> str:
    order = order.lower()
    if not order or any(c not in _AXIS_INDEX for c in order):
        raise ValueError(f"Euler order must be made of the letters x, y, z; got {order!r}")
    return order


def _half_angle_cos_sin(xp, angles, to_radians: float):
    """``cos(theta / 2)`` and ``sin(theta / 2)``, each ``(len(order), ...)`` and contiguous per angle.

    Computed through ``t = tan(theta / 4)`` as ``((1 - t^2), 2 t) / (1 + t^2)``: one vectorised
    tan instead of a sin and a cos, which NumPy does not vectorise for float64 (3-4x slower).
    Wrapping theta into ``[-pi, pi]`` first keeps ``|theta / 4| <= pi / 4``; it may flip an
    elementary quaternion's sign, which is the same rotation. The NumPy branch works in place
    on two buffers, since large temporaries dominate the cost of reading a BVH file.
    """
    if xp is not np:
        theta = xp.moveaxis(angles, -1, 0) * to_radians
        theta = xp.where(xp.abs(theta) > np.pi, (theta + np.pi) % (2 * np.pi) - np.pi, theta)
        t = xp.tan(0.25 * theta)
        inv = 1.0 / (1.0 + t * t)
        return (1.0 - t * t) * inv, 2.0 * t * inv
    theta = np.multiply(np.moveaxis(angles, -1, 0), to_radians, dtype=np.float64)
    theta = np.ascontiguousarray(theta)
    if np.abs(theta).max(initial=0.0) > np.pi:
        theta = np.where(np.abs(theta) > np.pi, (theta + np.pi) % (2 * np.pi) - np.pi, theta)
    t = theta
    np.multiply(t, 0.25, out=t)
    np.tan(t, out=t)
    c = np.multiply(t, t)  # t^2
    np.multiply(t, 2.0, out=t)  # 2 t
    inv = np.add(c, 1.0)  # 1 + t^2
    np.subtract(1.0, c, out=c)  # 1 - t^2
    np.divide(c, inv, out=c)
    np.divide(t, inv, out=t)
    return c, t


def from_euler(angles, order: str, degrees: bool = False, out=None):
    """Quaternions from intrinsic Euler angles.

    Args:
      angles: ``(..., len(order))`` angles, one per letter of ``order``.
      order: axis letters, e.g. ``"zyx"``; any length (a BVH joint may have 1-3 rotation channels).
        The rotation is ``R_order[0](angles[..., 0]) @ R_order[1](angles[..., 1]) @ ...``.
      degrees: angles are in degrees.
      out: optional NumPy array ``(..., 4)`` (possibly a view) to write the result into.
    """
    order = _check_order(order)
    xp = _xp(angles)
    angles = xp.asarray(angles)
    if angles.shape[-1] != len(order):
        raise ValueError(f"angles have {angles.shape[-1]} components but order {order!r} has {len(order)}")
    c, s = _half_angle_cos_sin(xp, angles, (np.pi / 180.0) if degrees else 1.0)
    # Compose the elementary rotations left to right without general Hamilton products: the
    # first two give a quaternion with four known terms, and each further one is a right-multiply
    # by (c + s e_axis), 8 products instead of 16.
    axis0 = _AXIS_INDEX[order[0]]
    v = [None, None, None]
    if len(order) == 1 or order[1] == order[0]:
        zeros = xp.zeros_like(c[0])
        v = [zeros, zeros, zeros]
        w, v[axis0] = c[0], s[0]
        x, y, z = v
        start = 1
    else:
        axis1 = _AXIS_INDEX[order[1]]
        axis2 = 3 - axis0 - axis1
        sign = 1.0 if (axis1 - axis0) % 3 == 1 else -1.0  # e_a e_b = +-e_c
        w = c[0] * c[1]
        v[axis0] = s[0] * c[1]
        v[axis1] = c[0] * s[1]
        v[axis2] = sign * (s[0] * s[1])
        x, y, z = v
        start = 2
    for i in range(start, len(order)):
        ci, si = c[i], s[i]
        a = order[i]
        if a == "x":
            w, x, y, z = w * ci - x * si, x * ci + w * si, y * ci + z * si, z * ci - y * si
        elif a == "y":
            w, x, y, z = w * ci - y * si, x * ci - z * si, y * ci + w * si, z * ci + x * si
        else:
            w, x, y, z = w * ci - z * si, x * ci + y * si, y * ci - x * si, z * ci + w * si
    if out is None:
        return xp.stack([w, x, y, z], axis=-1)
    for k, comp in enumerate((w, x, y, z)):
        out[..., k] = comp
    return out


def to_euler(q, order: str, degrees: bool = False):
    """Intrinsic Euler angles ``(..., 3)`` of quaternions, for the six Tait-Bryan orders.

    The middle angle lies in ``[-90, 90]`` degrees. At gimbal lock (middle angle +-90 degrees)
    the last angle is set to 0 and the first absorbs the whole remaining rotation, so
    ``from_euler(to_euler(q, o), o)`` always reproduces the rotation.
    """
    order = _check_order(order)
    if len(order) != 3 or len(set(order)) != 3:
        raise ValueError(f"to_euler needs three distinct axes (a Tait-Bryan order); got {order!r}")
    xp = _xp(q)
    i, j, k = (_AXIS_INDEX[a] for a in order)
    # +1 for cyclic orders (xyz, yzx, zxy), -1 for the others.
    s = 1.0 if (j - i) % 3 == 1 else -1.0
    m = to_matrix(normalize(q))
    sin_b = xp.clip(s * m[..., i, k], -1.0, 1.0)
    b = xp.arcsin(sin_b)
    locked = xp.abs(sin_b) > 1.0 - 1e-10
    a_free = xp.arctan2(-s * m[..., j, k], m[..., k, k])
    c_free = xp.arctan2(-s * m[..., i, j], m[..., i, i])
    a_lock = xp.arctan2(s * m[..., k, j], m[..., j, j])
    a = xp.where(locked, a_lock, a_free)
    c = xp.where(locked, 0.0, c_free)
    out = xp.stack([a, b, c], axis=-1)
    return out * (180.0 / np.pi) if degrees else out


def slerp(q0, q1, t):
    """Spherical linear interpolation along the shorter arc.

    Args:
      q0, q1: ``(..., 4)`` unit quaternions.
      t: interpolation weights broadcastable to ``(...)`` (0 gives ``q0``, 1 gives ``q1``).
    """
    xp = _xp(q0, q1, t)
    t = xp.asarray(t)[..., None]
    dot = xp.sum(q0 * q1, axis=-1, keepdims=True)
    q1 = xp.where(dot < 0, -q1, q1)
    dot = xp.abs(dot)
    theta = xp.arccos(xp.clip(dot, -1.0, 1.0))
    sin_theta = xp.sin(theta)
    small = sin_theta < 1e-6
    safe = xp.where(small, 1.0, sin_theta)
    w0 = xp.where(small, 1.0 - t, xp.sin((1.0 - t) * theta) / safe)
    w1 = xp.where(small, t, xp.sin(t * theta) / safe)
    return normalize(w0 * q0 + w1 * q1)


def forward(q):
    """The rotated local forward axis (+Z), ``(..., 3)``."""
    xp = _xp(q)
    return rotate(q, xp.broadcast_to(xp.asarray(FORWARD, dtype=q.dtype), q.shape[:-1] + (3,)))


def up(q):
    """The rotated local up axis (+Y), ``(..., 3)``."""
    xp = _xp(q)
    return rotate(q, xp.broadcast_to(xp.asarray(UP, dtype=q.dtype), q.shape[:-1] + (3,)))


def from_forward_up(fwd, up_vec):
    """Rotation whose local +Z maps to ``fwd`` and local +Y to (the part of ``up_vec`` orthogonal to) it.

    The inverse of ``(forward(q), up(q))``; inputs need not be unit or exactly orthogonal
    (Gram-Schmidt keeps ``fwd`` and corrects ``up_vec``), which is what decoding a network's
    predicted forward/up vectors needs.
    """
    xp = _xp(fwd, up_vec)
    z = fwd / xp.linalg.norm(fwd, axis=-1, keepdims=True)
    y = up_vec - xp.sum(up_vec * z, axis=-1, keepdims=True) * z
    y = y / xp.linalg.norm(y, axis=-1, keepdims=True)
    x = xp.cross(y, z)
    return from_matrix(xp.stack([x, y, z], axis=-1))


def between(u, v):
    """The shortest-arc rotation taking direction ``u`` onto direction ``v`` (both ``(..., 3)``)."""
    xp = _xp(u, v)
    u = u / xp.linalg.norm(u, axis=-1, keepdims=True)
    v = v / xp.linalg.norm(v, axis=-1, keepdims=True)
    w = 1.0 + xp.sum(u * v, axis=-1, keepdims=True)
    axis = xp.cross(u, v)
    # Opposite directions: rotate by 180 degrees about any axis orthogonal to u.
    alt = xp.cross(u, xp.broadcast_to(xp.asarray([1.0, 0.0, 0.0]), u.shape))
    alt = xp.where(xp.linalg.norm(alt, axis=-1, keepdims=True) < 1e-6,
                   xp.cross(u, xp.broadcast_to(xp.asarray([0.0, 1.0, 0.0]), u.shape)), alt)
    opposite = w < 1e-9
    q = xp.where(opposite, xp.concatenate([xp.zeros_like(w), alt], axis=-1), xp.concatenate([w, axis], axis=-1))
    return normalize(q)
