"""Robustness of the BVH reader against hostile or sloppy files.

Regression tests for the robustness issue (a long first motion row blowing up memory, a UTF-8 BOM
refused, absurd values accepted) and property-based fuzzing: any mutation of a real file either
parses to the same motion (whitespace, line endings, BOM) or raises ``MotionDataError`` naming the
file, never another exception type, and never hangs.
"""

from __future__ import annotations

import os
import random
import time
import tracemalloc
from datetime import timedelta

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import jaxstyle as js
from jaxstyle.motion import transform
from jaxstyle.motion.bvh import MAX_ABS_VALUE, frame_rate

SMALL = "xia/angry_18_000.bvh"  # 31 joints, 96 channels, 80 frames
N_FRAMES = 30  # the fuzzed copy is cut to this many frames, for speed
SOURCE = "fuzz.bvh"

FUZZ = settings(max_examples=200, derandomize=True, database=None, deadline=timedelta(seconds=2),
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])


# ----------------------------------------------------------------------------------------- helpers

def _lines(mocap) -> list[str]:
    return (mocap / SMALL).read_text().rstrip("\n").split("\n")


def _motion_start(lines: list[str]) -> int:
    """0-based index of the MOTION line."""
    return next(i for i, line in enumerate(lines) if line.strip() == "MOTION")


@pytest.fixture(scope="module")
def small_lines(mocap) -> list[str]:
    """The small real file cut to N_FRAMES frames, as lines (no newlines)."""
    lines = _lines(mocap)
    m = _motion_start(lines)
    return lines[:m + 1] + [f"Frames: {N_FRAMES}", lines[m + 2]] + lines[m + 3:m + 3 + N_FRAMES]


@pytest.fixture(scope="module")
def small_motion(small_lines) -> js.Motion:
    return js.parse_bvh("\n".join(small_lines) + "\n", source=SOURCE)


def assert_same_motion(a: js.Motion, b: js.Motion) -> None:
    assert a.names == b.names
    assert a.channels == b.channels
    assert a.fps == b.fps
    for field in ("parents", "offsets", "rotations", "local_positions", "end_site_parents", "end_site_offsets"):
        np.testing.assert_array_equal(getattr(a, field), getattr(b, field), err_msg=field)


def _parse_or_error(text: str | bytes, n_lines: int):
    """Parses; returns the Motion or the MotionDataError. Any other exception fails the test."""
    try:
        return js.parse_bvh(text, source=SOURCE)
    except js.MotionDataError as e:
        assert str(e).startswith(SOURCE), str(e)
        assert isinstance(e, js.JaxstyleError) and isinstance(e, ValueError)
        assert e.line is None or 1 <= e.line <= n_lines + 1, (e.line, n_lines, str(e))
        return e


def _with_first_row(mocap, tmp_path, row: str, index: int = 0):
    lines = _lines(mocap)
    first_row = _motion_start(lines) + 3
    lines[first_row + index] = row
    path = tmp_path / "long_row.bvh"
    path.write_text("\n".join(lines) + "\n")
    return path, first_row + index + 1  # 1-based line


def _bounded_read(path):
    """read_bvh's outcome, seconds taken, and peak traced memory (bytes)."""
    tracemalloc.start()
    start = time.perf_counter()
    try:
        outcome = js.read_bvh(path)
    except js.MotionDataError as e:
        outcome = e
    elapsed = time.perf_counter() - start
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    return outcome, elapsed, peak


# ------------------------------------------------------------------------- 1. long rows, fast failure

def test_huge_first_motion_row_fails_fast_in_bounded_memory(mocap, tmp_path):
    # On the old reader pandas took the width of the first row for every row: 100,000 values in
    # the first row of an 80-frame file cost 6 s and 380 MB (2.5 M values: 22 GB).
    path, line = _with_first_row(mocap, tmp_path, " ".join(["1.5"] * 100_000))
    error, elapsed, peak = _bounded_read(path)
    assert isinstance(error, js.MotionDataError)
    assert str(error) == (f"{path}, line {line}: motion row 1 has 100000 values; the hierarchy has 96 channels")
    assert elapsed < 5.0
    assert peak < 100 * 2**20, f"peak traced memory {peak / 2**20:.0f} MB"


def test_huge_later_motion_row_fails_fast_too(mocap, tmp_path):
    path, line = _with_first_row(mocap, tmp_path, " ".join(["1.5"] * 100_000), index=5)
    error, elapsed, peak = _bounded_read(path)
    assert isinstance(error, js.MotionDataError)
    assert str(error).startswith(f"{path}, line {line}: motion row 6 has 100000 values")
    assert elapsed < 5.0 and peak < 100 * 2**20


