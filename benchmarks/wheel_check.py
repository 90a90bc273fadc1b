"""The package as a user gets it: build the wheel, install it in a fresh venv outside the checkout, and use it.

Core install (no extras): rl_zoo3, pygame and matplotlib are absent, EM-PPO trains on the reserve (a few thousand
agent-steps, save, load, ``evaluate_policy``), ``emmarl patrol`` runs, the first run says that it compiles the reserve's
kernels, and ``import sb3_emmarl.zoo`` / ``emmarl train`` fail with one line naming the ``[zoo]`` extra. Then with
``[zoo]`` alone: ``emmarl train`` (20k agent-steps),
``emmarl enjoy`` (metrics; its GIF names the ``[render]`` extra), ``emmarl experiment --list``, ``emmarl plot``.

Each step prints ``ok`` or ``FAIL`` with its time; the script exits 1 at the first failure. Torch is installed first,
at the Makefile's ``TORCH_VERSION`` (the CPU build, as ``make install`` does). About 15 minutes on 2 cores::

    python benchmarks/wheel_check.py            # or: make wheel-check
    python benchmarks/wheel_check.py --keep     # keep the temporary folder (venv, wheel, runs) for a look
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
#: Modules of the extras that the core install must not bring.
EXTRA_MODULES = ("rl_zoo3", "pygame", "matplotlib")
#: The line a zoo import without the ``[zoo]`` extra ends with.
ZOO_MESSAGE = "the zoo needs rl_zoo3: pip install 'sb3-emmarl[zoo]'"
#: EM-PPO on the core install, from a folder outside the checkout (torch on one thread, as the suite).
CORE_TRAINING = """
import time
import torch as th
th.set_num_threads(1)
from sb3_emmarl import EMPPO, evaluate_policy
from sb3_emmarl.common.vec_env import make_vec_env
import sb3_emmarl
assert "site-packages" in sb3_emmarl.__file__, sb3_emmarl.__file__
env = make_vec_env(n_copies=1, seed=0)
model = EMPPO("MlpPolicy", env, n_steps=256, batch_size=256, seed=0)
start = time.perf_counter()
model.learn(total_timesteps={steps})
print(f"trained {{model.num_timesteps}} agent-steps in {{time.perf_counter() - start:.0f}} s")
model.save("em_ppo_reserve")
model = EMPPO.load("em_ppo_reserve", env=env)
mean, std = evaluate_policy(model, make_vec_env(n_copies=1, seed=1), n_eval_episodes=1)
print(f"team reward per episode: {{mean:.1f}} +/- {{std:.1f}}")
"""


def torch_version() -> str:
    """The Makefile's ``TORCH_VERSION`` (what ``make install`` installs)."""
    match = re.search(r"^TORCH_VERSION \?= (\S+)$", (ROOT / "Makefile").read_text(), re.MULTILINE)
    if match is None:
        raise SystemExit("wheel_check: no 'TORCH_VERSION ?= ...' line in the Makefile")
    return match.group(1)


def checkout_files() -> list[str]:
    """The checkout's files as they are (tracked and new, without what git ignores): the wheel is built from a copy
    of them, so that no stale ``build/`` folder of the checkout can add a removed module to it."""
    listing = subprocess.run(["git", "ls-files", "--cached", "--others", "--exclude-standard", "-z"], cwd=ROOT,
                             check=True, capture_output=True, text=True).stdout
    return [name for name in listing.split("\0") if name and (ROOT / name).is_file()]


