"""Preview rendering: the projection, GIF frames and timing, panels, contact sheet, MP4 and input checks."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from matplotlib.animation import writers
from matplotlib.colors import to_rgb
from PIL import Image

from jaxstyle.output import preview

# hips, left knee, left foot, right knee, right foot; units are metres
PARENTS = np.array([-1, 0, 1, 0, 3])
FPS = 25.0
DPI = 40
PANEL = 2.0  # inches, so 80-pixel panels at DPI
SMALL = preview.Drawing(dpi=DPI, panel_size=PANEL)


def walker(T: int, *, speed: float = 1.0, swing: float = 0.35, phase: float = 0.0) -> np.ndarray:
    """A 5-joint biped walking along +X at ``speed`` m/s, legs swinging sinusoidally, feet on y=0."""
    t = np.arange(T) / FPS
    angle = swing * np.sin(2 * np.pi * 1.0 * t + phase)
    pos = np.zeros((T, 5, 3))
    pos[:, 0] = np.stack([speed * t, np.full(T, 0.9), np.zeros(T)], axis=1)
    for side, sign, (knee, foot) in ((-1, 1, (1, 2)), (1, -1, (3, 4))):
        a = sign * angle
        pos[:, knee] = pos[:, 0] + np.stack([0.45 * np.sin(a), np.full(T, -0.45), np.full(T, 0.1 * side)], axis=1)
        pos[:, foot] = pos[:, knee] + np.stack([0.45 * np.sin(a), np.full(T, -0.45), np.zeros(T)], axis=1)
    pos[..., 1] -= pos[..., 1].min()
    return pos


def circle(n: int = 64, radius: float = 2.0) -> np.ndarray:
    a = np.linspace(0, 2 * np.pi, n)
    return np.stack([radius * np.sin(a), radius * (1 - np.cos(a))], axis=1)


def gif_frames(path) -> tuple[list[np.ndarray], list[int]]:
    """All frames of a GIF as RGB arrays, with each frame's duration in ms."""
    frames, durations = [], []
    with Image.open(path) as im:
        for k in range(im.n_frames):
            im.seek(k)
            durations.append(im.info["duration"])
            frames.append(np.asarray(im.convert("RGB"), dtype=int))
    return frames, durations


def panel(frame: np.ndarray, index: int, count: int) -> np.ndarray:
    """The pixels of panel ``index`` of ``count`` side by side (title band included)."""
    width = frame.shape[1] // count
    return frame[:, index * width:(index + 1) * width]


def changed(a: np.ndarray, b: np.ndarray) -> float:
    """Fraction of pixels whose colour differs by more than 40 levels in some channel."""
    return float((np.abs(a - b).max(axis=-1) > 40).mean())


# ----------------------------------------------------------------------------------------------------------------------
# projection


def rot_x(deg):
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def rot_y(deg):
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


@pytest.mark.parametrize("yaw, elevation", [(0, 0), (45, 25), (-30, 60), (120, 10), (200, 90)])
def test_project_is_camera_rotation(yaw, elevation):
    # turn the world by -yaw about Y, tilt it by the elevation about X, keep screen x and y
    points_Nx3 = np.random.default_rng(0).normal(size=(7, 3))
    expected = (rot_x(elevation) @ rot_y(-yaw) @ points_Nx3.T).T[:, :2]
    np.testing.assert_allclose(preview.project(points_Nx3, yaw, elevation), expected, atol=1e-12)


def test_project_known_views():
    p = np.array([[1.0, 2.0, 3.0], [-0.5, 0.0, 4.0]])
    np.testing.assert_allclose(preview.project(p, 0, 0), p[:, [0, 1]], atol=1e-12)  # front: x right, y up
    np.testing.assert_allclose(preview.project(p, 90, 0), np.stack([-p[:, 2], p[:, 1]], 1), atol=1e-12)  # from +X
    np.testing.assert_allclose(preview.project(p, 0, 90), np.stack([p[:, 0], -p[:, 2]], 1), atol=1e-12)  # top
    # the camera direction collapses to the screen origin; the default view is yaw 45, elevation 25
    d = np.array([[math.sin(math.radians(45)) * math.cos(math.radians(25)), math.sin(math.radians(25)),
                   math.cos(math.radians(45)) * math.cos(math.radians(25))]])
    np.testing.assert_allclose(preview.project(d), 0.0, atol=1e-12)


@pytest.mark.parametrize("yaw", [0.0, 33.0, 90.0, 145.0, -70.0])
def test_vertical_lines_stay_vertical(yaw):
    rng = np.random.default_rng(1)
    base = rng.normal(size=(5, 3))
    top = base + np.array([0.0, 1.7, 0.0])
    for elevation in (0.0, 25.0, 70.0):
        du_dv = preview.project(top, yaw, elevation) - preview.project(base, yaw, elevation)
        np.testing.assert_allclose(du_dv[:, 0], 0.0, atol=1e-12)
        np.testing.assert_allclose(du_dv[:, 1], 1.7 * math.cos(math.radians(elevation)), atol=1e-12)


