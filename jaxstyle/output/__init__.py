"""What a run produces: BVH/npz export, foot locking and foot IK, previews, quality metrics and synthesis along
paths."""

from jaxstyle._lazy import lazy_module

__getattr__, __dir__ = lazy_module(__name__, ["export", "footlock", "footik", "preview", "metrics", "quality", "viz",
                                              "synthesis"])