class Checker:
    """Runs the steps, prints each one's result and time, and stops at the first failure.

    :param work: the folder the commands run in (outside the checkout)
    :param python: the venv's python
    """

    def __init__(self, work: Path, python: Path) -> None:
        self.work, self.python = work, python
        self.env = {key: value for key, value in os.environ.items() if key not in ("PYTHONPATH", "PYTHONHOME",
                                                                                      "VIRTUAL_ENV")}
        self.env.update(OMP_NUM_THREADS="1", PATH=f"{python.parent}{os.pathsep}{os.environ.get('PATH', '')}")

    def run(self, name: str, command: list[str], expect_code: int = 0, expect_line: str | None = None,
            show: int = 3) -> subprocess.CompletedProcess:
        """Run ``command`` in the work folder; fail unless it exits with ``expect_code`` and, when given, its stderr's
        last line ends with ``expect_line``.

        :param name: the step's name
        :param command: the command
        :param expect_code: the exit code it must end with
        :param expect_line: what the last line of its stderr must end with
        :param show: how many last lines of its output to print
        """
        start = time.perf_counter()
        result = subprocess.run(command, cwd=self.work, env=self.env, capture_output=True, text=True)
        seconds = time.perf_counter() - start
        errors = result.stderr.strip().splitlines()
        ok = result.returncode == expect_code and (expect_line is None or (bool(errors) and errors[-1].endswith(expect_line)))
        print(f"{'ok  ' if ok else 'FAIL'} {name} ({seconds:.0f} s, exit code {result.returncode})", flush=True)
        for line in result.stdout.strip().splitlines()[-show:] if show else []:
            print(f"       | {line}")
        # stderr: all of it (its end) on a failure; else the kernels' compile notice and the expected line
        shown = errors[-15:] if not ok else [line for line in errors if line.startswith("wildlife_reserve:")]
        for line in shown + (errors[-1:] if ok and expect_line else []):
            print(f"       ! {line}")
        if not ok:
            raise SystemExit(1)
        return result

    def pip(self, name: str, *args: str) -> None:
        """``pip install`` in the venv."""
        self.run(name, [str(self.python), "-m", "pip", "install", "--quiet", "--disable-pip-version-check", *args],
                 show=0)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--torch-version", default=None, help="torch to install first (default: the Makefile's)")
    parser.add_argument("--steps", type=int, default=4096, help="agent-steps of the core install's EM-PPO run")
    parser.add_argument("--zoo-steps", type=int, default=20_000, help="agent-steps of emmarl train")
    parser.add_argument("--keep", action="store_true", help="keep the temporary folder")
    args = parser.parse_args(argv)
    if args.steps < 1 or args.zoo_steps < 1:
        parser.error(f"--steps and --zoo-steps must be >= 1, got {args.steps} and {args.zoo_steps}")
    temp = Path(tempfile.mkdtemp(prefix="sb3_emmarl_wheel_"))
    print(f"wheel check in {temp} (python {sys.version.split()[0]})", flush=True)
    try:
        dist, work = temp / "dist", temp / "work"
        work.mkdir()
        checker = Checker(work, temp / "venv" / "bin" / "python")
        source = temp / "source"
        for name in checkout_files():
            (source / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(ROOT / name, source / name)
        checker.run("build the wheel", [sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation",
                                        "--quiet", "-w", str(dist), str(source)], show=0)
        wheel = next(dist.glob("sb3_emmarl-*.whl"))
        print(f"       | {wheel.name} ({wheel.stat().st_size / 1024:.0f} KiB)")
        checker.run("a fresh venv (no system site-packages)", [sys.executable, "-m", "venv", str(temp / "venv")], show=0)
        checker.pip(f"torch=={args.torch_version or torch_version()}", f"torch=={args.torch_version or torch_version()}")
        checker.pip("the wheel, no extras", str(wheel))
        python = str(checker.python)
        checker.run("no extra's module installed", [python, "-c", "import importlib.util as u; found = [m for m in "
                                                    f"{EXTRA_MODULES!r} if u.find_spec(m)]; print('found:', found); "
                                                    "raise SystemExit(1 if found else 0)"])
        checker.run("emmarl --help", ["emmarl", "--help"], show=9)
        checker.run(f"EM-PPO on the reserve, {args.steps} agent-steps, core install",
                    [python, "-c", CORE_TRAINING.format(steps=args.steps)])
        checker.run("emmarl patrol (core)", ["emmarl", "patrol", "--episodes", "1"], show=2)
        checker.run("import sb3_emmarl.zoo without [zoo]", [python, "-c", "import sb3_emmarl.zoo"], expect_code=1,
                    expect_line=ZOO_MESSAGE)
        checker.run("emmarl train without [zoo]", ["emmarl", "train", "--help"], expect_code=1,
                    expect_line=f"emmarl train: {ZOO_MESSAGE}")
        checker.pip("the wheel with [zoo]", f"{wheel}[zoo]")
        env_id = checker.run("the reserve's zoo id", [python, "-c", "from sb3_emmarl.common.env_ids import ENV_ID; "
                                                      "print(ENV_ID)"], show=1).stdout.strip()
        checker.run(f"emmarl train --algo em_ppo -n {args.zoo_steps}",
                    ["emmarl", "train", "--algo", "em_ppo", "--env", env_id, "-n", str(args.zoo_steps), "--seed", "0",
                     "-f", "logs", "-tb", "runs", "--eval-freq", "-1", "--team-eval-episodes", "2", "--verbose", "0"],
                    show=8)
        checker.run("emmarl enjoy (metrics)", ["emmarl", "enjoy", "--algo", "em_ppo", "--env", env_id, "-f", "logs",
                                               "--episodes", "2", "--no-record"], show=4)
        checker.run("emmarl enjoy's GIF without [render]", ["emmarl", "enjoy", "--algo", "em_ppo", "--env", env_id,
                                                            "-f", "logs", "--episodes", "1"], expect_code=1,
                    expect_line="emmarl enjoy: drawing the reserve needs pygame: pip install 'sb3-emmarl[render]'",
                    show=0)
        checker.run("emmarl experiment --list", ["emmarl", "experiment", "--list"], show=20)
        checker.run("emmarl plot (learning curve of the run)", ["emmarl", "plot", "-f", "logs", "-a", "em_ppo", "-w", "4",
                                                                "-o", "curves.png"], show=2)
        checker.run("the figure is a PNG", [python, "-c", "import pathlib; data = pathlib.Path('curves.png')"
                                            ".read_bytes(); raise SystemExit(0 if data[:4] == b'\\x89PNG' else 1)"])
        print("wheel check passed")
        return 0
    finally:
        if args.keep:
            print(f"kept {temp}")
        else:
            shutil.rmtree(temp, ignore_errors=True)


if __name__ == "__main__":
    sys.exit(main())
