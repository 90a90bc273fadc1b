"""The ``emmarl`` command (``python -m sb3_emmarl``): one subcommand per tool, each dispatched to its module's ``main``.

Examples::

    emmarl train --algo em_ppo --env WildlifeReserve-v1 -n 20000 -f logs
    emmarl enjoy --algo em_ppo -f logs --episodes 2
    emmarl experiment --list
    emmarl patrol --policy stalest_block --episodes 3

A subcommand's module is imported only when it runs, so ``emmarl --help`` needs no extra, and a subcommand whose extra
is missing ends with one line naming it (``emmarl train: the zoo needs rl_zoo3: pip install 'sb3-emmarl[zoo]'``).
"""

from __future__ import annotations

import importlib
import sys
from typing import NamedTuple

from sb3_emmarl.common.trust.extras import MissingExtra
from sb3_emmarl.version import __version__


class Command(NamedTuple):
    """A subcommand: the function it runs (``"module:function"``, called with the remaining arguments, returning the
    exit code) and one line of help."""

    target: str
    help: str


#: The subcommands, in the order ``emmarl --help`` lists them.
COMMANDS: dict[str, Command] = {
    "train": Command("sb3_emmarl.zoo.cli:train_main", "train an agent with rl-baselines3-zoo's flags [zoo]"),
    "enjoy": Command("sb3_emmarl.zoo.cli:enjoy_main", "a trained team's metrics and a GIF of its patrol [zoo, render]"),
    "experiment": Command("sb3_emmarl.experiments.cli:experiment_main",
                          "the paper's experiments: run the missing cells, then their tables and figures [zoo]"),
    "compare": Command("sb3_emmarl.zoo.compare:compare_main", "variants at one budget over seeds, paired tests [zoo]"),
    "plot": Command("sb3_emmarl.plots.command:main", "learning curves and per-seed bar figures of runs [zoo]"),
    "patrol": Command("sb3_emmarl.patrol:patrol_main", "a scripted patrol's team metrics on the reserve"),
    "benchmark": Command("sb3_emmarl.zoo.benchmark:benchmark_main", "trained teams against the random team [zoo]"),
}


def usage(prog: str) -> str:
    """The help of ``prog``: its subcommands, one line each, with the extras they need in brackets."""
    width = max(map(len, COMMANDS)) + 2
    lines = [f"usage: {prog} <command> [arguments]   ({prog} <command> --help for a command's flags)", "",
             f"sb3-emmarl {__version__}: EM-PPO and the multi-agent baselines on the wildlife reserve.", "",
             "commands (extras they need in brackets: pip install 'sb3-emmarl[zoo,render]'):"]
    lines += [f"  {name:<{width}}{command.help}" for name, command in COMMANDS.items()]
    return "\n".join(lines)


def os_error_text(error: OSError) -> str:
    """``path: reason`` of a failed read or write (``No space left on device``), or the reason alone."""
    where = f"{error.filename}: " if error.filename else ""
    return f"{where}{error.strerror or error}"


def child_failure(stderr: str, limit: int = 3000) -> str:
    """What a failed child command (a training run, an experiment cell) said, for its parent's one-line error: its
    traceback's last ``limit`` characters on lines of their own if it crashed, else its ``error:`` line and any after
    it (or its last line), on the parent's line."""
    text = stderr.strip()
    if "Traceback" in text:
        return f"\n{text[-limit:]}"
    lines = text.splitlines()
    start = max((i for i, line in enumerate(lines) if "error:" in line), default=max(len(lines) - 1, 0))
    return f" {' '.join(lines[start:])[:limit]}".rstrip()


def main(argv: list[str] | None = None, prog: str = "emmarl") -> int:
    """Run ``emmarl <command> [arguments]``.

    :param argv: the arguments after the program's name (default: ``sys.argv[1:]``)
    :param prog: the program's name in messages and in the subcommands' usage lines
    :return: the exit code: the subcommand's; 2 for a missing or unknown command; 1 for a missing extra, or a file
        that cannot be read or written (a full disk, a read-only folder: one line naming the path) or memory run out
    """
    argv = sys.argv[1:] if argv is None else list(argv)
    if not argv or argv[0] in ("-h", "--help"):
        print(usage(prog), file=sys.stdout if argv else sys.stderr)
        return 0 if argv else 2
    if argv[0] == "--version":
        print(f"sb3-emmarl {__version__}")
        return 0
    name, rest = argv[0], argv[1:]
    if name not in COMMANDS:
        print(f"{prog}: error: unknown command {name!r}; choose from {', '.join(COMMANDS)} ({prog} --help)",
              file=sys.stderr)
        return 2
    module, function = COMMANDS[name].target.split(":")
    program = sys.argv[0]
    sys.argv[0] = f"{prog} {name}"  # the subcommand's argparse names itself after sys.argv[0]
    try:
        return int(getattr(importlib.import_module(module), function)(rest) or 0)
    except MissingExtra as error:
        print(f"{prog} {name}: {error}", file=sys.stderr)
        return 1
    except OSError as error:  # a full disk, a read-only or special path: one line naming it (writes are atomic)
        print(f"{prog} {name}: error: {os_error_text(error)}", file=sys.stderr)
        return 1
    except MemoryError:
        print(f"{prog} {name}: error: out of memory", file=sys.stderr)
        return 1
    finally:
        sys.argv[0] = program
