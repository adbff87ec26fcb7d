"""Mason et al. 2018 workflows: base training, the few-shot adapter sweep, rate selection and the pipeline from
a style folder."""

from jaxstyle._lazy import lazy_module

__getattr__, __dir__ = lazy_module(__name__, ["fewshot", "selection", "sweep_files", "pipeline", "train"])
