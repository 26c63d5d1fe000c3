"""`softjig study`: run a design study (designs x parts x poses through simulation and estimation)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any

import typer

from softjig.cli.app import app, handle_errors

WIDE_OUTPUT_COLUMNS = 200  # the summary table's width when stdout is not a terminal


@app.command()
@handle_errors
def study(
    study_file: Annotated[
        Path, typer.Argument(metavar="STUDY.toml", help="The study file (docs/studies.md).")
    ],
    out: Annotated[Path, typer.Option(help="Output folder: results.parquet, designs.parquet, report.html.")],
    workers: Annotated[
        int | None, typer.Option(min=1, help="Local worker processes (with --ray local: its CPUs).")
    ] = None,
    ray: Annotated[
        str | None,
        typer.Option(
            metavar="ADDRESS|auto|local",
            help="Run on a Ray cluster: its address, auto (this machine's) or local (start one here).",
        ),
    ] = None,
    resume: Annotated[
        bool, typer.Option(help="Finish this study in --out: only the tasks not yet finished run.")
    ] = False,
    progress: Annotated[bool, typer.Option(help="Show a progress bar with an ETA on stderr.")] = True,
    report: Annotated[bool, typer.Option(help="Write report.html, figures/ and best/ at the end.")] = True,
) -> None:
    """Run a design study: render and estimate every design; Parquet results.

    Every design is built and validated before any work starts; each finished task is written to
    OUT/parts/ at once, so a stopped study continues with --resume and recomputes nothing it finished."""
    from softjig.cli.app import stderr_console
    from softjig.io.outputs import check_output
    from softjig.study.execute import run_study
    from softjig.study.spec import load_study

    check_output(out, "--out", [study_file])
    loaded = load_study(study_file)
    spec = loaded.spec
    stderr_console().print(
        f"study {spec.name!r}: {spec.n_designs} designs x {len(spec.seeds)} seeds x "
        f"{spec.n_frames} frames x {len(spec.methods)} methods"
    )
    run = run_study(loaded, out, workers=workers, ray=ray, resume=resume, progress=progress, report=report)
    _print_summary(run, spec.paths)
    skipped = f" ({run.skipped} already finished)" if run.skipped else ""
    typer.echo(
        f"wrote {len(run.results)} estimates of {len(run.designs)} design rows to {out} in "
        f"{run.wall_s:.1f} s: {run.ran} tasks run{skipped}"
    )
    folder = run.folder.path
    typer.echo(f"results: {folder / 'results.parquet'}, designs: {folder / 'designs.parquet'}")
    if run.outputs is not None:
        _print_outputs(run.outputs)


def _print_summary(run: Any, paths: tuple[str, ...]) -> None:
    """The designs ranked by RMSE (:func:`softjig.study.report.summary_table`), on stdout."""
    from rich.console import Console

    from softjig.study.report import summary_table

    console = Console()
    if not console.is_terminal:  # a file or a pipe: the whole table, not 80 columns of it
        console = Console(width=WIDE_OUTPUT_COLUMNS)
    console.print(summary_table(run.designs, paths=paths))


def _print_outputs(outputs: Any) -> None:
    """Where the report, its figures and the best rigs are (:class:`softjig.study.report.StudyOutputs`)."""
    typer.echo(f"report: {outputs.report_html} ({len(outputs.figures)} figures)")
    if outputs.best_rigs:
        first = outputs.best_rigs[0]
        typer.echo(
            f"best rigs: {len(outputs.best_rigs)} in {first.parent} (the Pareto front's designs "
            f"{', '.join(str(d) for d in outputs.front_design_ids)}); simulate one with "
            f"`softjig simulate --config {first}`"
        )
    else:
        typer.echo("best rigs: none (no design has an estimate)")
