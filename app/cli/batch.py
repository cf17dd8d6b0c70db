"""``kogei batch``: reprocess sessions in worker processes (a thin shell over :func:`app.batch.runner.run_batch`)."""

from __future__ import annotations

import argparse
import sys

from app.errors import UsageError

__all__ = ["add_parser", "run", "summary_table"]


def add_parser(sub: argparse._SubParsersAction) -> None:
    from app.batch.steps import STEP_NAMES

    p = sub.add_parser("batch", help="reprocess sessions incrementally, one worker process per session",
                       description="Run the processing steps on every SESSION; a step runs again only when its "
                                   "inputs, parameters or code changed (docs/batch.md).")
    p.add_argument("sessions", nargs="+", metavar="SESSION", help="one or more session folders")
    p.add_argument("--steps", default=None, metavar="STEP,...",
                   help=f"steps to run, in pipeline order (default: {','.join(STEP_NAMES)})")
    p.add_argument("--preset", default="standard", choices=["draft", "standard", "reference"],
                   help="speed against accuracy of the geometry and the renders: draft, standard, reference "
                        "(default %(default)s)")
    p.add_argument("--calibration", default=None, metavar="CAL_SESSION|CAL.json",
                   help="install this scanner calibration into every session before its geometry step")
    p.add_argument("--chart", default="classic24", choices=["classic24", "sg140", "vinyl18"],
                   help="the colour chart in the chart frames (colour step) (default %(default)s)")
    p.add_argument("--workers", type=int, default=1, metavar="N",
                   help="worker processes on this machine, each with one session at a time (default %(default)s)")
    p.add_argument("--dask", default=None, metavar="tcp://SCHEDULER:8786",
                   help="run the sessions on a Dask distributed cluster instead (default: this machine)")
    p.add_argument("--quiet", action="store_true", help="no progress bars")


def summary_table(summary) -> object:
    """A ``rich`` table: one row per session with its status, the reason of a failure, and each step."""
    from rich.table import Table

    table = Table(title="kogei batch", caption=f"{len(summary.results)} session(s), {summary.engine}, "
                                              f"{summary.workers} worker(s), {summary.seconds:.1f} s")
    table.add_column("session", overflow="fold")
    table.add_column("result")
    table.add_column("steps", overflow="fold")
    table.add_column("reason", overflow="fold")
    style = {"ok": "green", "skipped": "cyan", "failed": "bold red", "interrupted": "yellow"}
    for r in summary.results:
        steps = ", ".join(f"{s.name} {s.status}" + (f" {s.seconds:.1f} s" if s.status == "ran" else "")
                          for s in r.steps)
        label = "skipped (up to date)" if r.status == "skipped" else r.status
        table.add_row(r.session, f"[{style.get(r.status, '')}]{label}[/]", steps, r.reason)
    return table


def run(args: argparse.Namespace) -> int:
    from rich.console import Console

    from app.batch.runner import run_batch
    from app.batch.steps import BatchOptions

    if args.workers < 1:
        raise UsageError(f"--workers must be >= 1, got {args.workers}")
    options = BatchOptions(preset=args.preset, calibration=args.calibration, chart=args.chart)
    summary = run_batch(args.sessions, args.steps, options=options, workers=args.workers, dask=args.dask,
                        progress=not args.quiet)
    Console(file=sys.stdout, width=max(100, Console().width)).print(summary_table(summary))
    counts = ", ".join(f"{summary.count(s)} {s}" for s in ("ok", "skipped", "failed", "interrupted") if summary.count(s))
    print(f"{counts}; logs: SESSION/batch.log", file=sys.stderr)
    return summary.exit_code
