"""User control signals: where the character should go, frame by frame.

A :class:`PathSignal` is what a user's joystick (or a script) gives the runtime of both papers
(Holden et al. 2017 section 6, followed by Mason et al. 2018 section 7.1 and Mason et al. 2022
section 4.4): per frame a desired ground velocity and a facing direction. Its ``positions`` are
where the character would stand if it followed the signal exactly, which is what the path error of
:mod:`jaxstyle.output.metrics` measures against.

Builders for the usual test paths, all in metres and seconds (``units_per_meter`` scales them to
the skeleton's file units; 100STYLE is in centimetres): :func:`straight`, :func:`circle`,
:func:`zigzag`, :func:`stop_and_go`, :func:`speed_ramp`, and :func:`waypoints` (walk a polyline at
a given speed, then stop). Yaw is the rotation about +Y that takes +Z onto the facing direction,
so a yaw ``a`` faces ``(sin a, cos a)`` in (x, z), as in :mod:`jaxstyle.motion.character_frame`.

:func:`jaxstyle.control.loop.path_controls` turns a signal into the per-frame trajectory samples the
networks read.
"""

from __future__ import annotations

from typing import Callable, NamedTuple

import numpy as np


class PathSignal(NamedTuple):
    """Per frame ``t``: desired ground ``velocity (T, 2)`` (x, z, units per second) and facing ``yaw
    (T,)`` (radians) of the step from frame ``t`` to ``t + 1``, and the ideal ground ``positions (T,
    2)`` after that step, integrating the velocity from ``(0, 0)``. A rollout's generated frame
    ``t`` (its ``origin[t]``, the character after step ``t``) should be at ``positions[t]``."""

    velocity: np.ndarray
    yaw: np.ndarray
    positions: np.ndarray
    fps: float


def from_velocity(velocity_Tx2, fps: float, yaw_T=None, start_yaw: float = 0.0) -> PathSignal:
    """A signal from a velocity per frame; ``yaw_T`` defaults to the direction of travel, held while
    the character stands still (``start_yaw`` before it first moves)."""
    v = np.asarray(velocity_Tx2, dtype=np.float64)
    if v.ndim != 2 or v.shape[1] != 2 or len(v) == 0:
        raise ValueError(f"velocity must be (T, 2) with T >= 1, got {v.shape}")
    if not np.isfinite(v).all():
        raise ValueError("velocity must be finite")
    if fps <= 0:
        raise ValueError(f"fps must be positive, got {fps}")
    if yaw_T is None:
        moving = np.linalg.norm(v, axis=1) > 1e-9
        yaw = np.where(moving, np.arctan2(v[:, 0], v[:, 1]), np.nan)
        yaw[0] = yaw[0] if moving[0] else start_yaw
        idx = np.where(np.isnan(yaw), 0, np.arange(len(yaw)))
        yaw = np.unwrap(yaw[np.maximum.accumulate(idx)])  # hold the last heading while stopped
    else:
        yaw = np.asarray(yaw_T, dtype=np.float64)
        if yaw.shape != (len(v),) or not np.isfinite(yaw).all():
            raise ValueError(f"yaw must be finite with shape ({len(v)},), got {yaw.shape}")
    positions = np.cumsum(v / fps, axis=0)
    return PathSignal(v, yaw, positions, float(fps))


def _heading(yaw):
    return np.stack([np.sin(yaw), np.cos(yaw)], axis=-1)


def _frames(seconds: float, fps: float) -> int:
    n = int(round(seconds * fps))
    if n < 1:
        raise ValueError(f"a path needs at least one frame, got {seconds} s at {fps} fps")
    return n


def straight(seconds: float, speed: float, *, fps: float = 60.0, heading: float = 0.0,
             units_per_meter: float = 1.0) -> PathSignal:
    """Walk straight at ``speed`` m/s along the direction ``heading`` (yaw, radians; 0 is +Z)."""
    n = _frames(seconds, fps)
    v = np.broadcast_to(speed * units_per_meter * _heading(np.float64(heading)), (n, 2))
    return from_velocity(v, fps, np.full(n, heading, np.float64))


def circle(seconds: float, speed: float, radius: float, *, fps: float = 60.0, reverse: bool = False,
           units_per_meter: float = 1.0) -> PathSignal:
    """Walk a circle of ``radius`` m at ``speed`` m/s, facing the direction of travel: the yaw grows
    at ``speed / radius`` rad/s (from +Z towards +X), or falls with ``reverse``."""
    if radius <= 0:
        raise ValueError(f"radius must be positive, got {radius}")
    n = _frames(seconds, fps)
    rate = (-1.0 if reverse else 1.0) * speed / radius
    yaw = rate * np.arange(n) / fps
    return from_velocity(speed * units_per_meter * _heading(yaw), fps, yaw)


