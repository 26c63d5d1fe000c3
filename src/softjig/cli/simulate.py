"""`softjig simulate`: render a simulated dataset."""

from __future__ import annotations

import time
from enum import StrEnum
from pathlib import Path
from typing import Annotated

import typer

from softjig.cli.app import app, handle_errors, load_config, parse_numbers
from softjig.errors import InputError


class Scenario(StrEnum):
    paper_sweep = "paper-sweep"
    cube = "cube"
    single = "single"
    zoo = "zoo"


@app.command()
@handle_errors
def simulate(
    scenario: Annotated[Scenario, typer.Option(help="What to render.")] = Scenario.paper_sweep,
    out: Annotated[
        Path | None, typer.Option(help="Dataset folder to write.", show_default="out/sim-SCENARIO")
    ] = None,
    config: Annotated[
        Path | None, typer.Option(help="The nominal jig (rig.toml).", show_default="the paper's jig")
    ] = None,
    seed: Annotated[int, typer.Option(min=0, help="Seed of the as-built jig and of every frame.")] = 0,
    diameters: Annotated[
        str | None,
        typer.Option(help="paper-sweep: cylinder diameters in mm.", show_default="30,40,50,60,70,80"),
    ] = None,
    alphas: Annotated[
        str | None, typer.Option(help="paper-sweep: tilts in degrees.", show_default="5,10,15,20")
    ] = None,
    theta_step: Annotated[
        float | None, typer.Option(help="paper-sweep: azimuth step in degrees.", show_default="10")
    ] = None,
    push_depth: Annotated[
        float | None,
        typer.Option(help="Push depth of the part in mm (not zoo: it draws 2-8 mm).", show_default="3"),
    ] = None,
    part_diameter: Annotated[
        float | None, typer.Option(help="single: the cylinder's diameter in mm.")
    ] = None,
    alpha: Annotated[float | None, typer.Option(help="single: tilt in degrees.", show_default="0")] = None,
    theta: Annotated[
        float | None, typer.Option(help="single: tilt azimuth in degrees.", show_default="0")
    ] = None,
    frames: Annotated[
        int | None,
        typer.Option(
            help="cube: number of loaded frames; zoo: loaded frames per design.", show_default="60, 20"
        ),
    ] = None,
    designs: Annotated[
        int | None, typer.Option(help="zoo: number of random jig designs.", show_default="10")
    ] = None,
    workers: Annotated[
        int | None, typer.Option(min=1, help="Rendering processes.", show_default="all CPUs")
    ] = None,
    color: Annotated[bool, typer.Option(help="Render colour (RGB) images instead of gray.")] = False,
    overwrite: Annotated[
        bool, typer.Option(help="Replace a dataset softjig simulated in --out (never a recording).")
    ] = False,
    progress: Annotated[bool, typer.Option(help="Show a progress bar on stderr.")] = True,
) -> None:
    """Render a simulated dataset: the paper's sweep, the cube experiment, a single frame or a jig zoo.

    The zoo draws random jig designs into DIR/000, DIR/001, ...: each a dataset with its own rig, its
    reference frame first."""
    from softjig.config import CylinderPart
    from softjig.io import simulated
    from softjig.sim import scenarios

    given = {
        "--diameters": diameters,
        "--alphas": alphas,
        "--theta-step": theta_step,
        "--part-diameter": part_diameter,
        "--alpha": alpha,
        "--theta": theta,
        "--frames": frames,
        "--designs": designs,
        "--push-depth": push_depth,
    }
    allowed = {
        Scenario.paper_sweep: {"--diameters", "--alphas", "--theta-step", "--push-depth"},
        Scenario.cube: {"--frames", "--push-depth"},
        Scenario.single: {"--part-diameter", "--alpha", "--theta", "--push-depth"},
        Scenario.zoo: {"--frames", "--designs"},
    }[scenario]
    stray = [name for name, value in given.items() if value is not None and name not in allowed]
    if stray:
        raise InputError(
            f"{', '.join(stray)} do(es) not apply to --scenario {scenario.value} "
            f"(it takes {', '.join(sorted(allowed))})"
        )
    from softjig.io.outputs import check_output

    if out is not None:  # an --overwrite never replaces a folder holding the config it reads
        check_output(out, "--out", [config])
    if scenario is Scenario.zoo:
        if config is not None:
            raise InputError("--config does not apply to --scenario zoo (each design draws its own jig)")
        _simulate_zoo(
            out or Path("out") / "sim-zoo",
            designs=10 if designs is None else designs,
            frames=20 if frames is None else frames,
            seed=seed,
            workers=workers,
            progress=progress,
            overwrite=overwrite,
            color=color,
        )
        return
    jig = load_config(config)
    push_depth = 3.0 if push_depth is None else push_depth
    if scenario is Scenario.paper_sweep:
        specs = list(
            scenarios.paper_sweep(
                diameters_mm=parse_numbers(diameters, "--diameters")
                if diameters
                else scenarios.PAPER_DIAMETERS_MM,
                alphas_deg=parse_numbers(alphas, "--alphas") if alphas else scenarios.PAPER_ALPHAS_DEG,
                theta_step_deg=10.0 if theta_step is None else theta_step,
                push_depth_mm=push_depth,
            )
        )
    elif scenario is Scenario.cube:
        specs = scenarios.cube_experiment(
            n_frames=60 if frames is None else frames, push_depth_mm=push_depth, rng=seed
        )
    else:
        if part_diameter is None:
            raise InputError("--scenario single needs --part-diameter MM (and optionally --alpha, --theta)")
        specs = scenarios.single(
            CylinderPart(diameter_mm=part_diameter), alpha or 0.0, theta or 0.0, push_depth
        )
    out = out or Path("out") / f"sim-{scenario.value}"
    t0 = time.perf_counter()
    simulated.simulate_dataset(
        out, specs, jig, seed=seed, workers=workers, progress=progress, overwrite=overwrite, color=color
    )
    if scenario is Scenario.cube:  # the cube's true poses as motion capture would export them
        from softjig.evaluation.experiment import write_simulated_mocap
        from softjig.io.dataset import Dataset

        write_simulated_mocap(Dataset.open(out), out / "mocap.csv")
        typer.echo(f"wrote the motion capture (Motive CSV) to {out / 'mocap.csv'}: softjig mocap {out}")
    typer.echo(f"wrote {len(specs)} frames to {out} in {time.perf_counter() - t0:.1f} s")


