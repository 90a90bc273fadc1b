"""Fuzz of the reserve's arguments: how every argument set of a seeded sample is handled, counted by outcome.

Draws ``--cases`` argument sets from the defaults by mutating one to three arguments with values from the
catalogue of ``tests/fuzz_reserve.py`` (wrong types, NaN, infinities, zero, negative and huge values, wrong
shapes, unknown names, and valid values, each labelled valid or invalid there), builds
``reserve_v1.parallel_env(**kwargs)``, and for those that build resets and takes a few random steps, each
under a time limit and with tracemalloc measuring its peak memory. It prints the count of each outcome
(``ran`` and ``clean_error`` are the good ones; silent acceptances of invalid values, false rejections of
valid ones, unclean exceptions, bad output, hangs and memory peaks above the limit are failures), the worst
memory peak and the slowest case, then every failure, and exits with 1 if there was any.

Example: ``python benchmarks/fuzz_reserve.py --cases 1000 --seed 0`` (a few seconds)
"""

from __future__ import annotations

import argparse
import importlib.util
import sys
from pathlib import Path
from types import ModuleType


def load_fuzz() -> ModuleType:
    """``tests/fuzz_reserve.py`` (loaded by path: this script's own name would shadow it on ``sys.path``)."""
    module = sys.modules.get("fuzz_reserve")
    if module is not None and hasattr(module, "generate_cases"):
        return module
    path = Path(__file__).resolve().parents[1] / "tests" / "fuzz_reserve.py"
    spec = importlib.util.spec_from_file_location("fuzz_reserve", path)
    module = importlib.util.module_from_spec(spec)  # type: ignore[arg-type]
    sys.modules["fuzz_reserve"] = module  # dataclasses look their module up while the file runs
    spec.loader.exec_module(module)  # type: ignore[union-attr]
    return module


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", type=int, default=1000, help="argument sets to draw and run")
    parser.add_argument("--seed", type=int, default=0, help="seed of the draw (the same seed gives the same cases)")
    parser.add_argument("--time-limit", type=float, default=10.0, help="seconds per case before it counts as a hang")
    parser.add_argument("--memory-limit-mb", type=float, default=1024.0,
                        help="traced peak (MiB) per case above which it counts as a memory failure")
    parser.add_argument("--steps", type=int, default=3, help="random steps after each reset")
    parser.add_argument("--show", type=int, default=50, help="failures to print at most")
    parser.add_argument("--no-guard", action="store_true",
                        help="do not cap the address space at its size + 4 GiB while the cases run")
    args = parser.parse_args(argv)
    if args.cases < 1 or args.seed < 0 or args.time_limit <= 0 or args.memory_limit_mb <= 0 or args.steps < 0:
        parser.error("--cases must be >= 1, --seed >= 0, --time-limit and --memory-limit-mb > 0, --steps >= 0")
    fuzz = load_fuzz()

    cases = fuzz.generate_cases(args.cases, seed=args.seed)
    report = fuzz.run_cases(cases, time_limit=args.time_limit, memory_limit=int(args.memory_limit_mb * 2**20),
                            steps=args.steps, guard=None if args.no_guard else 4 * 2**30)
    counts = report.counts
    valid = sum(case.valid for case in cases)
    print(f"Fuzz of reserve_v1.parallel_env arguments: {args.cases} cases from seed {args.seed} ({valid} valid, "
          f"{args.cases - valid} invalid by the catalogue), {args.steps} random steps after each reset, limits "
          f"{args.time_limit:g} s and {args.memory_limit_mb:g} MiB per case")
    print(f"{'outcome':<18} {'cases':>6}  kind")
    for outcome in fuzz.OUTCOMES:
        kind = "failure" if outcome in fuzz.FAILURES else "ok"
        print(f"{outcome:<18} {counts[outcome]:>6}  {kind}")
    worst = max(report.results, key=lambda r: r.peak_bytes)
    slowest = max(report.results, key=lambda r: r.seconds)
    print(f"worst memory peak {worst.peak_bytes / 2**20:.1f} MiB: {worst.outcome}, {worst.case.describe()}")
    print(f"slowest case {slowest.seconds:.2f} s: {slowest.outcome}, {slowest.case.describe()}")
    print(f"wall time {report.seconds:.1f} s")
    failures = report.failures
    for result in failures[:args.show]:
        print(f"FAILURE {result.outcome}: {result.case.describe()}: {result.detail[:500]}")
    if len(failures) > args.show:
        print(f"... and {len(failures) - args.show} more")
    print(f"{len(failures)} failures")
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
