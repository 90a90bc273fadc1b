"""The module map of the documentation holds: every source file the EM page and the environment card name exists, and
every name of the EM page's reading order is defined where the package's sources can show it."""

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
#: where a path a page names may start (the pages name files relative to the package that holds them)
BASES = [ROOT, ROOT / "benchmarks", ROOT / "sb3_emmarl", ROOT / "sb3_emmarl" / "common",
         ROOT / "sb3_emmarl" / "common" / "latent", ROOT / "envs" / "wildlife_reserve",
         ROOT / "envs" / "wildlife_reserve" / "reserve"]


def named_paths(page: str) -> set[str]:
    """The source files (``x.py``) and folders (``x/``) a page names in backticks."""
    text = (ROOT / "docs" / page).read_text()
    return set(re.findall(r"`([\w/]+\.py|[\w/]+/)`", text))


@pytest.mark.parametrize("page", ["em.md", "env.md"])
def test_every_module_a_page_names_exists(page):
    paths = named_paths(page)
    assert {"common/appended/wrapping.py", "common/trust/pickling.py"} <= paths if page == "em.md" else \
        {"reserve/view.py", "reserve/kernels/", "sb3_emmarl/common/trust/pickling.py"} <= paths
    missing = sorted(path for path in paths if not any((base / path).exists() for base in BASES))
    assert not missing, f"docs/{page} names modules that do not exist: {missing}"


def test_the_em_loop_s_reading_order_names_what_the_code_defines():
    text = (ROOT / "docs" / "em.md").read_text()
    block = text.split("**Reading the EM loop in the code**", 1)[1].split("\n\n", 2)[1]
    sources = "\n".join(path.read_text() for path in (ROOT / "sb3_emmarl").rglob("*.py"))
    names = {token.removesuffix("()") for token in re.findall(r"`([\w.]+(?:\(\))?)`", block)}
    names -= {name for name in names if name.endswith(".py")}
    assert {"LatentConfig", "BeliefWrapper._step_extra", "EStep", "LatentAlgorithmMixin.train"} <= names
    undefined = sorted(name for name in names if not re.search(rf"(def|class) {name.split('.')[-1]}\b", sources))
    assert not undefined, f"docs/em.md's reading order names what the package does not define: {undefined}"
    steps = re.findall(r"^(\d)\. ", block, flags=re.M)
    assert steps == ["1", "2", "3", "4", "5"]
