"""``zoo/experiment.py``: run the paper's experiments (missing cells only) and regenerate their reports.

By default everything goes under the results folder ``--root`` (``logs/experiments``): the runs, the SQLite store and
each experiment's report (``ROOT/<name>/<budget>/results.md`` and its ``figures/``); the tracked results page
(``docs/results.md``) and ``docs/figures/`` change only with ``--update-docs``.

Examples::

    python zoo/experiment.py table2_robustness --budget quick            # run what is missing, then report
    python zoo/experiment.py --all --budget quick --n-jobs 2
    python zoo/experiment.py table4_fig3_coverage_detection --budget full --backend ray --address HEAD_IP:6379 --gather
    python zoo/experiment.py --all --budget quick --report-only --update-docs   # docs/results.md and docs/figures/
    python zoo/experiment.py --list
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from sb3_emmarl.common.trust.validation import int_flag
from sb3_emmarl.experiments.runner import BACKENDS, check_ray_address, hardware, run_experiment
from sb3_emmarl.experiments.spec import BUDGETS, ExperimentSpec, list_specs, load_spec
from sb3_emmarl.experiments.store import LEASE_SECONDS, ResultStore

#: Where runs, the store and the reports go by default (relative to the working directory, as the zoo's logs/).
DEFAULT_ROOT = "logs/experiments"
#: The results page ``--update-docs`` rewrites by default.
DOCS_PAGE = "docs/results.md"
#: An experiment's report in the results folder, and its figures beside it.
REPORT_FILE = "results.md"


def experiment_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(description="Run the paper's experiments (missing cells only) and report them.")
    parser.add_argument("names", nargs="*", help="experiments (names of the package's specifications, or YAML files)")
    parser.add_argument("--all", action="store_true", help="every experiment of the package")
    parser.add_argument("--list", action="store_true", help="list the experiments (cells and agent-steps) and exit")
    parser.add_argument("--budget", default="quick", choices=list(BUDGETS), help="quick (this machine) or full (paper)")
    parser.add_argument("--conditions", nargs="+", default=None, metavar="CONDITION",
                        help="run only these conditions' cells (the report still covers every stored cell)")
    parser.add_argument("--backend", default="local", choices=list(BACKENDS), help="local processes or Ray tasks")
    parser.add_argument("--address", default=None, help="Ray cluster address (default: a local Ray instance)")
    parser.add_argument("--gather", action="store_true",
                        help="Ray: bring the run folders of cells run on other nodes to this machine's --root")
    parser.add_argument("--n-jobs", type=int_flag(1, 1024), default=None,
                        help="cells at once (default: this machine's cores; on Ray the cluster's CPUs)")
    parser.add_argument("-f", "--root", default=DEFAULT_ROOT,
                        help="results folder: the cells' runs, the store and the reports")
    parser.add_argument("--store", default=None, help="SQLite store (default: ROOT/results.sqlite)")
    parser.add_argument("--lease", type=float, default=LEASE_SECONDS,
                        help="seconds without a heartbeat after which another host's runner's cells are taken over")
    parser.add_argument("--rerun-stale", action="store_true",
                        help="run again the cells stored by another version of the package (replacing them)")
    parser.add_argument("--report-only", action="store_true", help="regenerate the reports from the store, run nothing")
    parser.add_argument("--no-report", action="store_true", help="run the cells, leave the reports alone")
    parser.add_argument("--allow-mixed-versions", action="store_true",
                        help="report cells made by different versions of the package together")
    parser.add_argument("--update-docs", action="store_true",
                        help="also rewrite the experiments' sections of the results page (--page) and its figures")
    parser.add_argument("--page", default=DOCS_PAGE, help="the results page --update-docs rewrites")
    parser.add_argument("--figures", default=None, help="with --update-docs: the page's figures (default: figures/ "
                        "beside --page)")
    return parser


def _specs(parser: argparse.ArgumentParser, args: argparse.Namespace) -> list[tuple[ExperimentSpec, str | None]]:
    """Every named specification, loaded and checked (with ``--conditions``) before anything runs."""
    if args.all == bool(args.names):
        parser.error("name experiments or give --all (not both)")
    names = list_specs() if args.all else args.names
    specs = []
    for name in names:
        try:
            spec = load_spec(name)
        except ValueError as error:
            parser.error(str(error))
        if args.conditions is not None:
            try:
                spec.cells(args.budget, args.conditions)
            except ValueError as error:
                parser.error(f"--conditions: {error}")
        specs.append((spec, name if Path(name).suffix else None))
    return specs


def _listing() -> list[str]:
    """``--list``: each experiment's name, paper, title and per budget its cells and agent-steps of training."""
    specs = [load_spec(name) for name in list_specs()]
    name_width = max(len(spec.name) for spec in specs) + 2
    paper_width = max(len(spec.paper) for spec in specs) + 2
    lines = [f"{'experiment':<{name_width}}{'paper':<{paper_width}}"
             + "".join(f"{budget + ': cells x agent-steps':<30}" for budget in BUDGETS) + "title"]
    for spec in specs:
        costs = "".join(f"{f'{len(spec.cells(b))} x {spec.budgets[b].n_timesteps:,}':<30}" for b in BUDGETS)
        lines.append(f"{spec.name:<{name_width}}{spec.paper:<{paper_width}}{costs}{spec.title}")
    return lines


