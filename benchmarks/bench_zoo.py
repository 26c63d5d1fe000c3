"""Accuracy and trust of the default estimator across a zoo of random jig designs, beside the paper sweep.

Run: ``python benchmarks/bench_zoo.py [--designs 50] [--frames 20] [--seed 0] [--json-out FILE]
[--write benchmarks/RESULTS.md]``; ``--designs 3 --frames 4 --sweep-step 90`` is a quick run (about a
minute). Everything is rendered in memory, in this process, on one core.

What it does
------------
1. Draws ``--designs`` random designs with :func:`softjig.sim.zoo.draw_designs` (the ranges of
   :class:`softjig.sim.zoo.ZooRanges`, the seed ``--seed``): each a nominal jig, an unloaded reference
   frame and ``--frames`` loaded frames of random parts. Each design is rendered exactly as
   ``softjig simulate --scenario zoo`` would write it (the as-built jig drawn from the design's seed,
   frame ``i`` rendered from ``SeedSequence(seed, spawn_key=(1, i))``).
2. Estimates every loaded frame with the default method (an :class:`~softjig.sensing.estimator.Estimator`
   per design and reference) four ways: with the part's size (``part_diameter_mm``: the part's
   ``diameter_mm``) or without it (``None``), each with the design's reference frame
   (:meth:`~softjig.sensing.estimator.Estimator.reference_from_pair`) or with the nominal rest shape
   (``reference=None``).
3. Reports, per design family and overall, for each of the four ways:

   - **RMSE**, **p95** and **max** of the angular error: the angle (deg) between the estimated and the
     true principal normal (``frame_truth``: the part's bottom-face normal in J), over frames with an
     estimate;
   - **failures**: frames without an estimate (``EstimationError`` or ``InputError``);
   - **silent failures**: error > 3 deg **and** error > 4 ``tilt_sigma_deg`` **and** quality ``"ok"``
     (``getattr(estimate, "quality", "ok")``: an estimator without a quality field counts as ``"ok"``);
   - **1-sigma coverage**: the fraction of estimated frames whose angular error is at most the reported
     ``tilt_sigma_deg`` (the 1-sigma of the angle between the estimated and the true normal). For an
     isotropic 2-D Gaussian error of the normal with per-axis sigma ``s``, the angle is Rayleigh
     distributed and ``P(angle <= s) = 1 - exp(-1/2) = 39 %``; if ``tilt_sigma_deg`` is the RMS angle
     ``s sqrt(2)``, ``P = 1 - exp(-1) = 63 %``. Frames without a sigma count as not covered.

   and the time per pair (estimate only, median ms) against the number of markers in contact (truth:
   in contact and visible in both images), in bins; and, per way, **why estimates were suspect**: each
   self-check's reason (its words up to the first comma or colon, numbers as ``N``), how many estimates
   gave it, how many of those were within 1 deg (false alarms) or over 3 deg off, and how many gave it
   alone.
4. The paper sweep on the default jig (diameters 30-80 mm, tilts 5-20 deg, azimuth step
   ``--sweep-step``): RMSE per diameter and tilt, with the part's size and the reference frame (what
   ``softjig demo`` does), and the four ways overall.

``--json-out FILE`` writes one JSON object per line and per frame and way (design, family, frame, way,
error, sigma, quality, contact markers, time, failure reason, suspect reasons, the estimated normal), for
iterating on the estimator (two ways' normals of a frame say how far apart they lie).
``--write FILE`` replaces (or appends) this benchmark's section of ``benchmarks/RESULTS.md``.
``--image-model stirred`` renders with the simulator's old image model (a new speckle every frame and
none of the bead-pack effects), for comparison; ``--image-model damaged`` with each design's own model
plus a damaged membrane, bubbles and glints (:func:`softjig.sim.zoo.damaged_image_model`);
``--image-model gentle-walls`` with a bead pack whose wall beside a contact stands at 20 deg instead of 35
(:func:`softjig.sim.zoo.gentle_wall_model`: membrane mechanics, not an image model, that no design has).
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import itertools  # noqa: E402
import json  # noqa: E402
import math  # noqa: E402
import platform  # noqa: E402
import re  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from collections import defaultdict  # noqa: E402
from collections.abc import Iterable, Sequence  # noqa: E402
from dataclasses import dataclass  # noqa: E402
from pathlib import Path  # noqa: E402

import cv2  # noqa: E402
import numpy as np  # noqa: E402

from softjig.config import JigConfig, default_jig  # noqa: E402
from softjig.errors import EstimationError, InputError  # noqa: E402
from softjig.sensing.estimator import Estimator  # noqa: E402
from softjig.sim.asbuilt import draw_as_built  # noqa: E402
from softjig.sim.render import render_pair  # noqa: E402
from softjig.sim.scenarios import FrameSpec, frame_truth, paper_sweep  # noqa: E402
from softjig.sim.zoo import damaged_image_model, gentle_wall_model, stirred_image_model  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from results_section import replace_section  # noqa: E402

WAYS = (
    ("size+reference", True, True),
    ("size+rest shape", True, False),
    ("no size+reference", False, True),
    ("no size+rest shape", False, False),
)
#: ``--image-model``: how each design's jig is rendered (``None``: its own bead-pack model).
IMAGE_MODELS = {
    "bead-pack": None,
    "stirred": stirred_image_model,
    "damaged": damaged_image_model,
    "gentle-walls": gentle_wall_model,
}
SILENT_ERROR_DEG = 3.0
RIGHT_DEG = 1.0  # a suspect estimate within this of the truth is a false alarm (the reasons' table)
SUSPECT_PREFIX = "suspect: "  # softjig.sensing.results.SUSPECT_PREFIX
SILENT_SIGMAS = 4.0
CONTACT_BINS = (0, 20, 40, 80, 150, 300, 100_000)
SECTION = "## Jig zoo (benchmarks/bench_zoo.py)"


@dataclass(frozen=True)
class Row:
    """One frame estimated one way."""

    design: int
    family: str
    frame: int
    way: str
    part: str
    part_size_mm: float
    alpha_deg: float
    offset_mm: float
    error_deg: float | None
    sigma_deg: float | None
    quality: str | None
    n_contact: int
    n_points: int | None
    time_ms: float | None
    failure: str | None
    frame_source: str | None = None
    bound_deg: float | None = None
    reasons: tuple[str, ...] = ()  # the suspect estimate's reasons (reason_kind of each)
    normal: tuple[float, ...] | None = None  # the estimated normal (J): to compare two ways of a frame

    @property
    def silent(self) -> bool:
        if self.error_deg is None or self.quality != "ok":
            return False
        sigma = self.sigma_deg if self.sigma_deg is not None else 0.0
        return self.error_deg > SILENT_ERROR_DEG and self.error_deg > SILENT_SIGMAS * sigma

    @property
    def covered(self) -> bool:
        return self.error_deg is not None and self.sigma_deg is not None and self.error_deg <= self.sigma_deg


def _angle_deg(a: Sequence[float], b: Sequence[float]) -> float:
    a, b = np.asarray(a, float), np.asarray(b, float)
    c = float(np.dot(a, b) / (np.linalg.norm(a) * np.linalg.norm(b)))
    return math.degrees(math.acos(min(1.0, max(-1.0, c))))


def evaluate_design(
    nominal: JigConfig,
    specs: Sequence[FrameSpec],
    seed: int,
    *,
    design: int,
    family: str,
    render_jig=None,
) -> list[Row]:
    """Render a design's frames in memory (as ``simulate_dataset`` would) and estimate each loaded frame
    the four ways; ``specs[0]`` must be the unloaded reference frame. ``render_jig`` maps the nominal
    jig to the one rendered (an image-model variant), default itself."""
    rendered_nominal = render_jig(nominal) if render_jig else nominal
    as_built = draw_as_built(
        rendered_nominal, np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(0,)))
    )
    rows: list[Row] = []
    reference = None
    estimators = {False: Estimator(nominal), True: None}  # built once per design (with_reference: by key)
    for index, spec in enumerate(specs):
        rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(1, index)))
        pair = render_pair(as_built, spec.part, spec.pose, rng)
        if spec.part is None:
            try:
                reference = estimators[False].reference_from_pair(pair.left, pair.right)
            except (EstimationError, InputError):
                reference = None
            estimators[True] = estimators[False].with_reference(reference) if reference is not None else None
            continue
        truth = frame_truth(as_built.jig, spec.pose)["normal"]
        m = pair.markers
        n_contact = int(np.sum(m.in_contact & m.visible_left & m.visible_right))
        size = float(spec.part.diameter_mm)
        offset = float(np.hypot(*spec.pose.center_xy_mm))
        for way, with_size, with_reference in WAYS:
            common = dict(
                design=design,
                family=family,
                frame=index,
                way=way,
                part=spec.part.kind,
                part_size_mm=size,
                alpha_deg=math.degrees(spec.pose.alpha_rad),
                offset_mm=offset,
                n_contact=n_contact,
            )
            if with_reference and reference is None:
                rows.append(
                    Row(
                        **common,
                        error_deg=None,
                        sigma_deg=None,
                        quality=None,
                        n_points=None,
                        time_ms=None,
                        failure="no reference",
                    )
                )
                continue
            t0 = time.perf_counter()
            try:
                est = (
                    estimators[bool(with_reference)]
                    .estimate(pair.left, pair.right, part_diameter_mm=size if with_size else None)
                    .estimate
                )
            except (EstimationError, InputError) as exc:
                rows.append(
                    Row(
                        **common,
                        error_deg=None,
                        sigma_deg=None,
                        quality=None,
                        n_points=None,
                        time_ms=None,
                        failure=str(exc)[:120],
                    )
                )
                continue
            dt = 1e3 * (time.perf_counter() - t0)
            rows.append(
                Row(
                    **common,
                    error_deg=_angle_deg(est.normal, truth),
                    sigma_deg=est.tilt_sigma_deg,
                    quality=getattr(est, "quality", "ok"),
                    n_points=est.n_points,
                    time_ms=dt,
                    failure=None,
                    frame_source=est.frame_source,
                    bound_deg=scatter_bound_deg(est),
                    reasons=tuple(reason_kind(w) for w in est.warnings if w.startswith(SUSPECT_PREFIX)),
                    normal=tuple(float(v) for v in est.normal),
                )
            )
    return rows


def scatter_bound_deg(estimate) -> float | None:
    """The RMS angle (deg) that the fitted markers' own scatter alone allows, a Cramer-Rao-like bound:
    ``sqrt(2) s / sqrt(N var_x)`` for ``N`` markers of RMS residual ``s`` spread over the contact's
    footprint as over a uniform disc of its area ``A`` (``var_x = A / (4 pi)`` per axis); ``None`` for an
    estimate without a footprint (the paper's method)."""
    area = getattr(estimate, "contact_area_mm2", None)
    if not area or not estimate.n_points:
        return None
    per_axis = estimate.rms_residual_mm / math.sqrt(estimate.n_points * area / (4.0 * math.pi))
    return math.degrees(math.sqrt(2.0) * per_axis)


def reason_kind(warning: str) -> str:
    """A suspect reason without its numbers: ``"suspect: only 16 markers were fitted, too few ..."`` ->
    ``"only N markers were fitted"`` (the words up to the first comma or colon, numbers as ``N``)."""
    text = re.sub(r"\d+(\.\d+)?", "N", warning.removeprefix(SUSPECT_PREFIX))
    text = re.sub(r"\bN marker (.*?) lies\b", r"N markers \1 lie", text)  # one kind, singular or plural
    return re.split(r"[,:]", text, maxsplit=1)[0].strip()


def reasons_table(rows: Sequence[Row]) -> list[str]:
    """Per way, each suspect reason: the estimates that gave it, those within :data:`RIGHT_DEG` (false
    alarms) and over :data:`SILENT_ERROR_DEG` (caught), and those that gave no other reason."""
    out = [
        "**Zoo: why estimates were suspect (every part)**",
        "",
        f"| way | reason | estimates | within {RIGHT_DEG:g} deg | over {SILENT_ERROR_DEG:g} deg | alone |",
        "|---|---|---|---|---|---|",
    ]
    for way, *_ in WAYS:
        sel = [r for r in rows if r.way == way and r.quality == "suspect" and r.error_deg is not None]
        counts: dict[str, list[int]] = defaultdict(lambda: [0, 0, 0, 0])
        for r in sel:
            for kind in set(r.reasons):
                c = counts[kind]
                c[0] += 1
                c[1] += r.error_deg <= RIGHT_DEG
                c[2] += r.error_deg > SILENT_ERROR_DEG
                c[3] += len(set(r.reasons)) == 1
        for kind, (n, right, wrong, alone) in sorted(counts.items(), key=lambda kv: -kv[1][0]):
            out.append(f"| {way} | {kind} | {n} | {right} | {wrong} | {alone} |")
    return [*out, ""]


def summary(rows: Sequence[Row]) -> dict[str, float]:
    """RMSE, p95, max (deg), failures, silent failures, coverage (%) and frames of a set of rows."""
    errors = np.array([r.error_deg for r in rows if r.error_deg is not None])
    est = [r for r in rows if r.error_deg is not None]
    return {
        "frames": len(rows),
        "rmse": float(np.sqrt(np.mean(errors**2))) if len(errors) else math.nan,
        "p95": float(np.percentile(errors, 95)) if len(errors) else math.nan,
        "max": float(errors.max()) if len(errors) else math.nan,
        "failures": sum(r.error_deg is None for r in rows),
        "silent": sum(r.silent for r in rows),
        "suspect": sum(r.quality not in (None, "ok") for r in rows),
        "coverage": 100.0 * sum(r.covered for r in est) / len(est) if est else math.nan,
    }


def table_by(rows: Sequence[Row], key, title: str) -> list[str]:
    """A Markdown table: one row per (group, way)."""
    groups: dict[str, list[Row]] = defaultdict(list)
    for r in rows:
        groups[key(r)].append(r)
    out = [
        f"**{title}**",
        "",
        "| group | way | frames | RMSE deg | p95 deg | max deg | failed | silent | suspect | 1-sigma cover |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for g in sorted(groups):
        for way, *_ in WAYS:
            sel = [r for r in groups[g] if r.way == way]
            if not sel:
                continue
            s = summary(sel)
            out.append(
                f"| {g} | {way} | {s['frames']} | {s['rmse']:.2f} | {s['p95']:.2f} | {s['max']:.2f} | "
                f"{s['failures']} | {s['silent']} | {s['suspect']} | {s['coverage']:.0f} % |"
            )
    return [*out, ""]


def accuracy_table(rows: Sequence[Row]) -> list[str]:
    """What limits the accuracy: RMSE against the markers in contact and where the cameras' pose came
    from, beside the RMS reported sigma and the bound of the fitted markers' own scatter
    (:func:`scatter_bound_deg`), for the goals' set (parts >= 40 mm), each way. Against the rest shape,
    a frame without fiducials in view has the config's poses (``config``): no reference frame levelled
    the head."""
    out = [
        "**Zoo, parts >= 40 mm: RMSE against markers in contact and where the cameras' pose came from**",
        "",
        "| way | pose from | markers in contact | frames | RMSE deg | RMS sigma deg | scatter bound deg | "
        "1-sigma cover |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for way, *_ in WAYS:
        for source in sorted({r.frame_source for r in rows if r.frame_source is not None}):
            for lo, hi in itertools.pairwise((0, 20, 40, 80, 100_000)):
                sel = [
                    r
                    for r in rows
                    if r.way == way
                    and r.part_size_mm >= 40
                    and r.frame_source == source
                    and lo <= r.n_contact < hi
                    and r.error_deg is not None
                ]
                if not sel:
                    continue

                def rms(values):
                    v = np.array([x for x in values if x is not None], dtype=float)
                    return float(np.sqrt(np.mean(v**2))) if len(v) else math.nan

                label = f"{lo}-{hi - 1}" if hi < 100_000 else f">= {lo}"
                cover = 100.0 * sum(r.covered for r in sel) / len(sel)
                out.append(
                    f"| {way} | {source} | {label} | {len(sel)} | {rms([r.error_deg for r in sel]):.2f} | "
                    f"{rms([r.sigma_deg for r in sel]):.2f} | {rms([r.bound_deg for r in sel]):.2f} | "
                    f"{cover:.0f} % |"
                )
    return [*out, ""]


def timing_table(rows: Sequence[Row]) -> list[str]:
    """Median estimate time per pair against the markers in contact (the default way)."""
    sel = [r for r in rows if r.way == WAYS[0][0] and r.time_ms is not None]
    out = [
        "**Time per pair (size+reference) against markers in contact**",
        "",
        "| markers in contact | frames | median ms | p90 ms |",
        "|---|---|---|---|",
    ]
    for lo, hi in itertools.pairwise(CONTACT_BINS):
        t = [r.time_ms for r in sel if lo <= r.n_contact < hi]
        if t:
            label = f"{lo}-{hi - 1}" if hi < 100_000 else f">= {lo}"
            out.append(f"| {label} | {len(t)} | {np.median(t):.1f} | {np.percentile(t, 90):.1f} |")
    return [*out, ""]


def sweep_tables(rows: Sequence[Row]) -> list[str]:
    """The paper sweep: RMSE per diameter and tilt (size+reference), then the four ways overall."""
    sel = [r for r in rows if r.way == WAYS[0][0]]
    diameters = sorted({r.part_size_mm for r in sel})
    alphas = sorted({round(r.alpha_deg, 6) for r in sel})
    out = [
        "**Paper sweep, default jig (size+reference): RMSE deg per diameter and tilt**",
        "",
        "| diameter mm | " + " | ".join(f"alpha {a:g}" for a in alphas) + " |",
        "|---|" + "---|" * len(alphas),
    ]
    for d in diameters:
        cells = []
        for a in alphas:
            e = [r.error_deg for r in sel if r.part_size_mm == d and round(r.alpha_deg, 6) == a]
            e = [x for x in e if x is not None]
            cells.append(f"{math.sqrt(np.mean(np.square(e))):.2f}" if e else "-")
        out.append(f"| {d:g} | " + " | ".join(cells) + " |")
    out.append("")
    return [*out, *table_by(rows, lambda r: "paper sweep", "Paper sweep, default jig, the four ways")]


def run_sweep(step_deg: float, seed: int, render_jig=None) -> list[Row]:
    specs = list(paper_sweep(theta_step_deg=step_deg))
    return evaluate_design(default_jig(), specs, seed, design=-1, family="paper sweep", render_jig=render_jig)


def run_zoo(n_designs: int, n_frames: int, seed: int, render_jig=None, progress: bool = True) -> list[Row]:
    from softjig.sim.zoo import ZooRanges, draw_designs

    rows: list[Row] = []
    t0 = time.perf_counter()
    for design in draw_designs(n_designs, seed=seed, frames=n_frames, ranges=ZooRanges()):
        rows += evaluate_design(
            design.jig,
            design.specs,
            design.seed,
            design=design.index,
            family=design.family,
            render_jig=render_jig,
        )
        if progress:
            print(
                f"  design {design.index + 1}/{n_designs} ({design.family}) {time.perf_counter() - t0:.0f} s",
                file=sys.stderr,
            )
    return rows


def write_section(path: Path, lines: Iterable[str]) -> None:
    """Replace this benchmark's section of ``path``, or append it."""
    replace_section(path, SECTION, lines)


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--designs", type=int, default=50)
    parser.add_argument("--frames", type=int, default=20, help="loaded frames per design")
    parser.add_argument("--seed", type=int, default=0, help="the zoo's seed")
    parser.add_argument("--sweep-step", type=float, default=30.0, help="paper sweep's azimuth step (deg)")
    parser.add_argument("--no-sweep", action="store_true", help="skip the paper sweep")
    parser.add_argument("--no-zoo", action="store_true", help="skip the zoo")
    parser.add_argument("--image-model", choices=tuple(IMAGE_MODELS), default="bead-pack")
    parser.add_argument("--json-out", type=Path, help="per-frame results, one JSON object per line")
    parser.add_argument("--write", type=Path, help="replace this benchmark's section of this Markdown file")
    args = parser.parse_args(argv)
    cv2.setNumThreads(1)
    render_jig = IMAGE_MODELS[args.image_model]
    t0 = time.perf_counter()
    zoo = [] if args.no_zoo else run_zoo(args.designs, args.frames, args.seed, render_jig)
    t_zoo = time.perf_counter() - t0
    sweep = [] if args.no_sweep else run_sweep(args.sweep_step, 0, render_jig)
    lines = [
        f"`python benchmarks/bench_zoo.py --designs {args.designs} --frames {args.frames} --seed {args.seed} "
        f"--sweep-step {args.sweep_step:g} --image-model {args.image_model}`; "
        f"{platform.processor() or platform.machine()}, Python {platform.python_version()}, one core; "
        f"zoo {t_zoo:.0f} s. Silent: error > {SILENT_ERROR_DEG:g} deg and > {SILENT_SIGMAS:g} sigma and "
        "quality ok; 1-sigma coverage: error <= tilt_sigma_deg.",
        "",
    ]
    if zoo:
        lines += table_by(zoo, lambda r: "all designs", "Zoo, all designs")
        lines += table_by(
            [r for r in zoo if r.part_size_mm >= 40],
            lambda r: "parts >= 40 mm",
            "Zoo, parts >= 40 mm across (the goals' set)",
        )
        lines += table_by(zoo, lambda r: r.family, "Zoo, per design family")
        lines += accuracy_table(zoo)
        lines += timing_table(zoo)
        lines += reasons_table(zoo)
    if sweep:
        lines += sweep_tables(sweep)
    print("\n".join(lines))
    if args.json_out:
        with open(args.json_out, "w") as fh:
            for r in [*zoo, *sweep]:
                fh.write(json.dumps({**r.__dict__, "silent": r.silent, "covered": r.covered}) + "\n")
    if args.write:
        write_section(args.write, lines)


if __name__ == "__main__":
    main()
