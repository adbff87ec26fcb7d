"""Training machinery shared by both papers: checkpoints and run logs."""

from jaxstyle._lazy import lazy_module

__getattr__, __dir__ = lazy_module(__name__, ["checkpoint", "runlog"])
