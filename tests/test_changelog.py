"""CHANGELOG.md has a section for every released version, and no docstring carries version history.

The version lives in ``sb3_emmarl/version.py`` (there are no tags), so the released versions are the values that
file's history set; each version's notes belong in CHANGELOG.md, not in the docstrings.
"""

from __future__ import annotations

import importlib
import inspect
import pkgutil
import re
import subprocess
from collections.abc import Iterator
from datetime import date
from pathlib import Path
from types import ModuleType

import pytest

import sb3_emmarl

ROOT = Path(__file__).resolve().parents[1]
CHANGELOG = ROOT / "CHANGELOG.md"
#: A version section: ``## [x.y.z] - YYYY-MM-DD``, or ``## [Unreleased]``.
SECTION = re.compile(r"^## \[(?P<version>[^\]]+)\](?: - (?P<date>.+?))?\s*$", re.MULTILINE)
#: A version number in a docstring: history, which belongs in CHANGELOG.md.
HISTORY = re.compile(r"\b0\.\d+\.\d+\b")
#: The packages whose docstrings are checked, and the modules left out.
PACKAGES = ("sb3_emmarl", "wildlife_reserve")
EXCLUDED = {"sb3_emmarl.version"}


def version_key(version: str) -> tuple[int, ...]:
    return tuple(int(part) for part in version.split("."))


def changelog_sections() -> list[tuple[str, str | None]]:
    """``(version, date)`` of every ``## [...]`` section of CHANGELOG.md, in order (date None where there is none)."""
    return [(m["version"], m["date"]) for m in SECTION.finditer(CHANGELOG.read_text(encoding="utf-8"))]


def released_sections() -> list[tuple[str, str | None]]:
    return [(version, day) for version, day in changelog_sections() if version != "Unreleased"]


def git_versions() -> dict[str, str]:
    """Every version ``sb3_emmarl/version.py``'s history set, with the date (YYYY-MM-DD) of the first commit that set
    it; skips the test when git or the history is not available (no git, not a checkout, a shallow clone)."""
    def git(*args: str) -> str:
        try:
            result = subprocess.run(["git", *args], cwd=ROOT, capture_output=True, text=True, timeout=60)
        except (OSError, subprocess.SubprocessError) as error:
            pytest.skip(f"git is not available: {error}")
        if result.returncode != 0:
            pytest.skip(f"no git history here: {result.stderr.strip()}")
        return result.stdout

    if git("rev-parse", "--is-shallow-repository").strip() == "true":
        pytest.skip("a shallow clone does not hold the version history")
    versions: dict[str, str] = {}
    day = None
    for line in git("log", "--reverse", "--format=commit %ad", "--date=short", "-p", "--",
                    "sb3_emmarl/version.py").splitlines():
        if line.startswith("commit "):
            day = line.split()[1]
        elif (m := re.match(r'^\+__version__ = "(\d+\.\d+\.\d+)"', line)) and m[1] not in versions:
            versions[m[1]] = day
    if not versions:
        pytest.skip("sb3_emmarl/version.py has no history here")
    return versions


def test_unreleased_comes_first_and_the_newest_version_is_the_current_one():
    sections = changelog_sections()
    assert sections, "CHANGELOG.md has no '## [...]' section"
    assert [version for version, _ in sections].count("Unreleased") <= 1
    if "Unreleased" in (version for version, _ in sections):
        assert sections[0] == ("Unreleased", None), "## [Unreleased] must come first, without a date"
    released = released_sections()
    assert released and released[0][0] == sb3_emmarl.__version__, (
        f"the newest section of CHANGELOG.md is {released[0][0] if released else None}, "
        f"the package is {sb3_emmarl.__version__}")


def test_versions_descend_with_iso_dates():
    released = released_sections()
    for version, day in released:
        assert re.fullmatch(r"\d+\.\d+\.\d+", version), f"section [{version}] is not a version x.y.z"
        assert day is not None, f"section [{version}] has no date ('## [{version}] - YYYY-MM-DD')"
        assert re.fullmatch(r"\d{4}-\d{2}-\d{2}", day), f"section [{version}]'s date {day!r} is not YYYY-MM-DD"
        date.fromisoformat(day)
    versions = [version_key(version) for version, _ in released]
    assert versions == sorted(versions, reverse=True) and len(set(versions)) == len(versions), (
        "versions are not in strictly descending order: " + ", ".join(version for version, _ in released))
    days = [day for _, day in released]
    assert days == sorted(days, reverse=True), "dates do not descend with the versions"


def test_every_released_version_has_its_section():
    released = dict(released_sections())
    current = version_key(sb3_emmarl.__version__)
    history = {version: day for version, day in git_versions().items() if version_key(version) <= current}
    missing = sorted(set(history) - set(released), key=version_key)
    assert not missing, f"CHANGELOG.md has no section for {', '.join(missing)}"
    wrong = [f"{version}: {released[version]} (set on {day})" for version, day in history.items()
             if released[version] != day]
    assert not wrong, "sections dated otherwise than the commit that set the version: " + "; ".join(wrong)


def package_modules() -> Iterator[ModuleType]:
    """Every importable module of :data:`PACKAGES`, imported one by one; a module that cannot be imported for lack
    of an optional dependency is left out."""
    for name in PACKAGES:
        package = importlib.import_module(name)
        yield package
        for info in pkgutil.walk_packages(package.__path__, f"{name}.", onerror=lambda _: None):
            if info.name in EXCLUDED:
                continue
            try:
                yield importlib.import_module(info.name)
            except ImportError:
                continue


def docstrings(module: ModuleType) -> Iterator[tuple[str, str]]:
    """``(name, docstring)`` of the module and of every class, function, method and property defined in it."""
    yield module.__name__, module.__doc__ or ""
    seen: set[int] = set()

    def walk(prefix: str, namespace: dict) -> Iterator[tuple[str, str]]:
        for attribute, value in namespace.items():
            if isinstance(value, (staticmethod, classmethod)):
                value = value.__func__
            if isinstance(value, property):
                yield f"{prefix}.{attribute}", value.__doc__ or ""
                continue
            if not (inspect.isclass(value) or inspect.isfunction(value)) or id(value) in seen:
                continue
            if getattr(value, "__module__", None) != module.__name__:
                continue  # imported from elsewhere: checked where it is defined
            seen.add(id(value))
            name = f"{prefix}.{attribute}"
            if inspect.isclass(value):
                yield name, value.__dict__.get("__doc__") or ""
                yield from walk(name, dict(value.__dict__))
            else:
                yield name, value.__doc__ or ""

    yield from walk(module.__name__, dict(vars(module)))


def test_no_docstring_carries_version_history():
    offences = []
    checked = 0
    for module in package_modules():
        checked += 1
        for name, text in docstrings(module):
            for match in HISTORY.finditer(text):
                context = " ".join(text[max(0, match.start() - 60):match.end() + 60].split())
                offences.append(f"{name}: {match[0]!r} in '...{context}...'")
    assert checked > 10, f"only {checked} modules were imported"
    assert not offences, ("version history belongs in CHANGELOG.md, not in docstrings:\n" + "\n".join(offences))
