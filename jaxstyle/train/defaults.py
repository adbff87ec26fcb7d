"""Defaults shared by both papers' workflows, in one place and free of JAX, so the command line can
show them in ``--help`` without loading a numerical library."""

import dataclasses

DEFAULT_RATES: tuple[float, ...] = (0.3, 0.5, 0.7)
"""The few-shot dropout rates of Mason et al. 2018 (their code's keep probabilities 0.7 / 0.5 / 0.3)."""

LEARN_EPOCHS = 100
"""Fine-tuning epochs of a style learned live in ``jaxstyle play``: the sweep's own default
(``jaxstyle.mason2018.fewshot.SweepConfig.epochs``). Measured by ``python benchmarks/play.py
--learn`` on the demo base (10 s clip): 100 epochs are playable within 30 s of the upload and their
chosen rate validates better than 40 epochs' (docs/play.md)."""

FILM_DEFAULT_RATES: tuple[float, ...] = (0.1, 0.3, 0.5)
"""Dropout rates of the 2022 FiLM generator sweep: lower than the 2018 adapters'
(:data:`DEFAULT_RATES`), the generator being trained with 0.3."""


CHOOSE_EPOCHS = 3
"""How many of a run's last epochs ``jaxstyle.mason2022.synthesis.choose_epoch`` compares (a run
folder keeps the last 3); ``jaxstyle lpn --choose-epoch``'s default."""

PHASE_FLOOR = 0.75
"""The runtime's default floor on each limb's local-phase advance, as a fraction of the style's
capture rate (:func:`jaxstyle.control.lpn_phases.floored_phases`,
:func:`jaxstyle.control.lpn_phases.capture_phase_rate`): 0 is the paper's runtime. 0.75
is the lower edge of the band (within 25% of the capture's rate) a stepping character's phases
should keep; measured on the demo's 100STYLE styles against 0.5 (docs/mason2022.md, "The closed loop:
why it froze"), so the phase rate of a character run with it is not independent evidence
that it steps: its steps per second, skating and style distance are."""

FOOT_SMOOTH = 0.1
"""The 2022 runtime's default weight of the ankles' and toes' predicted positions in the blend
``s P + (1 - s)(p + V)`` it carries each frame (the other joints :data:`BODY_SMOOTH`; 0.5 on every
joint, :data:`jaxstyle.control.loop.JOINT_SMOOTH`, is the paper's runtime;
:meth:`jaxstyle.control.lpn_controller.StyleNetModel.create`). Not in the paper: teacher-forced,
the network's velocity head moves a planted foot about 0.3 m/s and its position head about 2.4 m/s
(capture 0.09), so the feet follow their velocities. Chosen among 0, 0.05, 0.1, 0.2 and 0.5 on three
demo-size models (8 epochs, seeds 0-2) by their summed median raw skating (0.1 and 0.2 lowest,
0 makes the feet float), then checked on models it was not chosen on: the 4- and 16-epoch ones
of the same protocol and the paper-size model, on the quality benchmark's protocol too
(docs/mason2022.md, "Feet that slide")."""

BODY_SMOOTH = 0.2
"""The 2022 runtime's default weight of every other bone's predicted position in the same blend
(:data:`FOOT_SMOOTH` on the feet; :meth:`jaxstyle.control.lpn_controller.StyleNetModel.create`'s
``body_smooth``; 0.5, :data:`jaxstyle.control.loop.JOINT_SMOOTH`, is the paper's runtime). Not in
the paper: fed its own poses along captured clips, the paper-size network stills Drunk's pose with
the paper's blend, and carrying the bones more by their predicted velocities gives much of the
motion back on one of the two clips (docs/mason2022.md). 0.2 rather than 0.1 by the
rule that chose :data:`FOOT_SMOOTH` (the lower summed median raw skating on the three 8- and the
three 16-epoch demo-size models); against 0.5, on the nine 4-, 8- and 16-epoch demo-size models it
is about even (summed raw skating 39.2 against 41.4, 36 against 37 rows stepping), while on the
paper-size model (where it was found) Drunk steps and the quality protocol's LPN FiLM rows slide
and step closer to their captures (docs/mason2022.md, "Why Drunk glides")."""


@dataclasses.dataclass(frozen=True)
class RolloutCheck:
    """The closed-loop check of a fine-tuned new style, both papers' (the 2018 adapters' in
    :mod:`jaxstyle.mason2018.selection`, the 2022 FiLM generators' in
    :func:`jaxstyle.mason2022.finetune.closed_loop_check`): the controller drives the style
    ``seconds`` along a path turning at ``turn_deg_per_s`` at the clip's median speed, from a frame
    of the clip. It passes when the rollout stays finite, the bones keep their lengths (mean
    relative error at most ``max_bone_error``), the feet touch the floor at least
    ``min_contact_ratio`` times as often as in the clip, they slide at most ``max_skating_ratio``
    times (+ ``skating_slack_m_s``) as fast as the model before fine-tuning does on the same path,
    and the character covers between ``min_progress`` and ``1 / min_progress`` of the path's length
    (for styles that move)."""

    seconds: float = 5.0
    turn_deg_per_s: float = 45.0
    max_bone_error: float = 0.10
    min_contact_ratio: float = 0.5
    max_skating_ratio: float = 1.5
    skating_slack_m_s: float = 0.05
    min_progress: float = 0.5
    tolerance_m: float = 0.03


ROLLOUT_FIELDS = ("finite", "bone_error", "contact_fraction", "skating_m_s", "progress", "passed")
"""The per-(style, rate) figures of a :class:`RolloutCheck`, in report order."""
