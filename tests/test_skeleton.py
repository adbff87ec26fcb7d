"""Left/right pairing from joint names and hip/shoulder discovery."""

import numpy as np
import pytest

import jaxstyle as js

STYLE100 = ["Hips", "Chest", "Chest2", "Chest3", "Chest4", "Neck", "Head", "RightCollar", "RightShoulder",
            "RightElbow", "RightWrist", "LeftCollar", "LeftShoulder", "LeftElbow", "LeftWrist", "RightHip",
            "RightKnee", "RightAnkle", "RightToe", "LeftHip", "LeftKnee", "LeftAnkle", "LeftToe"]
CMU = ["Hips", "LHipJoint", "LeftUpLeg", "LeftLeg", "LeftFoot", "LeftToeBase", "RHipJoint", "RightUpLeg",
       "RightLeg", "RightFoot", "RightToeBase", "LowerBack", "Spine", "Spine1", "Neck", "Neck1", "Head",
       "LeftShoulder", "LeftArm", "LeftForeArm", "LeftHand", "LeftFingerBase", "LeftHandIndex1", "LThumb",
       "RightShoulder", "RightArm", "RightForeArm", "RightHand", "RightFingerBase", "RightHandIndex1", "RThumb"]
# The 3dsMax-friendly CMU release (cgspeed): mixed Left/L/l prefixes and lower-case spine names.
MAX_CMU = ["Hips", "LHipJoint", "LeftHip", "LeftKnee", "LeftAnkle", "LeftToe", "RHipJoint", "RightHip",
           "RightKnee", "RightAnkle", "RightToe", "lowerback", "Chest", "Chest2", "lowerneck", "Neck", "Head",
           "LeftCollar", "LeftShoulder", "LeftElbow", "LeftWrist", "lhand", "LFingers", "LThumb", "RightCollar",
           "RightShoulder", "RightElbow", "RightWrist", "rhand", "RFingers", "RThumb"]
OTHER = ["Bip01 Pelvis", "Bip01 L Thigh", "Bip01 R Thigh", "hip_l", "hip_r", "Hand.L", "Hand.R", "lShldr",
         "rShldr", "mixamorig:LeftArm", "mixamorig:RightArm", "Root", "LowerLeg"]


def _pair_names(names):
    pairs = js.mirror_pairs(names)
    assert np.array_equal(pairs[pairs], np.arange(len(names)))
    return {names[i]: names[j] for i, j in enumerate(pairs)}


@pytest.mark.parametrize("names", [STYLE100, CMU, MAX_CMU, OTHER], ids=["100style", "cmu", "3dsmax", "other"])
def test_every_sided_joint_gets_its_counterpart(names):
    mapping = _pair_names(names)
    for name, other in mapping.items():
        if name == other:
            continue
        # The counterpart is the same name with the side swapped.
        assert len(name) - len(other) in (-1, 0, 1)
    unpaired = {n for n, o in mapping.items() if n == o}
    expected_unpaired = {
        "100style": {"Hips", "Chest", "Chest2", "Chest3", "Chest4", "Neck", "Head"},
    }
    if names is STYLE100:
        assert unpaired == expected_unpaired["100style"]
    if names is MAX_CMU:
        assert mapping["lhand"] == "rhand" and mapping["LFingers"] == "RFingers" and mapping["lowerback"] == "lowerback"
    if names is OTHER:
        assert mapping["Bip01 L Thigh"] == "Bip01 R Thigh" and mapping["hip_l"] == "hip_r"
        assert mapping["Hand.L"] == "Hand.R" and mapping["lShldr"] == "rShldr"
        assert mapping["mixamorig:LeftArm"] == "mixamorig:RightArm"
        assert mapping["Root"] == "Root" and mapping["LowerLeg"] == "LowerLeg"
    if names is CMU:
        assert mapping["LHipJoint"] == "RHipJoint" and mapping["LThumb"] == "RThumb"
        assert mapping["LowerBack"] == "LowerBack"


def test_missing_counterpart_is_an_error():
    with pytest.raises(js.MotionDataError, match="LeftHand.*no counterpart 'RightHand'"):
        js.mirror_pairs(["Hips", "LeftHand"])


@pytest.mark.parametrize("names,hips,shoulders", [
    (STYLE100, ("LeftHip", "RightHip"), ("LeftShoulder", "RightShoulder")),
    (CMU, ("LeftUpLeg", "RightUpLeg"), ("LeftArm", "RightArm")),
    (MAX_CMU, ("LeftHip", "RightHip"), ("LeftShoulder", "RightShoulder")),
])
def test_find_hips_and_shoulders(names, hips, shoulders):
    assert js.find_hips_and_shoulders(names) == (hips, shoulders)


def test_find_hips_and_shoulders_names_what_is_missing():
    with pytest.raises(js.MotionDataError, match=r"left/right hips by name.*--joint-map FILE.*hips = \["):
        js.find_hips_and_shoulders(["Root", "Spine", "LeftArm", "RightArm"])
