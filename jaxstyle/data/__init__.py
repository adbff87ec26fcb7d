"""Data: locating and fetching motion capture, procedural clips, both papers' feature layouts, datasets,
normalisation and batching."""

from jaxstyle._lazy import lazy_module

__getattr__, __dir__ = lazy_module(__name__, [
    "locate", "fetch", "procedural", "datasets", "pfnn_features", "lpn_features", "normalise", "batching"])
