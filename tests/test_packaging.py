"""What a wheel install gets: every package, the zoo's hyperparameter files and the experiment specifications."""

import configparser
import subprocess
import sys
import zipfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def listed_packages() -> set[str]:
    config = configparser.ConfigParser()
    config.read(ROOT / "setup.cfg")
    return {line.strip() for line in config["options"]["packages"].splitlines() if line.strip()}


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