def test_project_is_orthographic_and_keeps_leading_axes():
    m_3x2 = preview.project(np.eye(3), 37.0, 21.0)
    np.testing.assert_allclose(m_3x2.T @ m_3x2, np.eye(2), atol=1e-12)  # orthonormal screen axes
    assert preview.project(np.zeros((4, 6, 3))).shape == (4, 6, 2)


# ----------------------------------------------------------------------------------------------------------------------
# GIF


def test_gif_frame_count_duration_and_width(tmp_path):
    T, every = 23, 2
    one = preview.render_gif(tmp_path / "one.gif", [walker(T)], PARENTS, FPS, SMALL, every=every)
    three = preview.render_gif(tmp_path / "three.gif", [walker(T)] * 3, PARENTS, FPS,
                               dataclasses.replace(SMALL, titles=["a", "b", "c"], paths=[circle(), None, circle()]),
                               every=every)
    for path in (one, three):
        frames, durations = gif_frames(path)
        assert len(frames) == math.ceil(T / every) == 12
        assert durations == [80] * 12  # 1000 * 2 / 25 ms
    with Image.open(one) as a, Image.open(three) as b:
        assert a.size[0] == round(PANEL * DPI)
        assert b.size[0] == 3 * a.size[0]
        assert a.size[1] == b.size[1]


def test_gif_keeps_real_time_when_frames_are_not_whole_centiseconds(tmp_path):
    # 30 fps, every frame: 33.3 ms each, which a GIF can only approximate in 10 ms steps
    T = 31
    path = preview.render_gif(tmp_path / "w.gif", [walker(T)], PARENTS, 30.0, SMALL, every=1)
    _, durations = gif_frames(path)
    assert len(durations) == T
    assert set(durations) <= {30, 40}
    for k in range(1, T + 1):  # every frame starts within 5 ms of its true time
        assert abs(sum(durations[:k]) - 1000.0 * k / 30.0) <= 5.0


def test_gif_panels_show_their_own_character(tmp_path):
    a, b = walker(20), walker(20, swing=0.7, phase=1.5)
    ab, _ = gif_frames(preview.render_gif(tmp_path / "ab.gif", [a, b], PARENTS, FPS, SMALL))
    aa, _ = gif_frames(preview.render_gif(tmp_path / "aa.gif", [a, a], PARENTS, FPS, SMALL))
    for k in (2, 5, 8):
        # the same character in the same place gives the same pixels, another one visibly different pixels
        assert changed(panel(ab[k], 0, 2), panel(aa[k], 0, 2)) < 0.001
        assert changed(panel(ab[k], 1, 2), panel(aa[k], 1, 2)) > 0.005


