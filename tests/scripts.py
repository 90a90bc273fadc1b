"""Load the repository's scripts as modules: the benchmarks (``benchmarks/*.py``) and the lab's one-off studies
(``docs/lab/studies/*.py``) are scripts, not packages."""

import importlib.util
import sys
from pathlib import Path
from types import ModuleType

ROOT = Path(__file__).resolve().parents[1]
BENCHMARKS = ROOT / "benchmarks"
STUDIES = ROOT / "docs" / "lab" / "studies"


def load_script(folder: Path, name: str) -> ModuleType:
    """``<folder>/<name>.py`` as a module (importing its sibling scripts as it does when run)."""
    if str(folder) not in sys.path:
        sys.path.append(str(folder))
    spec = importlib.util.spec_from_file_location(name, folder / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def load_benchmark(name: str) -> ModuleType:
    """``benchmarks/<name>.py`` as a module."""
    return load_script(BENCHMARKS, name)


def load_study(name: str) -> ModuleType:
    """``docs/lab/studies/<name>.py`` as a module (a study finds the benchmarks it imports itself)."""
    return load_script(STUDIES, name)
