"""The paper's experiments as named specifications, a resumable runner and the reports (``zoo/experiment.py``)."""

from sb3_emmarl.experiments.spec import ExperimentSpec, list_specs, load_spec
from sb3_emmarl.experiments.store import ResultStore

__all__ = ["ExperimentSpec", "ResultStore", "list_specs", "load_spec"]
