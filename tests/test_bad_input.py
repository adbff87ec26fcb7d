"""Every kind of malformed BVH raises MotionDataError naming the file and the line."""

from __future__ import annotations

import re

import numpy as np
import pytest

import jaxstyle as js

VALID = """HIERARCHY
ROOT Hips
{
  OFFSET 0 0 0
  CHANNELS 6 Xposition Yposition Zposition Zrotation Yrotation Xrotation
  JOINT Leg
  {
    OFFSET 0 -10 0
    CHANNELS 3 Zrotation Yrotation Xrotation
    End Site
    {
      OFFSET 0 -10 0
    }
  }
}
MOTION
Frames: 3
Frame Time: 0.016667
0 90 0 0 0 0 10 0 0
1 90 0 0 5 0 20 0 0
2 90 0 0 10 0 30 0 0
"""
# Line numbers (1-based) in VALID.
CHANNELS_LINE, MOTION_LINE, FRAMES_LINE, FIRST_ROW, LAST_ROW = 9, 16, 17, 19, 21


def _replace_line(text, lineno, new):
    lines = text.split("\n")
    lines[lineno - 1] = new
    return "\n".join(lines)


def _expect_error(tmp_path, text, line, pattern):
    path = tmp_path / "bad.bvh"
    path.write_text(text)
    with pytest.raises(js.MotionDataError) as info:
        js.read_bvh(path)
    err = info.value
    message = str(err)
    assert str(path) in message, message
    assert err.path == str(path)
    if line is not None:
        assert f"line {line}:" in message, message
        assert err.line == line
    assert re.search(pattern, message), message
    return err


def test_valid_template_reads(tmp_path):
    path = tmp_path / "ok.bvh"
    path.write_text(VALID)
    motion = js.read_bvh(path)
    assert motion.num_frames == 3 and motion.fps == 60.0


def test_missing_file(tmp_path):
    with pytest.raises(js.MotionDataError, match=r"nope\.bvh: file not found"):
        js.read_bvh(tmp_path / "nope.bvh")


def test_directory_instead_of_file(tmp_path):
    with pytest.raises(js.MotionDataError, match="is a directory"):
        js.read_bvh(tmp_path)


@pytest.mark.parametrize("text", ["", "   \n\n"])
def test_empty_file(tmp_path, text):
    _expect_error(tmp_path, text, 1, "empty file")


def test_missing_hierarchy_section(tmp_path):
    text = VALID.split("\n", 1)[1]  # drop the HIERARCHY line
    _expect_error(tmp_path, text, 1, "HIERARCHY")


def test_missing_hierarchy_without_motion(tmp_path):
    _expect_error(tmp_path, "this is not a bvh file\n", 1, "HIERARCHY")


def test_missing_motion_section(tmp_path):
    text = VALID[: VALID.index("MOTION")]
    _expect_error(tmp_path, text, text.count("\n") + 1, "missing MOTION")


def test_fewer_rows_than_frames(tmp_path):
    text = VALID.replace("Frames: 3", "Frames: 5")
    _expect_error(tmp_path, text, LAST_ROW, r"'Frames: 5' but the file has only 3 motion rows")


def test_more_rows_than_frames(tmp_path):
    text = VALID.replace("Frames: 3", "Frames: 2")
    _expect_error(tmp_path, text, LAST_ROW, "more motion rows")


@pytest.mark.parametrize("row", ["1 90 0 0 5 0 20 0", "1 90 0 0 5 0 20 0 0 7"])
def test_row_with_wrong_number_of_values(tmp_path, row):
    text = _replace_line(VALID, FIRST_ROW + 1, row)
    _expect_error(tmp_path, text, FIRST_ROW + 1, r"motion row 2 has (8|10) values; the hierarchy has 9 channels")


def test_unknown_channel_name(tmp_path):
    text = _replace_line(VALID, CHANNELS_LINE, "    CHANNELS 3 Zrotation Wrotation Xrotation")
    _expect_error(tmp_path, text, CHANNELS_LINE, "unknown channel name 'Wrotation'")


@pytest.mark.parametrize("bad", ["nan", "NaN", "inf", "-inf", "1e999"])
def test_nan_or_inf_value(tmp_path, bad):
    text = _replace_line(VALID, LAST_ROW, f"2 90 0 0 10 {bad} 30 0 0")
    _expect_error(tmp_path, text, LAST_ROW, r"motion row 3 holds .* \(value 6\)")


def test_non_number_value(tmp_path):
    text = _replace_line(VALID, FIRST_ROW, "0 90 0 0 zero 0 10 0 0")
    _expect_error(tmp_path, text, FIRST_ROW, "non-number 'zero'")


@pytest.mark.parametrize("line,new,pattern", [
    (FRAMES_LINE, "Frames: three", "Frames must be a number"),
    (FRAMES_LINE + 1, "Frame Time: 0", "Frame Time must be a positive number"),
    (FRAMES_LINE, "Frame Time: 0.01", "expected 'Frames:'"),
    (4, "  OFFSET 0 0", "OFFSET needs 3 numbers"),
    (4, "  OFFSET 0 nan 0", "OFFSET holds NaN"),
    (CHANNELS_LINE, "    CHANNELS 4 Zrotation Yrotation Xrotation", "says 4 channels but lists 3"),
    (CHANNELS_LINE, "    CHANNELS 2 Zrotation Zrotation", "repeated channel"),
    (6, "  JOINT Hips", "duplicate joint name 'Hips'"),
    (6, "  BONE Leg", "unexpected token 'BONE'"),
])
def test_malformed_header_lines(tmp_path, line, new, pattern):
    _expect_error(tmp_path, _replace_line(VALID, line, new), line, pattern)


def test_unbalanced_braces(tmp_path):
    text = _replace_line(VALID, 14, "")  # drop the root's closing brace
    _expect_error(tmp_path, text, None, "unclosed")


def test_error_line_is_exact_in_a_real_file(mocap, tmp_path):
    lines = (mocap / "100style/Angry/Angry_FW.bvh").read_text().split("\n")
    motion_line = lines.index("MOTION") + 1
    target = motion_line + 3 + 4000  # the 4001st motion row
    values = lines[target - 1].split()
    values[17] = "nan"
    lines[target - 1] = " ".join(values)
    path = tmp_path / "Angry_FW.bvh"
    path.write_text("\n".join(lines))
    expected = rf"Angry_FW\.bvh, line {target}: motion row 4001 holds nan \(value 18\)"
    with pytest.raises(js.MotionDataError, match=expected):
        js.read_bvh(path)


def test_motion_rejects_inconsistent_arrays():
    motion = js.parse_bvh(VALID)
    with pytest.raises(js.MotionDataError, match="rotations has shape"):
        motion.replace(rotations=np.zeros((3, 5, 4)))
    with pytest.raises(js.MotionDataError, match="no joint named 'Arm'; joints are Hips, Leg"):
        motion.joint_index("Arm")


def test_error_is_a_value_error_and_project_error():
    with pytest.raises(ValueError):
        js.parse_bvh("")
    with pytest.raises(js.JaxstyleError):
        js.parse_bvh("")
