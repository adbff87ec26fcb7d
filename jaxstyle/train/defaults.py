"""Defaults shared by both papers' workflows, in one place and free of JAX, so the command line can
show them in ``--help`` without loading a numerical library."""

DEFAULT_RATES: tuple[float, ...] = (0.3, 0.5, 0.7)
"""The few-shot dropout rates of Mason et al. 2018 (their code's keep probabilities 0.7 / 0.5 / 0.3)."""

FILM_DEFAULT_RATES: tuple[float, ...] = (0.1, 0.3, 0.5)
"""Dropout rates of the 2022 FiLM generator sweep: lower than the 2018 adapters'
(:data:`DEFAULT_RATES`), the generator being trained with 0.3."""
