"""`obsbench report`: paper-style tables (Markdown + HTML), plots and a JSON summary from results.jsonl and/or
one of the paper's published tables (`bench.report`)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from lerobot_obsbench.commands import common
from lerobot_obsbench.errors import UsageError
from lerobot_obsbench.outputs import check_output_file, check_output_folder, record_outputs, write_text_atomic

NAME = "report"
HELP = "paper-style tables (Markdown + HTML) and plots from results.jsonl and/or a published table"
EXAMPLE = """obsbench report outputs/bench/quick/results.jsonl --json outputs/bench/quick/summary.json"""
# What `write_report` writes in --out whatever the results hold (the figures' names depend on them).
REPORT_FILES = ("report.md", "report.html")


def add_arguments(p: argparse.ArgumentParser) -> None:
    from lerobot_obsbench.bench.report import CHECKPOINT_CHOICES, published_tables

    p.add_argument("results", type=Path, nargs="?", default=None, help="results.jsonl written by `obsbench run`")
    p.add_argument(
        "--table",
        default=None,
        help="published table: a CSV (rows = tasks, columns = methods, values = success rates in [0, 1]) or the "
        f"name of one of the paper's tables shipped with the plugin: {', '.join(published_tables())}",
    )
    p.add_argument(
        "--checkpoint",
        default="best",
        choices=CHECKPOINT_CHOICES,
        help="which checkpoint's test "
        "evaluations the tables show: best on the validation seeds (where a run has one) or last",
    )
    p.add_argument(
        "--out",
        type=Path,
        default=None,
        help="report directory (default: next to the results); its report.md, report.html and figures are replaced "
        "only when a report of the same results and table wrote them, or with --overwrite",
    )
    p.add_argument(
        "--json",
        type=Path,
        default=None,
        help="write mean_sr and mean_rank per method here (an existing file: as --out's files)",
    )
    p.add_argument(
        "--overwrite",
        action="store_true",
        help="replace --out's report files and the --json file even when another report or no report wrote them",
    )
    p.add_argument(
        "--grid",
        default=None,
        help="a grid file or preset name: report only the runs it names, and their evaluations (a results file "
        "shared by several grids, or holding runs of a budget the grid no longer gives)",
    )
    p.add_argument("--title", default="OBSBench report")
    p.add_argument(
        "--reference",
        default=None,
        help="a column label (as the tables print it): every method's probability of improvement over it is added "
        "beside the one over its blind control",
    )


def run(args: argparse.Namespace) -> int:
    import json

    from lerobot_obsbench.bench.report import (
        ReportError,
        build_report,
        markdown_table,
        read_published,
        resolve_table,
        summary_json,
        write_report,
    )
    from lerobot_obsbench.bench.results import read_results

    if args.results is None and args.table is None:
        raise UsageError("give a results file (results.jsonl) and/or --table FILE.csv")
    if args.results is not None and not args.results.is_file():
        raise ReportError(f"results file {args.results} not found (`obsbench run` writes OUT/results.jsonl)")
    out = args.out or (args.results.parent / "report" if args.results else Path("report"))
    inputs = [path for path in (args.results, args.table) if path is not None and Path(path).exists()]
    table = resolve_table(args.table) if args.table else None
    # a report of the same results and table regenerates its own files in place; anything else needs --overwrite
    made_by = {
        "writer": "obsbench report",
        "results": str(args.results.resolve()) if args.results else None,
        "table": str(Path(table).resolve()) if table else None,
        **({"grid": str(args.grid)} if args.grid else {}),
    }
    check_output_folder(out, "--out", inputs, files=REPORT_FILES, made_by=made_by, overwrite=args.overwrite)
    if args.json:  # never over the results it summarises, nor over the report it writes beside
        refuse_json_among(args.json, out, REPORT_FILES)
        check_output_file(args.json, "--json", args.overwrite, inputs, made_by)
    records = read_results(args.results) if args.results else []
    if args.results and not records:
        print(f"warning: no readable records in {args.results}", file=sys.stderr)
    if args.grid:
        records = grid_records(records, args.grid)
    published = read_published(table) if table else None
    report = build_report(
        records,
        published,
        published_name=table.stem if table else "published",
        checkpoint=args.checkpoint,
        reference=args.reference,
    )
    # the figures' names depend on the results: checked once the report is built, before anything is written
    check_output_folder(out, "--out", inputs, files=report["figures"], made_by=made_by, overwrite=args.overwrite)
    if args.json:
        refuse_json_among(args.json, out, report["figures"])
    paths = write_report(report, out, title=args.title)
    record_outputs([*paths.values(), *(out / name for name in report["figures"])], made_by)
    heading, (header, rows) = report["sections"][0]
    print(f"{heading}\n{markdown_table(header, rows)}")
    for warning in report["warnings"]:
        print(f"note: {warning}")
    for source, methods in report["summary"].items():
        for method, s in sorted(methods.items(), key=lambda kv: kv[1]["mean_rank"]):
            print(f"{source:9s} {method:45s} Mean S.R. {s['mean_sr']:.2f}  Mean Rank {s['mean_rank']:.2f}")
    if args.json:
        write_text_atomic(args.json, json.dumps(summary_json(report), indent=2) + "\n")
        record_outputs([args.json], made_by)
    print(f"report: {paths['markdown']}, {paths['html']}" + (f"; summary: {args.json}" if args.json else ""))
    return 0


def refuse_json_among(summary: Path, out: Path, files) -> None:
    """Refuse a --json path that is one of the files the report writes in `out` (the summary would replace it)."""
    if summary.resolve().parent == out.resolve() and summary.name in files:
        raise UsageError(
            f"--json {summary}: the report writes {summary.name} in --out {out}, and the summary would replace it; "
            "give the summary a name of its own (e.g. summary.json)"
        )


def grid_records(records: list[dict], grid_name: str) -> list[dict]:
    """The records of the runs `grid_name` names; a ReportError when it names none of the file's runs."""
    from lerobot_obsbench.bench.grid import load_grid
    from lerobot_obsbench.bench.report import ReportError

    run_ids = {run.run_id for run in load_grid(grid_name).expand()}
    kept = [record for record in records if record.get("run_id") in run_ids]
    if records and not kept:
        raise ReportError(f"the results hold none of the {len(run_ids)} runs grid {grid_name!r} names")
    return kept


def main(argv: list[str] | None = None) -> int:
    return common.main(sys.modules[__name__], argv)


if __name__ == "__main__":
    sys.exit(main())
