"""Preview renderings of character motion: animated GIF or MP4, and a still contact sheet.

Input is global joint positions in file units (Y up, the ground is the XZ plane at the floor
height), one ``(T, J, 3)`` array per character, with the skeleton's ``parents`` (``-1`` for the
root, parents before children). Several characters (say, one path in several styles) are drawn
side by side, one panel each. Every panel shows the skeleton (bones child -> parent, joints as
dots) with its shadow on the ground, a 1 m ground grid, the user's path when given and a fading
trail of the root's ground trajectory.

Drawing is a fixed oblique orthographic projection (:func:`project`) onto plain 2-D axes, which is
much faster than ``mplot3d``. The camera follows each character: the view is centred on its
root's ground position (smoothed over half a second so the hips' sway does not shake the world)
and keeps a fixed scale, so long paths stay in view. Artists are created once per panel and only
their data change from frame to frame.

Figures are made with :class:`matplotlib.figure.Figure` directly, so nothing here touches pyplot
or the global backend; GIFs need only Pillow, MP4s need ffmpeg.
"""

from __future__ import annotations

import dataclasses
import math
import os
from pathlib import Path
from typing import Sequence

import numpy as np
from matplotlib.animation import AbstractMovieWriter, FFMpegWriter, PillowWriter, writers
from matplotlib.collections import LineCollection
from matplotlib.colors import to_rgba
from matplotlib.figure import Figure
from PIL import Image
from tqdm import tqdm

YAW_DEG = 45.0
"""Default camera yaw about the vertical axis, degrees (0 looks along -Z with +X to the right)."""
ELEVATION_DEG = 25.0
"""Default camera elevation above the ground plane, degrees (90 looks straight down)."""
PANEL_COLORS = ("#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e", "#17becf", "#8c564b", "#e377c2")
"""Skeleton and trail colour of each character, in order, repeating after the last."""

_BACKGROUND = "#f5f5f2"
_GRID_COLOR = "#cfcfca"
_PATH_COLOR = "#6e6e6e"
_SHADOW_COLOR = (0.0, 0.0, 0.0, 0.18)
_TRAIL_SECONDS = 3.0
_CAMERA_SMOOTH_SECONDS = 0.5
_MIN_GIF_FRAME_MS = 20.0  # browsers play GIF frame delays under 20 ms as 100 ms
_TITLE_BAND_IN = 0.3  # inches above panels for titles


@dataclasses.dataclass(frozen=True)
class Drawing:
    """What :func:`render_gif`, :func:`render_mp4` and :func:`contact_sheet` draw besides the
    skeletons, and how: ``titles`` above the panels; ``paths``, one ``(N, 2)`` array of x, z ground
    points (or None) per character, drawn dashed; ``trails``, the root's ground trajectory of the
    last 3 s, fading out; ``units_per_meter`` sets the 1 m grid spacing; ``floor`` is the ground
    height (default: the lowest joint of any character); ``yaw`` / ``elevation`` the camera angles
    in degrees (:func:`project`); each panel is ``panel_size`` inches square (``None``: 3 in an
    animation, 2 in a contact sheet) at ``dpi``."""

    titles: Sequence[str] | None = None
    paths: Sequence[np.ndarray | None] | None = None
    trails: bool = True
    units_per_meter: float = 1.0
    floor: float | None = None
    yaw: float = YAW_DEG
    elevation: float = ELEVATION_DEG
    panel_size: float | None = None
    dpi: float = 80

    def prepared(self, characters, parents, fps):
        """The checked tracks, titles and camera of ``characters`` (:func:`_prepare`)."""
        return _prepare(characters, parents, self.titles, self.paths, self.units_per_meter, self.floor, self.yaw,
                        self.elevation, _CAMERA_SMOOTH_SECONDS, fps)

    def panel(self, default: float) -> float:
        return default if self.panel_size is None else self.panel_size


