"""Training machinery shared by both papers: the masked Adam scan and sweep batch plans, checkpoints and run logs."""

from jaxstyle._lazy import lazy_module

__getattr__, __dir__ = lazy_module(__name__, ["checkpoint", "defaults", "runlog", "scan", "shard"])
