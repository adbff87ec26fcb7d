"""jaxstyle: style-controllable character locomotion in JAX.

Reimplements Mason et al. 2018 (few-shot PFNN residual adapters) and Mason, Starke & Komura 2022
(local motion phases with FiLM). The packages, from the bottom layer up (pyproject.toml holds the
contract that import-linter checks):

- motion: the Motion clip, BVH, quaternions, kinematics, transforms, skeleton roles;
- labels: foot contacts, global phase, local phases;
- data: locating and fetching capture, procedural clips, both papers' features, datasets;
- nn: the networks of both papers as pure functions (and Flax NNX modules over them); train: checkpoints
  and run logs;
- control: paths, the shared closed loop, the CharacterModel interface and both papers' models of it;
  output: driving characters, export, foot locking, previews, metrics, synthesis, the quality benchmark;
- mason2018 and mason2022: each paper's workflows; cli: the jaxstyle command.

import jaxstyle is light: the names below load from their modules on first use.
"""

from jaxstyle._lazy import lazy_module

__version__ = "0.1.0"

_SUBPACKAGES = ["cli", "control", "data", "labels", "mason2018", "mason2022", "motion", "nn", "output", "train",
                "errors", "timing"]

_NAMES = {
    "BaseSettings": "mason2018.base_model",
    "Character": "output.drive",
    "CharacterModel": "control.model",
    "CharacterFrames": "motion.character_frame",
    "ContactConfig": "labels.contacts",
    "Course": "output.drive",
    "FiLMConfig": "nn.film_generator",
    "FiLMFinetuneConfig": "mason2022.finetune",
    "FootContacts": "labels.contacts",
    "FootJoints": "labels.contacts",
    "FootstepConfig": "labels.phase",
    "JaxstyleError": "errors",
    "LPNFeatures": "data.lpn_features",
    "LPNFiLMModule": "nn.modules",
    "LPNLayout": "data.lpn_features",
    "LPNTrainConfig": "mason2022.train",
    "LocalPhaseConfig": "labels.local_phase",
    "LocalPhases": "labels.local_phase",
    "Motion": "motion.clip",
    "MotionDataError": "errors",
    "MotionQuality": "output.metrics",
    "Normaliser": "data.normalise",
    "PFNNLayout": "data.pfnn_features",
    "PFNNModel": "control.controller",
    "PFNNModule": "nn.modules",
    "PathSignal": "control.paths",
    "RolloutCheck": "train.defaults",
    "SinusoidConfig": "labels.sinusoid",
    "SinusoidFit": "labels.sinusoid",
    "StyleModelConfig": "nn.style_models",
    "StyleNetModel": "control.lpn_controller",
    "SweepConfig": "mason2018.fewshot",
    "SweepResult": "mason2018.selection",
    "balanced_batches": "data.batching",
    "blend_character": "output.drive",
    "adapter_sweep": "mason2018.fewshot",
    "bone_lengths": "motion.kinematics",
    "build_lpn_dataset": "data.datasets",
    "build_pfnn_dataset": "data.datasets",
    "character_frames": "motion.character_frame",
    "circular_distance": "labels.phase",
    "contiguous_split": "data.batching",
    "decode_lpn": "data.lpn_features",
    "decode_pfnn": "data.pfnn_features",
    "default_mocap_dir": "data.locate",
    "drive": "output.drive",
    "encode_lpn": "data.lpn_features",
    "encode_pfnn": "data.pfnn_features",
    "estimate_units_per_meter": "labels.contacts",
    "facing_directions": "motion.kinematics",
    "fewshot_sweep": "mason2018.selection",
    "find_feet_and_hands": "motion.skeleton",
    "find_hips_and_shoulders": "motion.skeleton",
    "fit_normaliser": "data.normalise",
    "fit_sinusoids": "labels.sinusoid",
    "fit_windows": "labels.sinusoid",
    "foot_contacts": "labels.contacts",
    "footsteps": "labels.phase",
    "format_bvh": "motion.bvh",
    "forward_kinematics": "motion.kinematics",
    "global_phase": "labels.phase",
    "global_positions": "motion.kinematics",
    "global_transforms": "motion.kinematics",
    "grid_sweep": "train.scan",
    "joint_contacts": "labels.contacts",
    "load_adapter": "mason2018.sweep_files",
    "local_phases": "labels.local_phase",
    "mirror": "motion.transform",
    "mirror_pairs": "motion.skeleton",
    "mocap_dir": "data.locate",
    "motion_from_global": "motion.kinematics",
    "motion_quality": "output.metrics",
    "parse_bvh": "motion.bvh",
    "read_bvh": "motion.bvh",
    "read_phase_labels": "labels.phase",
    "reference_quality": "output.metrics",
    "resample": "motion.transform",
    "rest_positions": "motion.kinematics",
    "rollout": "control.model",
    "rollout_batch": "control.model",
    "rollout_motion": "output.export",
    "root_trajectory": "motion.kinematics",
    "rotate": "motion.transform",
    "run_sweep": "mason2018.pipeline",
    "save_rollout": "output.export",
    "scale": "motion.transform",
    "set_up_axis": "motion.transform",
    "skeleton_height": "motion.kinematics",
    "step_fn": "control.model",
    "sweep_batches": "train.scan",
    "synthesize": "output.synthesis",
    "train_base": "mason2018.base_model",
    "turning_path": "control.loop",
    "write_bvh": "motion.bvh",
    "write_report": "mason2018.sweep_files",
    "write_sweep": "mason2018.pipeline",
}

__all__ = sorted(_NAMES)

__getattr__, __dir__ = lazy_module(__name__, _SUBPACKAGES, _NAMES)