def test_gif_camera_follows_the_character(tmp_path):
    T = 50  # 2 s at 1.5 m/s: 3 m, more than a panel's width
    path = preview.render_gif(tmp_path / "f.gif", [walker(T, speed=1.5)], PARENTS, FPS,
                              dataclasses.replace(SMALL, trails=False, dpi=2 * DPI), every=1)
    frames, _ = gif_frames(path)
    colour = np.array(to_rgb(preview.PANEL_COLORS[0])) * 255
    for k in (0, T // 2, T - 1):
        skeleton = np.abs(frames[k] - colour).max(axis=-1) < 50
        assert skeleton.sum() > 50
        centre_x = np.nonzero(skeleton)[1].mean()
        assert abs(centre_x / frames[k].shape[1] - 0.5) < 0.1, (k, centre_x)


def test_gif_shorter_clip_holds_its_last_frame(tmp_path):
    frames, _ = gif_frames(preview.render_gif(tmp_path / "h.gif", [walker(20), walker(9)], PARENTS, FPS, SMALL))
    assert len(frames) == 10
    # output frames 6 and 9 show input frames 12 and 18: the 9-frame clip is held, the other moves on
    assert changed(panel(frames[6], 1, 2), panel(frames[9], 1, 2)) == 0.0
    assert changed(panel(frames[6], 0, 2), panel(frames[9], 0, 2)) > 0.0


def test_gif_progress_bar_only_when_asked(tmp_path, capsys):
    tiny = dataclasses.replace(SMALL, panel_size=1.0)
    preview.render_gif(tmp_path / "q.gif", [walker(4)], PARENTS, FPS, tiny)
    assert capsys.readouterr().err == ""
    preview.render_gif(tmp_path / "p.gif", [walker(4)], PARENTS, FPS, tiny, progress=True)
    assert "2/2" in capsys.readouterr().err


# ----------------------------------------------------------------------------------------------------------------------
# contact sheet and MP4


def test_contact_sheet_size_follows_rows_and_columns(tmp_path):
    chars = [walker(30), walker(30, swing=0.6)]
    wide = preview.contact_sheet(tmp_path / "wide.png", chars[:1], PARENTS, SMALL, frames=6)
    tall = preview.contact_sheet(tmp_path / "tall.png", chars, PARENTS,
                                 dataclasses.replace(SMALL, titles=["slow", "big steps"], paths=[circle(), None]),
                                 frames=3, fps=FPS)
    with Image.open(wide) as w, Image.open(tall) as t:
        assert w.format == t.format == "PNG"
        assert w.size[0] == 6 * round(PANEL * DPI) and t.size[0] == 3 * round(PANEL * DPI)
        assert abs(t.size[1] - 2 * w.size[1]) <= 1
        sheet = np.asarray(w.convert("RGB"), dtype=int)
    cell = round(PANEL * DPI)
    cells = [sheet[:, c * cell:(c + 1) * cell] for c in range(6)]
    assert all(changed(cells[c], cells[c + 1]) > 0.0 for c in range(5))  # different frames, different cells


def test_contact_sheet_columns_capped_by_clip_length(tmp_path):
    path = preview.contact_sheet(tmp_path / "short.png", [walker(3)], PARENTS, SMALL, frames=6)
    with Image.open(path) as im:
        assert im.size[0] == 3 * round(PANEL * DPI)


@pytest.mark.skipif(not writers.is_available("ffmpeg"), reason="ffmpeg not installed; the error branch is tested")
def test_mp4_written_with_ffmpeg(tmp_path):
    path = preview.render_mp4(tmp_path / "a.mp4", [walker(20)] * 2, PARENTS, FPS, SMALL)
    data = path.read_bytes()
    assert data[4:8] == b"ftyp" and len(data) > 1000


@pytest.mark.skipif(writers.is_available("ffmpeg"), reason="ffmpeg is installed; the writing branch is tested")
def test_mp4_without_ffmpeg_raises(tmp_path):
    with pytest.raises(RuntimeError, match="ffmpeg was not found.*render_gif needs no ffmpeg"):
        preview.render_mp4(tmp_path / "a.mp4", [walker(20)], PARENTS, FPS)
    assert not (tmp_path / "a.mp4").exists()


# ----------------------------------------------------------------------------------------------------------------------
# bad input


def _with_nan(frame: int, value: float = np.nan) -> np.ndarray:
    pos = walker(10)
    pos[frame, 2, 1] = value
    return pos


BAD_INPUTS = [
    ({"characters": [np.zeros((10, 3))]}, r"characters\[0\] must have shape \(T, J, 3\)"),
    ({"characters": [walker(10), np.zeros((10, 5, 2))]}, r"characters\[1\] must have shape \(T, J, 3\)"),
    ({"characters": [walker(10)[:, :4]]}, r"characters\[0\] has 4 joints but parents has 5"),
    ({"characters": [walker(10), _with_nan(3)]}, r"characters\[1\] has NaN or infinite positions, first at frame 3"),
    ({"characters": [_with_nan(7, np.inf)]}, r"characters\[0\] has NaN or infinite positions, first at frame 7"),
    ({"characters": []}, r"characters is empty"),
    ({"characters": [np.zeros((0, 5, 3))]}, r"characters\[0\] has no frames"),
    ({"titles": ["only one"]}, r"titles has 1 entries for 2 characters"),
    ({"paths": [circle()]}, r"paths has 1 entries for 2 characters"),
    ({"paths": [circle(), np.zeros((4, 3))]}, r"paths\[1\] must have shape \(N, 2\)"),
    ({"parents": np.array([-1, 2, 0, 0, 3])}, r"parents must have -1 for the root"),
    ({"units_per_meter": 0.0}, r"units_per_meter must be a positive number"),
]


@pytest.mark.parametrize("change, message", BAD_INPUTS)
@pytest.mark.parametrize("render", ["gif", "sheet"])
def test_bad_input_names_the_argument(tmp_path, render, change, message):
    drawn = {k: v for k, v in change.items() if k in ("titles", "paths", "units_per_meter")}  # Drawing's fields
    args = {"characters": [walker(10), walker(10)], "parents": PARENTS,
            **{k: v for k, v in change.items() if k not in drawn}, "drawing": preview.Drawing(**drawn)}
    with pytest.raises(ValueError, match=message):
        if render == "gif":
            preview.render_gif(tmp_path / "x.gif", fps=FPS, **args)
        else:
            preview.contact_sheet(tmp_path / "x.png", **args)
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize("change, message", [
    ({"every": 0}, r"every must be an integer >= 1"),
    ({"every": 1.5}, r"every must be an integer >= 1"),
    ({"fps": 0.0}, r"fps must be a positive number"),
    ({"fps": 100.0, "every": 1}, r"every=1 at fps=100 gives 10.0 ms GIF frames.*every >= 2"),
])
def test_bad_animation_settings(tmp_path, change, message):
    args = {"fps": FPS, **change}
    with pytest.raises(ValueError, match=message):
        preview.render_gif(tmp_path / "x.gif", [walker(10)], PARENTS, **args)
    if "fps" not in change or change["fps"] <= 0:  # MP4 has no GIF frame-length limit
        with pytest.raises(ValueError, match=message):
            preview.render_mp4(tmp_path / "x.mp4", [walker(10)], PARENTS, **args)


def test_bad_contact_sheet_frames(tmp_path):
    with pytest.raises(ValueError, match=r"frames must be an integer >= 1"):
        preview.contact_sheet(tmp_path / "x.png", [walker(10)], PARENTS, frames=0)