def _check_flags(parser: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    """Refuse flags that do not go together, and a Ray address no cluster answers at, before anything is written."""
    if not args.lease > 0:
        parser.error(f"--lease must be > 0 seconds, got {args.lease}")
    if not args.update_docs and (args.page != DOCS_PAGE or args.figures is not None):
        parser.error("--page and --figures name what --update-docs rewrites: give --update-docs with them")
    if args.gather and args.backend != "ray":
        parser.error("--gather brings run folders from Ray's nodes: give --backend ray with it")
    if args.backend == "ray" and not args.report_only and not args.list:
        try:
            check_ray_address(args.address)
        except ValueError as error:
            parser.error(str(error))


def experiment_main(argv: list[str] | None = None) -> int:
    parser = experiment_parser()
    args = parser.parse_args(argv)
    if args.list:
        print("\n".join(_listing()))
        return 0
    _check_flags(parser, args)
    specs = _specs(parser, args)
    root = Path(args.root)
    store = ResultStore(args.store or root / "results.sqlite")
    if not args.report_only:
        for spec, path in specs:
            try:
                run_experiment(spec, args.budget, store, root, backend=args.backend, n_jobs=args.n_jobs,
                               address=args.address, spec_path=path, lease_seconds=args.lease,
                               rerun_stale=args.rerun_stale, gather=args.gather, conditions=args.conditions)
            except (RuntimeError, ValueError) as error:
                print(f"error: {error}", file=sys.stderr)
                return 1
    if args.no_report:
        return 0
    from sb3_emmarl.common.trust.atomic_files import write_text
    from sb3_emmarl.experiments.report import check_versions, render_section, update_results_page

    rows = {spec.name: store.rows(spec.name, args.budget) for spec, _ in specs}
    try:
        for spec, _ in specs:
            check_versions(spec.name, args.budget, rows[spec.name], args.allow_mixed_versions)
    except ValueError as error:
        print(f"error: {error}", file=sys.stderr)
        return 1
    page = Path(args.page)
    docs_figures = Path(args.figures) if args.figures else page.parent / "figures"
    sections = {}
    for spec, _ in specs:
        command = f"python zoo/experiment.py {spec.name} --budget {args.budget}"
        machine = rows[spec.name][0]["hardware"] if rows[spec.name] else hardware()
        report = root / spec.name / args.budget / REPORT_FILE
        section = render_section(spec, rows[spec.name], args.budget, report.parent / "figures", command, machine)
        report.parent.mkdir(parents=True, exist_ok=True)
        write_text(report, section)
        print(f"wrote {report} and its figures")
        if args.update_docs:
            sections[spec.name] = render_section(spec, rows[spec.name], args.budget, docs_figures, command, machine)
    if args.update_docs:
        update_results_page(page, sections)
        print(f"wrote {len(sections)} section(s) of {page} and their figures in {docs_figures}")
    return 0


if __name__ == "__main__":
    sys.exit(experiment_main())
