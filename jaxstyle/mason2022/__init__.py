"""Mason, Starke & Komura 2022 workflows: training the Table 2 style models and fine-tuning the FiLM generator."""

from jaxstyle._lazy import lazy_module

__getattr__, __dir__ = lazy_module(__name__, ["styledata", "loss", "train", "finetune", "pipeline", "synthesis",
                                                   "report"])