def project(points_Nx3: np.ndarray, yaw: float = YAW_DEG, elevation: float = ELEVATION_DEG) -> np.ndarray:
    """Oblique orthographic projection of Y-up points onto screen coordinates ``(N, 2)``.

    The camera looks at the origin from direction ``(sin(yaw) cos(elev), sin(elev), cos(yaw) cos(elev))``
    (angles in degrees). Screen ``u`` runs along ``(cos(yaw), 0, -sin(yaw))``, so it never depends on
    height and vertical lines stay vertical; screen ``v`` is the camera's up vector. Equivalently
    ``[u, v]`` are the first two rows of ``Rx(elevation) @ Ry(-yaw)`` applied to each point. Extra
    leading axes are kept: ``(..., 3) -> (..., 2)``.
    """
    points = np.asarray(points_Nx3, dtype=float)
    if points.ndim < 1 or points.shape[-1] != 3:
        raise ValueError(f"points_Nx3 must have a last axis of size 3, got shape {points.shape}")
    cy, sy = math.cos(math.radians(yaw)), math.sin(math.radians(yaw))
    ce, se = math.cos(math.radians(elevation)), math.sin(math.radians(elevation))
    right_up_3x2 = np.array([[cy, -sy * se], [0.0, ce], [-sy, -cy * se]])
    return points @ right_up_3x2


# ----------------------------------------------------------------------------------------------------------------------
# input checks


def _check_characters(characters, parents) -> tuple[list[np.ndarray], np.ndarray]:
    if isinstance(characters, np.ndarray) and characters.ndim == 3:
        characters = [characters]  # a single (T, J, 3) array is one character
    characters = list(characters)
    if not characters:
        raise ValueError("characters is empty: give at least one (T, J, 3) positions array")
    parents_J = np.asarray(parents)
    if parents_J.ndim != 1 or parents_J.size == 0 or not np.issubdtype(parents_J.dtype, np.integer):
        raise ValueError(f"parents must be a non-empty 1-D integer array, got {parents_J.dtype} of shape "
                         f"{parents_J.shape}")
    index = np.arange(parents_J.size)
    if parents_J[0] != -1 or np.any(parents_J < -1) or np.any(parents_J[1:] >= index[1:]):
        raise ValueError("parents must have -1 for the root (joint 0) and put every parent before its child")
    checked = []
    for i, positions in enumerate(characters):
        positions_TxJx3 = np.asarray(positions, dtype=float)
        if positions_TxJx3.ndim != 3 or positions_TxJx3.shape[-1] != 3:
            raise ValueError(f"characters[{i}] must have shape (T, J, 3), got {positions_TxJx3.shape}")
        if positions_TxJx3.shape[0] == 0:
            raise ValueError(f"characters[{i}] has no frames")
        if positions_TxJx3.shape[1] != parents_J.size:
            raise ValueError(f"characters[{i}] has {positions_TxJx3.shape[1]} joints but parents has "
                             f"{parents_J.size} entries")
        bad_T = ~np.isfinite(positions_TxJx3).all(axis=(1, 2))
        if bad_T.any():
            raise ValueError(f"characters[{i}] has NaN or infinite positions, first at frame {int(np.argmax(bad_T))}")
        checked.append(positions_TxJx3)
    return checked, parents_J.astype(int)


def _check_titles(titles, count: int) -> list[str]:
    if titles is None:
        return [""] * count
    if isinstance(titles, str):
        raise ValueError("titles must be a sequence of strings, one per character, not a single string")
    titles = [str(t) for t in titles]
    if len(titles) != count:
        raise ValueError(f"titles has {len(titles)} entries for {count} characters")
    return titles


def _check_paths(paths, count: int) -> list[np.ndarray | None]:
    if paths is None:
        return [None] * count
    paths = list(paths)
    if len(paths) != count:
        raise ValueError(f"paths has {len(paths)} entries for {count} characters")
    checked: list[np.ndarray | None] = []
    for i, path in enumerate(paths):
        if path is None:
            checked.append(None)
            continue
        path_Nx2 = np.asarray(path, dtype=float)
        if path_Nx2.ndim != 2 or path_Nx2.shape[1] != 2 or path_Nx2.shape[0] == 0:
            raise ValueError(f"paths[{i}] must have shape (N, 2) of x, z ground points, got {path_Nx2.shape}")
        if not np.isfinite(path_Nx2).all():
            raise ValueError(f"paths[{i}] has NaN or infinite points")
        checked.append(path_Nx2)
    return checked


def _check_positive(name: str, value: float) -> float:
    value = float(value)
    if not (math.isfinite(value) and value > 0):
        raise ValueError(f"{name} must be a positive number, got {value}")
    return value


def _check_count(name: str, value: int) -> int:
    if isinstance(value, bool) or int(value) != value or value < 1:
        raise ValueError(f"{name} must be an integer >= 1, got {value!r}")
    return int(value)


# ----------------------------------------------------------------------------------------------------------------------
# scene: everything projected once, per character