def test_first_row_with_a_huge_run_of_spaces_parses_in_bounded_memory(mocap, tmp_path):
    # The right number of values, but 100,000 spaces between two of them: splitting on single
    # spaces would make 100,000 columns for every row.
    lines = _lines(mocap)
    first_row = _motion_start(lines) + 3
    expected = js.read_bvh(mocap / SMALL)
    values = lines[first_row].split()
    lines[first_row] = values[0] + " " * 100_000 + " ".join(values[1:])
    path = tmp_path / "spaces.bvh"
    path.write_text("\n".join(lines) + "\n")
    motion, elapsed, peak = _bounded_read(path)
    assert isinstance(motion, js.Motion), motion
    assert_same_motion(motion, expected)
    assert elapsed < 5.0 and peak < 100 * 2**20


# ------------------------------------------------------------------- 2. BOM, CRLF and tabs accepted

@pytest.mark.parametrize("bom", [False, True])
@pytest.mark.parametrize("newline", ["\n", "\r\n", "\r"])
@pytest.mark.parametrize("tabs", [False, True])
def test_bom_line_endings_and_tabs_give_the_same_motion(mocap, tmp_path, bom, newline, tabs):
    text = (mocap / SMALL).read_text()
    if tabs:
        text = "\n".join("\t" + "\t \t".join(line.split()) + "\t" for line in text.split("\n"))
    data = (b"\xef\xbb\xbf" if bom else b"") + text.replace("\n", newline).encode()
    path = tmp_path / "variant.bvh"
    path.write_bytes(data)
    assert_same_motion(js.read_bvh(path), js.read_bvh(mocap / SMALL))


def test_bom_in_a_string_is_accepted(small_lines, small_motion):
    assert_same_motion(js.parse_bvh("\ufeff" + "\n".join(small_lines), source=SOURCE), small_motion)


# -------------------------------------------------------------------- 3. non-finite and absurd values

@pytest.mark.parametrize("bad,pattern", [
    ("nan", r"holds nan \(value 1\)"),
    ("inf", r"holds inf \(value 1\)"),
    ("-1e999", r"holds -1e999 \(value 1\)"),
    ("1e300", r"holds an absurd value 1e300 \(value 1; \|value\| must be <= 1e\+07\)"),
    ("-2e7", r"holds an absurd value -2e7 \(value 1;"),
])
def test_root_x_nonfinite_or_absurd_is_refused(mocap, tmp_path, bad, pattern):
    lines = _lines(mocap)
    target = _motion_start(lines) + 3 + 10  # the 11th motion row; value 1 is the root's Xposition
    values = lines[target].split()
    values[0] = bad
    lines[target] = " ".join(values)
    path = tmp_path / "absurd.bvh"
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(js.MotionDataError, match=rf"absurd\.bvh, line {target + 1}: motion row 11 {pattern}"):
        js.read_bvh(path)


def test_values_at_the_bound_are_accepted(small_lines):
    lines = list(small_lines)
    target = _motion_start(lines) + 3
    values = lines[target].split()
    values[0] = repr(MAX_ABS_VALUE)
    lines[target] = " ".join(values)
    motion = js.parse_bvh("\n".join(lines), source=SOURCE)
    assert motion.local_positions[0, 0, 0] == MAX_ABS_VALUE


def test_absurd_offset_is_refused(small_lines):
    lines = list(small_lines)
    i = next(k for k, line in enumerate(lines) if line.strip().startswith("OFFSET"))
    lines[i] = "OFFSET 0 1e300 0"
    with pytest.raises(js.MotionDataError, match=rf"{SOURCE}, line {i + 1}: OFFSET holds an absurd value"):
        js.parse_bvh("\n".join(lines), source=SOURCE)


@pytest.mark.parametrize("frame_time", ["1e-320", "1e-300", "1e300", "2e7", "10", "1.5", "1e-7", "0.0009"])
def test_absurd_frame_time_is_refused(small_lines, tmp_path, frame_time):
    # 1e-320 used to overflow (fps = inf) with an OverflowError instead of MotionDataError.
    lines = list(small_lines)
    i = _motion_start(lines) + 2
    lines[i] = f"Frame Time: {frame_time}"
    with pytest.raises(js.MotionDataError, match=rf"{SOURCE}, line {i + 1}: Frame Time .* sane range"):
        js.parse_bvh("\n".join(lines), source=SOURCE)
    path = tmp_path / "ft.bvh"
    path.write_text("\n".join(lines))
    with pytest.raises(js.MotionDataError, match=rf"ft\.bvh, line {i + 1}: Frame Time"):
        frame_rate(path)


def test_huge_frame_count_is_a_clear_error(small_lines):
    lines = list(small_lines)
    i = _motion_start(lines) + 1
    lines[i] = f"Frames: {10**30}"
    with pytest.raises(js.MotionDataError, match=r"'Frames: 10{30}' but the file has only 30 motion rows"):
        js.parse_bvh("\n".join(lines), source=SOURCE)


