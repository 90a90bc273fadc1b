"""``zoo/experiment.py``: run the paper's experiments (missing cells only) and regenerate their reports.

Examples::

    python zoo/experiment.py table2_robustness --budget quick            # run what is missing, then report
    python zoo/experiment.py --all --budget quick --n-jobs 2
    python zoo/experiment.py table4_coverage --budget full --backend ray --address ray://head:10001
    python zoo/experiment.py --all --budget quick --report-only          # docs/results.md and docs/figures/ only
    python zoo/experiment.py --list
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from sb3_emmarl.experiments.runner import BACKENDS, hardware, run_experiment
from sb3_emmarl.experiments.spec import BUDGETS, ExperimentSpec, list_specs, load_spec
from sb3_emmarl.experiments.store import ResultStore

#: Where runs and the store go by default (relative to the working directory, as the zoo's logs/).
DEFAULT_ROOT = "logs/experiments"


def experiment_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(description="Run the paper's experiments (missing cells only) and report them.")
    parser.add_argument("names", nargs="*", help="experiments (names of the package's specifications, or YAML files)")
    parser.add_argument("--all", action="store_true", help="every experiment of the package")
    parser.add_argument("--list", action="store_true", help="list the experiments and exit")
    parser.add_argument("--budget", default="quick", choices=list(BUDGETS), help="quick (this machine) or full (paper)")
    parser.add_argument("--backend", default="local", choices=list(BACKENDS), help="local processes or Ray tasks")
    parser.add_argument("--address", default=None, help="Ray cluster address (default: a local Ray instance)")
    parser.add_argument("--n-jobs", type=int, default=None, help="cells at once on the local backend (default: cores)")
    parser.add_argument("-f", "--root", default=DEFAULT_ROOT, help="folder of the cells' runs")
    parser.add_argument("--store", default=None, help="SQLite store (default: ROOT/results.sqlite)")
    parser.add_argument("--report-only", action="store_true", help="regenerate the reports from the store, run nothing")
    parser.add_argument("--no-report", action="store_true", help="run the cells, leave the reports alone")
    parser.add_argument("--page", default="docs/results.md", help="the results page whose experiment sections to rewrite")
    parser.add_argument("--figures", default=None, help="folder of the figures (default: figures/ beside --page)")
    return parser


def _specs(parser: argparse.ArgumentParser, args: argparse.Namespace) -> list[tuple[ExperimentSpec, str | None]]:
    """Every named specification, loaded and checked before anything runs."""
    if args.all == bool(args.names):
        parser.error("name experiments or give --all (not both)")
    names = list_specs() if args.all else args.names
    specs = []
    for name in names:
        try:
            spec = load_spec(name)
        except ValueError as error:
            parser.error(str(error))
        specs.append((spec, name if Path(name).suffix else None))
    return specs


def experiment_main(argv: list[str] | None = None) -> int:
    parser = experiment_parser()
    args = parser.parse_args(argv)
    if args.list:
        for name in list_specs():
            spec = load_spec(name)
            print(f"{name:<28}{spec.paper:<28}{spec.title}")
        return 0
    if args.n_jobs is not None and args.n_jobs < 1:
        parser.error(f"--n-jobs must be >= 1, got {args.n_jobs}")
    specs = _specs(parser, args)
    store = ResultStore(args.store or Path(args.root) / "results.sqlite")
    if not args.report_only:
        for spec, path in specs:
            try:
                run_experiment(spec, args.budget, store, args.root, args.backend, args.n_jobs, args.address, path)
            except (RuntimeError, ValueError) as error:
                print(f"error: {error}", file=sys.stderr)
                return 1
    if args.no_report:
        return 0
    from sb3_emmarl.experiments.report import render_section, update_results_page

    page = Path(args.page)
    figures = Path(args.figures) if args.figures else page.parent / "figures"
    sections = {}
    for spec, _ in specs:
        command = f"python zoo/experiment.py {spec.name} --budget {args.budget}"
        rows = store.rows(spec.name, args.budget)
        machine = rows[0]["hardware"] if rows else hardware()
        sections[spec.name] = render_section(spec, rows, args.budget, figures, command, machine)
    update_results_page(page, sections)
    print(f"wrote {len(sections)} section(s) of {page} and their figures in {figures}")
    return 0