class _View:
    """Camera settings shared by all panels of one figure: angles, window size, ground grid."""

    def __init__(self, tracks: list[np.ndarray], floor: float | None, units_per_meter: float, yaw: float,
                 elevation: float):
        self.yaw, self.elevation, self.meter = float(yaw), float(elevation), units_per_meter
        self.floor = float(min(p[..., 1].min() for p in tracks)) if floor is None else float(floor)
        height = max(float((p[..., 1].max(axis=1) - self.floor).max()) for p in tracks)
        self.half_width = 0.9 * max(height, 0.5 * units_per_meter)
        width = 2.0 * self.half_width
        self.xlim = (-self.half_width, self.half_width)
        self.ylim = (-0.37 * width, 0.63 * width)
        # ground seen inside the window, as a square around the camera centre, in whole metres
        ground = width * (1.0 + 0.6 / max(math.sin(math.radians(abs(self.elevation))), 0.15))
        self.grid_lines = int(math.ceil(ground / units_per_meter))

    def grid_segments(self, centre_x: float, centre_z: float) -> np.ndarray:
        """Projected 1 m grid lines around a ground point, relative to that point's projection: (L, 2, 2)."""
        m = self.meter
        ks_x = np.arange(math.floor(centre_x / m) - self.grid_lines, math.ceil(centre_x / m) + self.grid_lines + 1)
        ks_z = np.arange(math.floor(centre_z / m) - self.grid_lines, math.ceil(centre_z / m) + self.grid_lines + 1)
        reach = self.grid_lines * m
        lines_x = np.zeros((ks_x.size, 2, 3))  # lines along Z at x = k metres
        lines_x[:, :, 0] = ks_x[:, None] * m
        lines_x[:, :, 2] = centre_z + np.array([-reach, reach])
        lines_z = np.zeros((ks_z.size, 2, 3))  # lines along X at z = k metres
        lines_z[:, :, 2] = ks_z[:, None] * m
        lines_z[:, :, 0] = centre_x + np.array([-reach, reach])
        lines = np.concatenate([lines_x, lines_z])
        lines[:, :, 1] = self.floor
        origin = np.array([centre_x, self.floor, centre_z])
        return project(lines - origin, self.yaw, self.elevation)


def _smooth(values_TxD: np.ndarray, window: int) -> np.ndarray:
    """Centred moving average with edge padding (window 1 returns the input)."""
    if window <= 1 or values_TxD.shape[0] < 2:
        return values_TxD
    half = window // 2
    padded = np.pad(values_TxD, ((half, half), (0, 0)), mode="edge")
    kernel = np.ones(2 * half + 1) / (2 * half + 1)
    return np.stack([np.convolve(padded[:, d], kernel, mode="valid") for d in range(values_TxD.shape[1])], axis=1)


class _Track:
    """One character's motion projected to the screen, relative to a camera that follows its root."""

    def __init__(self, positions_TxJx3: np.ndarray, parents_J: np.ndarray, path_Nx2: np.ndarray | None, view: _View,
                 smooth_frames: int):
        self.num_frames = positions_TxJx3.shape[0]
        root = int(np.flatnonzero(parents_J == -1)[0])
        self.bones = np.flatnonzero(parents_J >= 0)
        self.bone_parents = parents_J[self.bones]
        root_xz_Tx2 = positions_TxJx3[:, root][:, [0, 2]]
        self.camera_xz_Tx2 = _smooth(root_xz_Tx2, smooth_frames)
        camera_Tx3 = np.stack([self.camera_xz_Tx2[:, 0], np.full(self.num_frames, view.floor),
                               self.camera_xz_Tx2[:, 1]], axis=1)
        yaw, elev = view.yaw, view.elevation
        self.camera_uv_Tx2 = project(camera_Tx3, yaw, elev)
        self.joints_uv_TxJx2 = project(positions_TxJx3, yaw, elev) - self.camera_uv_Tx2[:, None]
        shadow = positions_TxJx3.copy()
        shadow[..., 1] = view.floor
        self.shadow_uv_TxJx2 = project(shadow, yaw, elev) - self.camera_uv_Tx2[:, None]
        self.root_uv_Tx2 = project(np.stack([root_xz_Tx2[:, 0], np.full(self.num_frames, view.floor),
                                             root_xz_Tx2[:, 1]], axis=1), yaw, elev)
        self.path_uv_Nx2 = None
        if path_Nx2 is not None:
            path_Nx3 = np.stack([path_Nx2[:, 0], np.full(len(path_Nx2), view.floor), path_Nx2[:, 1]], axis=1)
            self.path_uv_Nx2 = project(path_Nx3, yaw, elev)


