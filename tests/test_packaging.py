"""What a wheel install gets: every package, the zoo's hyperparameter files and the experiment specifications, the
``emmarl`` command, and a core of dependencies with the heavy ones as extras."""

import configparser
import re
import subprocess
import sys
import zipfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


#: The extras, and the distributions the core install must leave to them.
EXTRAS = {"zoo", "render", "plots", "ray", "docs", "tests", "bench"}
HEAVY = {"rl_zoo3", "optuna", "pandas", "matplotlib", "pygame-ce", "pygame", "ray"}


def setup_cfg() -> configparser.ConfigParser:
    config = configparser.ConfigParser()
    config.read(ROOT / "setup.cfg")
    return config


def requirements(text: str) -> list[str]:
    """The distribution names of a setup.cfg requirement list (comments and versions dropped)."""
    lines = [line.split("#")[0].strip() for line in text.splitlines()]
    return [re.split(r"[\[<>=!~ ]", line, maxsplit=1)[0].lower() for line in lines if line]


def listed_packages() -> set[str]:
    return {line.strip() for line in setup_cfg()["options"]["packages"].splitlines() if line.strip()}


def test_the_core_install_leaves_the_heavy_dependencies_to_extras():
    config = setup_cfg()
    core = set(requirements(config["options"]["install_requires"]))
    assert {"torch", "stable-baselines3", "sb3-contrib", "pettingzoo", "supersuit", "numba", "pyyaml"} <= core
    assert not core & HEAVY
    extras = config["options.extras_require"]
    assert set(extras) == EXTRAS | {"all"}
    assert requirements(extras["all"]) == ["sb3-emmarl"]
    assert extras["all"].strip() == f"sb3-emmarl[{','.join(name for name in extras if name != 'all')}]"
    assert {"rl_zoo3", "optuna", "pandas", "matplotlib"} <= set(requirements(extras["zoo"]))  # emmarl plot among them
    assert "pygame-ce" in requirements(extras["render"]) and extras["plots"].strip() == "sb3-emmarl[zoo]"
    assert requirements(extras["ray"]) == ["ray"]


def test_make_install_installs_every_extra():
    assert '$(PIP) -e ".[all]"' in (ROOT / "Makefile").read_text().split("\ninstall:", 1)[1].split("\n\n", 1)[0]


def test_setup_cfg_lists_every_package():
    found = {".".join(p.parent.relative_to(ROOT).parts) for p in (ROOT / "sb3_emmarl").rglob("__init__.py")}
    found |= {"wildlife_reserve." + ".".join(p.parent.relative_to(ROOT / "envs" / "wildlife_reserve").parts)
              for p in (ROOT / "envs" / "wildlife_reserve").rglob("__init__.py")}
    found = {name.rstrip(".") for name in found}
    assert found == listed_packages()


def test_the_wheel_holds_the_packages_and_the_yaml_files(tmp_path):
    subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q", "-w",
                    str(tmp_path), str(ROOT)], check=True, capture_output=True)
    wheel = next(tmp_path.glob("sb3_emmarl-*.whl"))
    names = set(zipfile.ZipFile(wheel).namelist())
    for package in listed_packages():
        assert f"{package.replace('.', '/')}/__init__.py" in names, package
    yamls = {p.name for p in (ROOT / "sb3_emmarl" / "zoo" / "hyperparams").glob("*.yml")}
    assert yamls and {f"sb3_emmarl/zoo/hyperparams/{name}" for name in yamls} <= names
    specs = {p.name for p in (ROOT / "sb3_emmarl" / "experiments" / "specs").glob("*.yml")}
    assert {f"sb3_emmarl/experiments/specs/{name}" for name in specs} <= names
    info = next(name.split("/")[0] for name in names if name.endswith(".dist-info/METADATA"))
    with zipfile.ZipFile(wheel) as archive:
        assert "emmarl = sb3_emmarl.cli:main" in archive.read(f"{info}/entry_points.txt").decode()
        metadata = archive.read(f"{info}/METADATA").decode()
    assert {line.split(": ")[1] for line in metadata.splitlines() if line.startswith("Provides-Extra: ")} == EXTRAS | {"all"}
    core = {line.split(": ")[1] for line in metadata.splitlines() if line.startswith("Requires-Dist: ") and ";" not in line}
    assert not set(requirements("\n".join(core))) & HEAVY
