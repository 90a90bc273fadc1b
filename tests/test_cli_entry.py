"""The ``emmarl`` command and ``python -m sb3_emmarl``, the extras' one-line errors, and the kernels' compile notice."""

import configparser
import importlib
import subprocess
import sys
from pathlib import Path

import pytest

from sb3_emmarl.cli import COMMANDS, main
from sb3_emmarl.common.trust.extras import MissingExtra, requires
from wildlife_reserve.reserve import compilation

ROOT = Path(__file__).resolve().parents[1]
ZOO_LINE = "the zoo needs rl_zoo3: pip install 'sb3-emmarl[zoo]'"
#: Modules of the extras; the core package imports none of them.
EXTRA_MODULES = ("rl_zoo3", "optuna", "pandas", "matplotlib", "pygame", "ray")


def python(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, *args], capture_output=True, text=True, timeout=300, cwd=ROOT)


def test_setup_cfg_installs_the_emmarl_command():
    config = configparser.ConfigParser()
    config.read(ROOT / "setup.cfg")
    scripts = [line.strip() for line in config["options.entry_points"]["console_scripts"].splitlines() if line.strip()]
    assert scripts == ["emmarl = sb3_emmarl.cli:main"]
    assert importlib.import_module("sb3_emmarl.cli").main is main


def test_every_command_runs_a_main_taking_argv():
    assert list(COMMANDS) == ["train", "enjoy", "experiment", "compare", "plot", "patrol", "benchmark"]
    for name, command in COMMANDS.items():
        module, function = command.target.split(":")
        assert callable(getattr(importlib.import_module(module), function)), name


def test_python_m_lists_the_commands_one_line_each():
    result = python("-m", "sb3_emmarl", "--help")
    assert result.returncode == 0, result.stderr
    lines = result.stdout.splitlines()
    for name, command in COMMANDS.items():
        (line,) = [line for line in lines if line.split()[:1] == [name]]
        assert line.endswith(command.help) and command.help, name


@pytest.mark.parametrize("argv", [["trian"], ["--train"]])
def test_an_unknown_command_is_one_line_naming_the_allowed_ones(argv, capsys):
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert f"unknown command {argv[0]!r}; choose from {', '.join(COMMANDS)}" in err


def test_no_command_prints_the_usage_and_fails(capsys):
    assert main([]) == 2
    assert "patrol" in capsys.readouterr().err


def test_a_command_runs_under_its_own_name(capsys):
    with pytest.raises(SystemExit) as stop:
        main(["patrol", "--episodes", "0"])
    assert stop.value.code == 2
    assert capsys.readouterr().err == ("emmarl patrol: error: argument --episodes: must be an int in [1, 10000], got 0 "
                                       "(--help for usage)\n")


def test_the_zoo_scripts_are_thin_calls_of_the_command():
    for script in sorted((ROOT / "zoo").glob("*.py")):
        assert f'main(["{script.stem}", *sys.argv[1:]])' in script.read_text(), script.name
        assert script.stem in COMMANDS


def test_the_core_package_imports_no_extra():
    code = ("import sys, sb3_emmarl, sb3_emmarl.cli, sb3_emmarl.patrol; from sb3_emmarl import EMPPO; "
            "from wildlife_reserve import reserve_v1; reserve_v1.parallel_env(); "
            f"print(sorted(m for m in {EXTRA_MODULES!r} if m in sys.modules))")
    result = python("-c", code)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == "[]"


def _without(monkeypatch, module: str, *reimported: str) -> None:
    """Simulate ``module`` not installed, and forget ``reimported`` modules (restored after the test). Its submodules
    go too: an earlier test may have imported them, and Python finds ``matplotlib.figure`` in ``sys.modules`` without
    looking at ``matplotlib``."""
    for name in [name for name in sys.modules if name.startswith(f"{module}.")]:
        monkeypatch.setitem(sys.modules, name, None)
    monkeypatch.setitem(sys.modules, module, None)
    for name in [name for name in sys.modules if name.startswith(reimported)] if reimported else []:
        monkeypatch.delitem(sys.modules, name)


def test_the_zoo_without_rl_zoo3_is_one_line_naming_the_extra(monkeypatch, capsys):
    _without(monkeypatch, "rl_zoo3", "sb3_emmarl.zoo")
    with pytest.raises(MissingExtra, match=r"^the zoo needs rl_zoo3: pip install 'sb3-emmarl\[zoo\]'$") as error:
        importlib.import_module("sb3_emmarl.zoo")
    assert error.value.extra == "zoo" and error.value.name == "rl_zoo3" and error.value.__suppress_context__
    for command in ("train", "enjoy", "compare", "benchmark"):
        assert main([command, "--help"]) == 1
        assert capsys.readouterr().err == f"emmarl {command}: {ZOO_LINE}\n"


def test_drawing_the_reserve_without_pygame_names_the_render_extra(monkeypatch):
    from wildlife_reserve import reserve_v1

    _without(monkeypatch, "pygame")
    env = reserve_v1.parallel_env(render_mode="rgb_array", max_cycles=5)
    env.reset(seed=0)
    with pytest.raises(MissingExtra, match=r"^drawing the reserve needs pygame: pip install 'sb3-emmarl\[render\]'$"):
        env.render()


def test_the_experiments_figures_without_matplotlib_name_the_zoo_extra(monkeypatch):
    _without(monkeypatch, "matplotlib", "sb3_emmarl.experiments.report")
    with pytest.raises(MissingExtra, match=r"needs matplotlib: pip install 'sb3-emmarl\[zoo\]'$"):
        importlib.import_module("sb3_emmarl.experiments.report")


def test_the_ray_backend_without_ray_names_the_ray_extra(monkeypatch):
    from sb3_emmarl.experiments import runner

    _without(monkeypatch, "ray")
    with pytest.raises(MissingExtra, match=r"^the ray backend needs ray: pip install 'sb3-emmarl\[ray\]'$"), \
            runner._backend("ray", n_jobs=None, address=None, gather=False):
        pass


def test_requires_turns_only_its_own_module_missing():
    with pytest.raises(ModuleNotFoundError) as error, requires("rl_zoo3", "zoo", "the zoo"):
        importlib.import_module("sb3_emmarl_no_such_module")
    assert not isinstance(error.value, MissingExtra)  # another missing module passes unchanged
    with pytest.raises(ImportError, match="broken inside"), requires("rl_zoo3", "zoo", "the zoo"):
        raise ImportError("broken inside an installed module", name="rl_zoo3")  # not ModuleNotFoundError: unchanged


def test_the_compile_notice_is_one_line_once_and_only_on_a_cold_cache(monkeypatch, tmp_path, capsys):
    monkeypatch.setattr(compilation, "cache_folder", lambda: tmp_path)
    compilation.announce_compilation.cache_clear()
    compilation.announce_compilation()
    compilation.announce_compilation()
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and str(tmp_path) in err
    assert err.startswith("wildlife_reserve: compiling the reserve's kernels")
    (tmp_path / "kernels.advance_world-1037.py311.nbi").touch()  # numba's index of one compiled kernel
    compilation.announce_compilation.cache_clear()
    compilation.announce_compilation()
    assert capsys.readouterr().err == ""
    compilation.announce_compilation.cache_clear()


def test_the_compile_notice_finds_numbas_own_cache():
    from wildlife_reserve import reserve_v1

    env = reserve_v1.parallel_env(max_cycles=2)
    env.reset(seed=0)
    env.step({agent: env.action_space(agent).sample() for agent in env.agents})  # compiled (or loaded) and cached
    assert compilation.cache_folder() is not None and not compilation.cache_is_cold()