def _prepare(characters, parents, titles, paths, units_per_meter, floor, yaw, elevation, smooth_seconds, fps):
    tracks, parents_J = _check_characters(characters, parents)
    titles = _check_titles(titles, len(tracks))
    paths = _check_paths(paths, len(tracks))
    units_per_meter = _check_positive("units_per_meter", units_per_meter)
    if floor is not None and not math.isfinite(float(floor)):
        raise ValueError(f"floor must be a finite number or None, got {floor}")
    view = _View(tracks, floor, units_per_meter, yaw, elevation)
    smooth_frames = 1 if fps is None else max(1, int(round(smooth_seconds * fps)))
    scene = [_Track(p, parents_J, path, view, smooth_frames) for p, path in zip(tracks, paths, strict=True)]
    return scene, titles, view


# ----------------------------------------------------------------------------------------------------------------------
# drawing


class _Panel:
    """The artists of one character in one axes, created once; :meth:`show` moves them to a frame."""

    def __init__(self, ax, track: _Track, view: _View, color, *, trails: bool, trail_frames: int | None,
                 fps: float | None):
        self.track, self.view, self.ax = track, view, ax
        self.trail_frames, self.fps = trail_frames, fps
        ax.set_facecolor(_BACKGROUND)
        ax.set_xlim(*view.xlim)
        ax.set_ylim(*view.ylim)
        ax.set_xticks([])
        ax.set_yticks([])
        for spine in ax.spines.values():
            spine.set_color("#b0b0aa")
        self.grid = LineCollection([], colors=_GRID_COLOR, linewidths=0.6, zorder=1)
        ax.add_collection(self.grid, autolim=False)
        self.path = None
        if track.path_uv_Nx2 is not None:
            (self.path,) = ax.plot([], [], color=_PATH_COLOR, lw=1.0, ls="--", zorder=2)
        self.trail = None
        if trails:
            self.trail_rgba = np.array(to_rgba(color))
            self.trail = LineCollection([], linewidths=1.6, zorder=3)
            ax.add_collection(self.trail, autolim=False)
        self.shadow = LineCollection([], colors=[_SHADOW_COLOR], linewidths=2.0, zorder=4, capstyle="round")
        ax.add_collection(self.shadow, autolim=False)
        self.bones = LineCollection([], colors=color, linewidths=2.2, zorder=5, capstyle="round")
        ax.add_collection(self.bones, autolim=False)
        (self.joints,) = ax.plot([], [], ls="none", marker="o", ms=2.5, color=color, zorder=6)
        self.label = ax.text(0.03, 0.03, "", transform=ax.transAxes, fontsize=7, color="#555555", zorder=7)

    def show(self, frame: int) -> None:
        """Update every artist to ``frame`` (frames past the end hold the last one)."""
        track = self.track
        t = min(frame, track.num_frames - 1)
        camera_uv = track.camera_uv_Tx2[t]
        self.grid.set_segments(self.view.grid_segments(*track.camera_xz_Tx2[t]))
        if self.path is not None:
            rel = track.path_uv_Nx2 - camera_uv
            self.path.set_data(rel[:, 0], rel[:, 1])
        if self.trail is not None:
            start = 0 if self.trail_frames is None else max(0, t - self.trail_frames)
            points = track.root_uv_Tx2[start:t + 1] - camera_uv
            segments = np.stack([points[:-1], points[1:]], axis=1)
            colors = np.tile(self.trail_rgba, (len(segments), 1))
            colors[:, 3] = np.linspace(0.05, 0.9, len(segments))  # older is fainter
            self.trail.set_segments(segments)
            self.trail.set_color(colors)
        joints = track.joints_uv_TxJx2[t]
        self.bones.set_segments(np.stack([joints[track.bones], joints[track.bone_parents]], axis=1))
        shadow = track.shadow_uv_TxJx2[t]
        self.shadow.set_segments(np.stack([shadow[track.bones], shadow[track.bone_parents]], axis=1))
        self.joints.set_data(joints[:, 0], joints[:, 1])
        text = f"frame {t}"
        if self.fps is not None:
            text += f"  {t / self.fps:.2f} s"
        if frame != t:
            text += " (end)"
        self.label.set_text(text)