def _simulate_zoo(
    out: Path,
    *,
    designs: int,
    frames: int,
    seed: int,
    workers: int | None,
    progress: bool,
    overwrite: bool,
    color: bool,
) -> None:
    """Draw the zoo's designs and write each as a dataset ``out/NNN`` (see :mod:`softjig.sim.zoo`)."""
    import json

    from softjig.files import write_text_atomic
    from softjig.io import simulated
    from softjig.sim.zoo import ZooRanges, draw_designs

    t0 = time.perf_counter()
    ranges = ZooRanges()
    manifest = []
    for design in draw_designs(designs, seed=seed, frames=frames, ranges=ranges):
        target = out / f"{design.index:03d}"
        simulated.simulate_dataset(
            target,
            design.specs,
            design.jig,
            seed=design.seed,
            workers=workers,
            progress=progress,
            overwrite=overwrite,
            color=color,
        )
        manifest.append(
            {
                "design": design.index,
                "dir": target.name,
                "seed": design.seed,
                "family": design.family,
                **design.labels,
            }
        )
        write_text_atomic(
            out / "zoo.json", json.dumps({"seed": seed, "frames": frames, "designs": manifest}, indent=1)
        )
    typer.echo(
        f"wrote {len(manifest)} designs x {frames + 1} frames to {out} in {time.perf_counter() - t0:.1f} s"
    )