def zigzag(seconds: float, speed: float, *, fps: float = 60.0, period: float = 2.0, angle_deg: float = 45.0,
           units_per_meter: float = 1.0) -> PathSignal:
    """Walk along +Z, switching every ``period / 2`` s between ``+angle`` and ``-angle`` headings."""
    n = _frames(seconds, fps)
    t = np.arange(n) / fps
    sign = np.where(np.floor(2 * t / period) % 2 == 0, 1.0, -1.0)
    yaw = np.deg2rad(angle_deg) * sign
    return from_velocity(speed * units_per_meter * _heading(yaw), fps, yaw)


def stop_and_go(seconds: float, speed: float, *, fps: float = 60.0, go: float = 2.0, stop: float = 1.0,
                heading: float = 0.0, units_per_meter: float = 1.0) -> PathSignal:
    """Walk ``go`` s, stand ``stop`` s, and repeat, along the direction ``heading``, facing it."""
    n = _frames(seconds, fps)
    t = np.arange(n) / fps
    moving = np.mod(t, go + stop) < go
    v = np.where(moving[:, None], speed * units_per_meter * _heading(np.float64(heading)), 0.0)
    return from_velocity(v, fps, np.full(n, heading, np.float64))


def speed_ramp(seconds: float, start_speed: float, end_speed: float, *, fps: float = 60.0, heading: float = 0.0,
               units_per_meter: float = 1.0) -> PathSignal:
    """Walk straight while the speed changes linearly from ``start_speed`` to ``end_speed`` m/s."""
    n = _frames(seconds, fps)
    speed = np.linspace(start_speed, end_speed, n)
    v = speed[:, None] * units_per_meter * _heading(np.float64(heading))
    return from_velocity(v, fps, np.full(n, heading, np.float64))


def waypoints(points_Nx2, speed: float, *, fps: float = 60.0, seconds: float | None = None,
              units_per_meter: float = 1.0) -> PathSignal:
    """Walk the polyline ``points (N, 2)`` (x, z in metres, starting where the character stands:
    the points are taken relative to the first) at ``speed`` m/s, then stand still, facing the last
    direction of travel. ``seconds`` defaults to the walk plus one second of standing."""
    p = np.asarray(points_Nx2, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 2 or len(p) < 2:
        raise ValueError(f"waypoints must be (N, 2) with N >= 2, got {p.shape}")
    if not np.isfinite(p).all():
        raise ValueError("waypoints must be finite")
    if speed <= 0:
        raise ValueError(f"speed must be positive, got {speed}")
    seg = np.diff(p, axis=0)
    seg_len = np.linalg.norm(seg, axis=1)
    if not (seg_len > 0).all():
        raise ValueError("consecutive waypoints must differ")
    total = seg_len.sum()
    n = _frames(total / speed + 1.0 if seconds is None else seconds, fps)
    # arc length reached at the start of each frame, and the segment being walked
    s = np.minimum(np.arange(n) * speed / fps, total)
    ends = np.cumsum(seg_len)
    k = np.minimum(np.searchsorted(ends, s, side="right"), len(seg) - 1)
    direction = seg[k] / seg_len[k, None]
    walking = (np.arange(n) + 1) * speed / fps <= total + 1e-9
    v = np.where(walking[:, None], direction * speed, 0.0)
    # the last partial step lands exactly on the final point
    last = np.flatnonzero(~walking)
    if len(last):
        rest = total - (last[0]) * speed / fps
        v[last[0]] = direction[last[0]] * rest * fps
    yaw = np.unwrap(np.arctan2(direction[:, 0], direction[:, 1]))
    return from_velocity(v * units_per_meter, fps, yaw)


def _waypoint_path(seconds: float, speed: float, **kw) -> PathSignal:
    """A zigzag polyline of 45-degree bends, sized so walking it at ``speed`` takes 7/8 of
    ``seconds``, then standing: (0, 0), (0, a), (a, 2a), (a, 3a) metres."""
    a = max(speed, 1e-3) * 7.0 / 8.0 * seconds / (2.0 + np.sqrt(2.0))
    return waypoints(np.array([[0.0, 0.0], [0.0, a], [a, 2 * a], [a, 3 * a]]), max(speed, 1e-3), seconds=seconds, **kw)


PATHS: dict[str, Callable[..., PathSignal]] = {
    "straight": lambda seconds, speed, **kw: straight(seconds, speed, **kw),
    "circle": lambda seconds, speed, **kw: circle(seconds, speed, radius=2.0, **kw),
    "zigzag": lambda seconds, speed, **kw: zigzag(seconds, speed, **kw),
    "stop_and_go": lambda seconds, speed, **kw: stop_and_go(seconds, speed, **kw),
    "speed_ramp": lambda seconds, speed, **kw: speed_ramp(seconds, 0.5 * speed, 1.5 * speed, **kw),
    "waypoints": _waypoint_path,
}
"""The named test paths of ``experiments/synthesize.py``: ``PATHS[name](seconds, speed, fps=...,
units_per_meter=...)``."""


def named(name: str, seconds: float, speed: float, **kwargs) -> PathSignal:
    """One of :data:`PATHS` by name (a clear error naming the known ones otherwise)."""
    if name not in PATHS:
        raise KeyError(f"unknown path {name!r}; known: {', '.join(PATHS)}")
    return PATHS[name](seconds, speed, **kwargs)