def _trail_frames(fps: float | None) -> int | None:
    return None if fps is None else max(2, int(round(_TRAIL_SECONDS * fps)))


# ----------------------------------------------------------------------------------------------------------------------
# animation (GIF and MP4 share this)


class _RealTimePillowWriter(PillowWriter):
    """A PillowWriter whose GIF plays in real time.

    GIF delays are whole centiseconds and :class:`PillowWriter` truncates ``1000 / fps`` ms (a 30 fps
    clip drawn every 2nd frame would play at 60 ms instead of 66.7 ms). Here frame ``k`` lasts from
    ``k / fps`` to ``(k + 1) / fps`` rounded to 10 ms, so delays alternate where needed and the total
    never drifts by more than 5 ms.
    """

    def finish(self):
        frames = getattr(self, "_frames", None)
        if not frames:
            return super().finish()
        bounds = np.round(np.arange(len(frames) + 1) * 100.0 / self.fps) * 10.0
        durations = [int(d) for d in np.diff(bounds)]
        frames = _shared_palette(frames)
        frames[0].save(self.outfile, save_all=True, append_images=frames[1:], duration=durations, loop=0)


def _shared_palette(frames: list[Image.Image]) -> list[Image.Image]:
    """Map RGB frames onto one palette made from the first, middle and last frames.

    Pillow would otherwise run an adaptive quantisation per frame, which costs more than drawing
    it; the scene has few colours (background, grid, one per character and their blends), so one
    palette fits every frame and mapping onto it is about twenty times faster.
    """
    if any(frame.mode != "RGB" for frame in frames):
        return frames
    width, height = frames[0].size
    picks = [frames[0], frames[len(frames) // 2], frames[-1]]
    sample = Image.new("RGB", (width, height * len(picks)))
    for k, frame in enumerate(picks):
        sample.paste(frame, (0, height * k))
    palette = sample.quantize(colors=256, dither=Image.Dither.NONE)
    return [frame.quantize(palette=palette, dither=Image.Dither.NONE) for frame in frames]


def _animate(path, writer: AbstractMovieWriter, scene: list[_Track], titles: list[str], view: _View, *, fps: float,
             every: int, trails: bool, dpi: float, panel_size: float, progress: bool) -> Path:
    """Draw the panels frame by frame into ``writer`` (the one animation builder behind GIF and MP4)."""
    count = len(scene)
    fig = Figure(figsize=(count * panel_size, panel_size + _TITLE_BAND_IN), dpi=dpi, facecolor="white")
    axes_height = panel_size / (panel_size + _TITLE_BAND_IN)
    panels = []
    for i, (track, title) in enumerate(zip(scene, titles, strict=True)):
        ax = fig.add_axes((i / count, 0.0, 1.0 / count, axes_height))
        panels.append(_Panel(ax, track, view, PANEL_COLORS[i % len(PANEL_COLORS)], trails=trails,
                             trail_frames=_trail_frames(fps), fps=fps))
        if title:
            fig.text((i + 0.5) / count, (1.0 + axes_height) / 2, title, ha="center", va="center", fontsize=10)
    num_frames = max(track.num_frames for track in scene)
    shown = range(0, num_frames, every)
    with writer.saving(fig, os.fspath(path), dpi):
        for frame in tqdm(shown, total=len(shown), disable=not progress, unit="frame", desc=Path(path).name):
            for panel in panels:
                panel.show(frame)
            writer.grab_frame()
    return Path(path)


def _check_animation_args(fps, every, dpi, panel_size) -> tuple[float, int]:
    fps = _check_positive("fps", fps)
    every = _check_count("every", every)
    _check_positive("dpi", dpi)
    _check_positive("panel_size", panel_size)
    return fps, every


def render_gif(path: str | os.PathLike, characters: Sequence[np.ndarray], parents: np.ndarray, fps: float,
               drawing: Drawing = Drawing(), *, every: int = 2, progress: bool = False) -> Path:
    """Write an animated GIF of the characters side by side (Pillow only, no ffmpeg) and return its path.

    ``characters`` is a sequence of ``(T, J, 3)`` global positions (a single array is one character);
    shorter clips hold their last frame. ``parents (J,)`` is the skeleton. ``drawing``: titles,
    paths, trails, grid, camera and panel size (:class:`Drawing`). Every ``every``-th frame is drawn
    and the GIF keeps real time: frames last ``1000 * every / fps`` ms on average (GIF delays are in
    10 ms steps, so they alternate when needed). GIFs cannot show frames shorter than 20 ms, so
    ``1000 * every / fps`` must be at least 20. ``progress`` shows a tqdm bar over frames.
    """
    panel_size = drawing.panel(3.0)
    fps, every = _check_animation_args(fps, every, drawing.dpi, panel_size)
    frame_ms = 1000.0 * every / fps
    if frame_ms < _MIN_GIF_FRAME_MS:
        raise ValueError(f"every={every} at fps={fps:g} gives {frame_ms:.1f} ms GIF frames; browsers play frames "
                         f"under 20 ms too slowly, so use every >= {math.ceil(_MIN_GIF_FRAME_MS * fps / 1000)}")
    scene, titles, view = drawing.prepared(characters, parents, fps)
    return _animate(path, _RealTimePillowWriter(fps=fps / every), scene, titles, view, fps=fps, every=every,
                    trails=drawing.trails, dpi=drawing.dpi, panel_size=panel_size, progress=progress)


def render_mp4(path: str | os.PathLike, characters: Sequence[np.ndarray], parents: np.ndarray, fps: float,
               drawing: Drawing = Drawing(), *, every: int = 2, progress: bool = False) -> Path:
    """Write the same animation as :func:`render_gif` as an MP4 through ffmpeg and return its path.

    The video runs at ``fps / every`` frames per second. Raises ``RuntimeError`` when matplotlib
    cannot find ffmpeg (``render_gif`` needs no ffmpeg).
    """
    panel_size = drawing.panel(3.0)
    fps, every = _check_animation_args(fps, every, drawing.dpi, panel_size)
    scene, titles, view = drawing.prepared(characters, parents, fps)
    if not writers.is_available("ffmpeg"):
        raise RuntimeError("ffmpeg was not found, so render_mp4 cannot write MP4; render_gif needs no ffmpeg")
    return _animate(path, FFMpegWriter(fps=fps / every), scene, titles, view, fps=fps, every=every,
                    trails=drawing.trails, dpi=drawing.dpi, panel_size=panel_size, progress=progress)


# ----------------------------------------------------------------------------------------------------------------------
# still frames


def contact_sheet(path: str | os.PathLike, characters: Sequence[np.ndarray], parents: np.ndarray,
                  drawing: Drawing = Drawing(), *, frames: int = 6, fps: float | None = None) -> Path:
    """Write a PNG grid of still frames, one row per character, and return its path.

    Columns are ``frames`` evenly spaced frames from the first to the last of the longest clip (fewer
    when the clip is shorter than that); each cell is drawn as in :func:`render_gif` (``drawing``,
    :class:`Drawing`; cells 2 inches square unless it says) and labelled with its frame index, and
    each row's title sits above it. With ``fps`` the label also gives the time and the trail covers
    the last 3 s (otherwise everything before the frame) and the camera is smoothed as in the GIF.
    """
    frames = _check_count("frames", frames)
    dpi, panel_size, trails = drawing.dpi, drawing.panel(2.0), drawing.trails
    _check_positive("dpi", dpi)
    _check_positive("panel_size", panel_size)
    if fps is not None:
        fps = _check_positive("fps", fps)
    scene, titles, view = drawing.prepared(characters, parents, fps)
    num_frames = max(track.num_frames for track in scene)
    columns = min(frames, num_frames)
    shown = np.round(np.linspace(0, num_frames - 1, columns)).astype(int)
    rows = len(scene)
    row_height = panel_size + _TITLE_BAND_IN
    fig = Figure(figsize=(columns * panel_size, rows * row_height), dpi=dpi, facecolor="white")
    cell_w, cell_h = 1.0 / columns, panel_size / (rows * row_height)
    for r, (track, title) in enumerate(zip(scene, titles, strict=True)):
        bottom = (rows - 1 - r) * row_height / (rows * row_height)
        color = PANEL_COLORS[r % len(PANEL_COLORS)]
        for c, frame in enumerate(shown):
            ax = fig.add_axes((c * cell_w, bottom, cell_w, cell_h))
            _Panel(ax, track, view, color, trails=trails, trail_frames=_trail_frames(fps), fps=fps).show(int(frame))
        if title:
            fig.text(0.01, bottom + cell_h + 0.5 * _TITLE_BAND_IN / (rows * row_height), title, ha="left",
                     va="center", fontsize=10)
    fig.savefig(os.fspath(path), dpi=dpi, format="png", facecolor="white")
    return Path(path)
