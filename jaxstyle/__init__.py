"""jaxstyle: style-controllable character locomotion in JAX.

Reimplements Mason et al. 2018 (few-shot PFNN residual adapters) and Mason, Starke & Komura 2022
(local motion phases with FiLM). This module re-exports the public API.
"""

from jaxstyle import (
    controller,
    export,
    fetch,
    fewshot,
    film,
    footik,
    lpn,
    lpn_controller,
    metrics,
    paths,
    pfnn,
    pipeline,
    preview,
    procedural,
    quat,
    selection,
    style_models,
    synthesis,
    train_lpn,
)
from jaxstyle.batching import balanced_batches, contiguous_split
from jaxstyle.bvh import format_bvh, parse_bvh, read_bvh, write_bvh
from jaxstyle.character_frame import CharacterFrames, character_frames
from jaxstyle.contacts import FootContacts, FootJoints, estimate_units_per_meter, foot_contacts, joint_contacts
from jaxstyle.controller import rollout, rollout_batch, turning_path
from jaxstyle.data import default_mocap_dir, mocap_dir, read_phase_labels
from jaxstyle.errors import JaxstyleError, MotionDataError
from jaxstyle.export import rollout_motion, save_rollout
from jaxstyle.fewshot import SweepConfig, finetune_sweep, sweep_batches
from jaxstyle.film import FiLMConfig
from jaxstyle.kinematics import (
    bone_lengths,
    facing_directions,
    forward_kinematics,
    global_positions,
    global_transforms,
    motion_from_global,
    rest_positions,
    root_trajectory,
    skeleton_height,
)
from jaxstyle.local_phase import LocalPhases, local_phases
from jaxstyle.lpn_features import LPNFeatures, LPNLayout, decode_lpn, encode_lpn
from jaxstyle.metrics import MotionQuality, motion_quality, reference_quality
from jaxstyle.motion import Motion
from jaxstyle.normalise import Normaliser, fit_normaliser
from jaxstyle.paths import PathSignal
from jaxstyle.pfnn_features import PFNNLayout, decode_pfnn, encode_pfnn
from jaxstyle.phase import circular_distance, footsteps, global_phase
from jaxstyle.selection import RolloutCheck, SweepResult, fewshot_sweep, load_adapter, write_report
from jaxstyle.sinusoid import SinusoidFit, fit_sinusoids, fit_windows
from jaxstyle.skeleton import find_feet_and_hands, find_hips_and_shoulders, mirror_pairs
from jaxstyle.style_models import StyleModelConfig
from jaxstyle.train_lpn import FiLMFinetuneConfig, LPNTrainConfig
from jaxstyle.transform import mirror, resample, rotate, scale, set_up_axis

__version__ = "0.1.0"

__all__ = [
    "CharacterFrames",
    "FiLMConfig",
    "FiLMFinetuneConfig",
    "FootContacts",
    "FootJoints",
    "JaxstyleError",
    "LPNFeatures",
    "LPNLayout",
    "LPNTrainConfig",
    "LocalPhases",
    "Motion",
    "MotionDataError",
    "MotionQuality",
    "Normaliser",
    "PFNNLayout",
    "PathSignal",
    "RolloutCheck",
    "SinusoidFit",
    "StyleModelConfig",
    "SweepConfig",
    "SweepResult",
    "balanced_batches",
    "bone_lengths",
    "character_frames",
    "circular_distance",
    "contiguous_split",
    "controller",
    "decode_lpn",
    "decode_pfnn",
    "default_mocap_dir",
    "encode_lpn",
    "encode_pfnn",
    "estimate_units_per_meter",
    "export",
    "fetch",
    "facing_directions",
    "fewshot",
    "fewshot_sweep",
    "film",
    "find_feet_and_hands",
    "find_hips_and_shoulders",
    "finetune_sweep",
    "fit_normaliser",
    "fit_sinusoids",
    "fit_windows",
    "foot_contacts",
    "footik",
    "footsteps",
    "format_bvh",
    "forward_kinematics",
    "global_phase",
    "global_positions",
    "global_transforms",
    "joint_contacts",
    "load_adapter",
    "local_phases",
    "lpn",
    "lpn_controller",
    "metrics",
    "mirror",
    "mirror_pairs",
    "mocap_dir",
    "motion_from_global",
    "motion_quality",
    "parse_bvh",
    "paths",
    "pfnn",
    "pipeline",
    "preview",
    "procedural",
    "quat",
    "read_bvh",
    "read_phase_labels",
    "reference_quality",
    "resample",
    "rest_positions",
    "rollout",
    "rollout_batch",
    "rollout_motion",
    "root_trajectory",
    "rotate",
    "save_rollout",
    "scale",
    "selection",
    "set_up_axis",
    "skeleton_height",
    "style_models",
    "sweep_batches",
    "synthesis",
    "train_lpn",
    "turning_path",
    "write_bvh",
    "write_report",
]