# ------------------------------------------------------------------------------ 3. property fuzzing

_WHITESPACE = st.sampled_from([" ", "  ", "\t", " \t", "\t\t ", "    "])


@FUZZ
@given(seed=st.integers(0, 2**32 - 1), pool=st.lists(_WHITESPACE, min_size=1, max_size=4), bom=st.booleans(),
       newline=st.sampled_from(["\n", "\r\n"]), blank_lines=st.lists(st.integers(0, 10**6), max_size=4))
def test_whitespace_mutations_parse_to_the_same_motion(small_lines, small_motion, seed, pool, bom, newline,
                                                       blank_lines):
    rnd = random.Random(seed)  # which whitespace goes where (drawing thousands of choices would be slow)
    out = []
    for line in small_lines:
        tokens = line.split()
        text = rnd.choice(["", *pool]) + tokens[0]
        for tok in tokens[1:]:
            text += rnd.choice(pool) + tok
        out.append(text + rnd.choice(["", *pool]))
    for pos in blank_lines:
        out.insert(pos % (len(out) + 1), rnd.choice(["", *pool]))
    text = ("\ufeff" if bom else "") + newline.join(out) + rnd.choice(["", newline])
    motion = _parse_or_error(text.encode(), len(out))
    assert isinstance(motion, js.Motion), motion
    assert_same_motion(motion, small_motion)


def _number_positions(lines: list[str]) -> list[tuple[int, int]]:
    """(line, token) of every number in the file: OFFSETs, CHANNELS counts, Frames, Frame Time, rows."""
    out = []
    for i, line in enumerate(lines):
        for k, tok in enumerate(line.split()):
            try:
                float(tok)
            except ValueError:
                continue
            out.append((i, k))
    return out


_BAD_NUMBERS = ["nan", "NaN", "-nan", "inf", "-inf", "Infinity", "1e999", "-1e999", "1e300", "-1e300", "1e8",
                "-12345678901", "99999999999999999999999", "abc", "1.2.3", "0x10", "--1", "1e", "", "\x00", "\u00e9",
                "'", '"', "#"]


@FUZZ
@given(pick=st.integers(0, 10**9), bad=st.sampled_from(_BAD_NUMBERS))
def test_a_corrupted_number_raises_naming_its_line(small_lines, pick, bad):
    positions = _number_positions(small_lines)
    i, k = positions[pick % len(positions)]
    lines = list(small_lines)
    tokens = lines[i].split()
    tokens[k] = bad
    lines[i] = " ".join(tokens)
    error = _parse_or_error("\n".join(lines) + "\n", len(lines))
    assert isinstance(error, js.MotionDataError), f"line {i + 1} with {bad!r} parsed"
    if not lines[i].startswith("Frames:"):  # a too-large frame count is reported at the last row
        assert error.line == i + 1, str(error)


@FUZZ
@given(op=st.sampled_from(["delete", "duplicate", "swap", "truncate", "insert", "move"]),
       a=st.integers(0, 10**9), b=st.integers(0, 10**9), junk=st.text(max_size=12))
def test_structural_mutations_raise_only_the_project_error(small_lines, op, a, b, junk):
    lines = list(small_lines)
    first_row = _motion_start(lines) + 3
    i, j = a % len(lines), b % len(lines)
    text = "\n".join(lines) + "\n"
    if op == "delete":
        del lines[i]
    elif op == "duplicate":
        lines.insert(i, lines[i])
    elif op == "swap":
        lines[i], lines[j] = lines[j], lines[i]
    elif op == "move":
        lines.insert(j, lines.pop(i))
    if op in ("delete", "duplicate", "swap", "move"):
        text = "\n".join(lines) + "\n"
    elif op == "truncate":
        text = text[:a % (len(text) + 1)]
    else:
        pos = a % (len(text) + 1)
        text = text[:pos] + junk + text[pos:]
    outcome = _parse_or_error(text.encode(), text.count("\n") + 1)
    if op in ("delete", "duplicate") and i >= first_row:  # the frame count no longer matches
        assert isinstance(outcome, js.MotionDataError)
    if op == "swap" and min(i, j) >= first_row:  # rows in another order: a valid motion
        assert isinstance(outcome, js.Motion), outcome
    if op == "truncate" and "MOTION" not in text:
        assert isinstance(outcome, js.MotionDataError)


@FUZZ
@given(blob=st.binary(max_size=64), pos=st.integers(0, 10**9))
def test_random_bytes_raise_only_the_project_error(small_lines, blob, pos):
    data = ("\n".join(small_lines) + "\n").encode()
    pos %= len(data) + 1
    _parse_or_error(data[:pos] + blob + data[pos:], data.count(b"\n") + blob.count(b"\n") + blob.count(b"\r") + 1)



