"""Fuzz the zoo's hyperparameters (YAML files and -params) and flags; print how each case ended.

The cases and their valid/invalid labels are in ``tests/fuzz_zoo.py`` (hyperparameters of PPO, DQN
and EM-PPO set to wrong types, NaN, inf, zero, negative and huge values; broken or unsafe YAML files;
unknown keys; every numeric flag out of range). Each case runs ``zoo/train.py``'s ``train_main`` in this
process on a tiny reserve with a one-rollout budget. A case fails if an invalid value is accepted, a
valid one refused, an error does not name the argument or leaves a run folder, or it takes more than
60 s. Exit code 1 on any failure.

Then the hostile cases of issue 52 (``tests/fuzz_zoo.py``, ``hostile_cases``): command lines, ``-conf`` files and
tampered run folders (``--resume``, ``enjoy``) that try to run code (attribute walks, ``lambda``, ``__import__``,
``th.os``, names rl_zoo3 imports and calls, Python tags, YAML bombs), each trying to create a marker file; settings
SB3 takes and that would fail in the first rollout or update (``ent_coef: 'auto'`` for PPO, optimizers and their
arguments, callbacks' and wrappers' arguments, ``-tb`` under a file); and flags that do not fit the machine
(``--device``), the zip (``-i``) or the run (``--resume`` with flags of other values, or no checkpoint that loads). It
prints how many created their marker, printed a traceback (or not one ``error:`` line), left files behind or were
accepted: all must be 0.

Example: ``python benchmarks/fuzz_zoo.py`` (about two minutes); ``--hostile-only`` for the hostile cases alone
"""

from __future__ import annotations

import collections
import sys
import tempfile
import time
from pathlib import Path

import torch as th

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from fuzz_zoo import FAILURES, cases, hostile_cases, run_case, run_hostile_case, train_template_run

HOSTILE_COUNTS = ("marker", "traceback", "leftover", "accepted")


def run_hostile(every: int = 1) -> collections.Counter:
    """Run every ``every``-th hostile case; print each failure and the counts; return the counts."""
    all_cases = hostile_cases()[::every]
    counts: collections.Counter = collections.Counter()
    start = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        needs_template = any(c.config is not None or any("{t}" in a for a in c.argv) for c in all_cases)
        template = train_template_run(Path(tmp) / "template") if needs_template else None
        for i, case in enumerate(all_cases):
            outcome = run_hostile_case(case, Path(tmp) / str(i), template)
            for name in HOSTILE_COUNTS:
                if outcome[name]:
                    counts[name] += 1
                    print(f"{name}: {case.name}: {outcome['text']}")
    print(f"{len(all_cases)} hostile cases in {time.perf_counter() - start:.0f} s: "
          + ", ".join(f"{counts[name]} {name}s" for name in HOSTILE_COUNTS))
    return counts


def main(argv: list[str] | None = None) -> int:
    th.set_num_threads(1)
    hostile = run_hostile()
    if any(hostile.values()):
        return 1
    if "--hostile-only" in (sys.argv[1:] if argv is None else argv):
        return 0
    all_cases = cases()
    counts: collections.Counter = collections.Counter()
    slowest = (0.0, "")
    start = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        for i, case in enumerate(all_cases):
            began = time.perf_counter()
            outcome, text = run_case(case, Path(tmp) / str(i))
            slowest = max(slowest, (time.perf_counter() - began, case.name))
            counts[outcome] += 1
            if outcome in FAILURES:
                print(f"{outcome}: {case.name}: {text.strip()[-300:]}")
    valid = sum(c.valid for c in all_cases)
    print(f"{len(all_cases)} cases ({valid} valid, {len(all_cases) - valid} invalid) in {time.perf_counter() - start:.0f} s; "
          f"slowest {slowest[0]:.1f} s ({slowest[1]})")
    for outcome in ("ran", "clean", *FAILURES):
        print(f"  {outcome:>9}: {counts[outcome]}")
    return 1 if any(counts[f] for f in FAILURES) else 0


if __name__ == "__main__":
    sys.exit(main())