@pytest.mark.parametrize("frame_time, fps", [("1", 1.0), ("0.001", 1000.0), ("0.0083333", 120.0)])
def test_frame_times_at_the_bounds_are_read(small_lines, frame_time, fps):
    lines = list(small_lines)
    lines[_motion_start(lines) + 2] = f"Frame Time: {frame_time}"
    assert js.parse_bvh("\n".join(lines), source=SOURCE).fps == pytest.approx(fps)


def test_pipes_devices_and_large_files_are_refused_without_reading_them(small_lines, tmp_path, monkeypatch):
    fifo = tmp_path / "clip.bvh"
    os.mkfifo(fifo)  # no writer: opening it for reading the usual way would block forever
    for fn in (js.read_bvh, frame_rate):
        with pytest.raises(js.MotionDataError, match=r"clip\.bvh: is not a regular file"):
            fn(fifo)
        with pytest.raises(js.MotionDataError, match=r"/dev/zero: is not a regular file"):
            fn("/dev/zero")
    path = tmp_path / "big.bvh"
    path.write_text("\n".join(small_lines) + "\n")
    size = path.stat().st_size
    assert js.read_bvh(path, max_bytes=size).num_frames > 0
    with pytest.raises(js.MotionDataError, match=r"big\.bvh: is .* MB, more than the .* MB .*JAXSTYLE_MAX_BVH_MB"):
        js.read_bvh(path, max_bytes=size - 1)
    monkeypatch.setenv("JAXSTYLE_MAX_BVH_MB", str((size - 1) / 1e6))
    with pytest.raises(js.MotionDataError, match=r"big\.bvh: is"):
        js.read_bvh(path)
    monkeypatch.setenv("JAXSTYLE_MAX_BVH_MB", "nan")
    with pytest.raises(js.MotionDataError, match=r"JAXSTYLE_MAX_BVH_MB must be a positive number"):
        js.read_bvh(path)


def _chain_bvh(n_joints: int, frames: int = 2) -> str:
    lines = ["HIERARCHY", "ROOT j0", "{", "OFFSET 0 0 0",
             "CHANNELS 6 Xposition Yposition Zposition Zrotation Yrotation Xrotation"]
    for k in range(1, n_joints):
        lines += [f"JOINT j{k}", "{", "OFFSET 0 1 0", "CHANNELS 3 Zrotation Yrotation Xrotation"]
    lines += ["End Site", "{", "OFFSET 0 1 0", "}"] + ["}"] * n_joints
    row = " ".join(["0.5"] * (3 + 3 * n_joints))
    return "\n".join(lines + ["MOTION", f"Frames: {frames}", "Frame Time: 0.0333333"] + [row] * frames) + "\n"


def test_a_100000_joint_chain_parses_in_seconds():
    # the hierarchy and the rows are read in time linear in the joint count (a name list searched
    # per joint, and pandas with one column per value, made 40,000 joints take 14 s)
    text = _chain_bvh(100_000)
    t0 = time.perf_counter()
    motion = js.parse_bvh(text, source="chain.bvh")
    assert time.perf_counter() - t0 < 10.0
    assert motion.num_joints == 100_000 and motion.parents[-1] == 99_998
    np.testing.assert_allclose(motion.local_positions[:, 0], 0.5)
    # a wide row one value short is still refused with its line
    short = text.rsplit(" 0.5\n", 1)[0] + "\n"
    with pytest.raises(js.MotionDataError, match=r"chain\.bvh, line \d+: motion row 2 has 300002 values"):
        js.parse_bvh(short, source="chain.bvh")


def test_resampling_is_bounded():
    motion = js.parse_bvh(_chain_bvh(3, frames=10), source="slow.bvh").replace(fps=2.0)
    assert transform.resample(motion, 16.0).num_frames == 73
    with pytest.raises(js.MotionDataError, match=r"slow\.bvh: the clip runs at 2 frames/s; resampling it to 60 .*8x"):
        transform.resample(motion, 60.0)


def test_joint_names_are_read_from_the_hierarchy_alone(small_lines, tmp_path):
    from jaxstyle.motion.bvh import read_joint_names

    path = tmp_path / "clip.bvh"
    path.write_text("\n".join(small_lines) + "\n")
    names = js.read_bvh(path).names
    assert read_joint_names(path) == names and len(names) > 20
    # the motion block is not read: a damaged one does not matter; a missing MOTION line does
    m = _motion_start(small_lines)
    path.write_text("\n".join(small_lines[:m + 1]) + "\nFrames: x\n")
    assert read_joint_names(path) == names
    path.write_text("\n".join(small_lines[:m]) + "\n")
    with pytest.raises(js.MotionDataError, match=r"clip\.bvh, line \d+: missing MOTION section"):
        read_joint_names(path)
