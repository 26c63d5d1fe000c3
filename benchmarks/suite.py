"""softjig's benchmark suite: estimate stages, marker detectors against peers, renderer; one command.

Run: ``python benchmarks/suite.py [--quick] [--write benchmarks/RESULTS.md]``.

Everything runs in this process on one core (``cv2.setNumThreads(1)``, BLAS limited to one thread) on
pairs rendered here from the as-built default jig with default physics (a 50 mm cylinder tilted by
10 degrees, pushed in 3 mm). Tables:

1. ``estimate_pair``: time per stage and total (median, IQR) for ``method="refractive"`` and ``"paper"``.
2. Detectors on the same images in the same run (the detectors take turns on each image): ours
   (:func:`softjig.sensing.detect.detect_markers` with the pipeline's own scale and threshold; its default
   options, and the older options as extra rows when the function has gained new ones), and the peers of
   ``benchmarks/peers.py``. Time per image (median, IQR), localisation RMSE and median error against the
   renderer's ground truth (``pair.markers.left_px[visible_left]``, likewise right; a detection within
   2 px of a true centre matches it, one to one, nearest first), recall, false positives per image
   (detections on the fiducials and their quiet zone are ignored for every detector), and the ratio of each
   one's time and RMSE to ours. The Cramer-Rao bound is shown beside when
   ``softjig.evaluation.cramer_rao`` is importable.
3. The simulator: render time per stereo pair.
4. The machine and versions.

Peers' settings are tuned fairly on a separate tuning pair (another seed and azimuth, never scored):
a grid search maximising F1 = 2 TP / (2 TP + FP + FN), then the smaller RMSE (:func:`tune_peers`).
``--quick`` renders 2 pairs and repeats less (under a minute); the full run renders 8 (a few minutes).
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import inspect  # noqa: E402
import platform  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from collections.abc import Callable, Sequence  # noqa: E402
from dataclasses import dataclass, field  # noqa: E402
from functools import partial  # noqa: E402
from pathlib import Path  # noqa: E402

import cv2  # noqa: E402
import numpy as np  # noqa: E402
from scipy.spatial import cKDTree  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
import peers  # noqa: E402
from softjig.config import CylinderPart, JigConfig, default_jig  # noqa: E402
from softjig.sensing.detect import DEFAULT_THRESHOLD, detect_markers  # noqa: E402
from softjig.sensing.estimator import Estimator  # noqa: E402
from softjig.sensing.pipeline import sensing_setup  # noqa: E402
from softjig.sensing.subpixel import MarkerModel, kernel_tables  # noqa: E402
from softjig.sim.asbuilt import draw_as_built  # noqa: E402
from softjig.sim.parts import PartPose  # noqa: E402
from softjig.sim.render import RenderedPair, render_pair  # noqa: E402

MATCH_RADIUS_PX = 2.0
FIDUCIAL_MARGIN_PX = 12.0  # detections this close to a fiducial's quad are ignored (its quiet zone)
METHODS = ("refractive", "paper")

Detector = Callable[[np.ndarray], np.ndarray]


# ------------------------------------------------------------------------------------------- data


@dataclass(frozen=True)
class Image:
    """One camera image and its ground truth: visible markers' centres and fiducial boxes to ignore.

    ``truth_px``: (N, 2) true ``(u, v)`` px; ``ignore_boxes``: (M, 4) ``u0, v0, u1, v1`` px.
    """

    name: str
    pixels: np.ndarray
    truth_px: np.ndarray
    ignore_boxes: np.ndarray


def render_pairs(jig: JigConfig, n: int, *, seed0: int = 0, theta0_deg: float = 0.0) -> tuple[list, list]:
    """``n`` default pairs (as-built jig of seed 0) and the wall time of each render (s), after one
    untimed warm-up render (the renderer's caches)."""
    as_built = draw_as_built(jig, rng=0)
    render_pair(as_built, CylinderPart(50.0), PartPose(np.radians(10.0), 0.0, 3.0), rng=seed0 + 999)
    pairs, seconds = [], []
    for k in range(n):
        pose = PartPose(np.radians(10.0), np.radians(theta0_deg + 360.0 * k / max(n, 1)), 3.0)
        t0 = time.perf_counter()
        pairs.append(render_pair(as_built, CylinderPart(50.0), pose, rng=seed0 + k))
        seconds.append(time.perf_counter() - t0)
    return pairs, seconds


def _boxes(quads: np.ndarray) -> np.ndarray:
    quads = np.asarray(quads, dtype=float).reshape(-1, 4, 2)
    return np.column_stack([quads.min(axis=1) - FIDUCIAL_MARGIN_PX, quads.max(axis=1) + FIDUCIAL_MARGIN_PX])


def images_of(pairs: Sequence[RenderedPair]) -> list[Image]:
    """Both images of every pair with their visible markers' true centres."""
    out = []
    for k, pair in enumerate(pairs):
        m = pair.markers
        out.append(
            Image(f"{k}L", pair.left, m.left_px[m.visible_left], _boxes(pair.fiducial_corners_left_px))
        )
        out.append(
            Image(f"{k}R", pair.right, m.right_px[m.visible_right], _boxes(pair.fiducial_corners_right_px))
        )
    return out


# ---------------------------------------------------------------------------------------- scoring


@dataclass(frozen=True)
class Score:
    """Detections scored against the truth: ``errors_px`` of the matched ones, counts of the rest."""

    errors_px: np.ndarray
    n_truth: int
    n_false: int

    def __add__(self, other: Score) -> Score:
        return Score(
            np.concatenate([self.errors_px, other.errors_px]),
            self.n_truth + other.n_truth,
            self.n_false + other.n_false,
        )

    @property
    def recall(self) -> float:
        return len(self.errors_px) / max(self.n_truth, 1)

    @property
    def rmse_px(self) -> float:
        return float(np.sqrt(np.mean(self.errors_px**2))) if len(self.errors_px) else float("nan")

    @property
    def f1(self) -> float:
        tp = len(self.errors_px)
        return 2 * tp / max(2 * tp + self.n_false + self.n_truth - tp, 1)


def score(detected_px: np.ndarray, image: Image) -> Score:
    """Match detections to true centres one to one within :data:`MATCH_RADIUS_PX`, nearest pairs first;
    detections inside an ignore box are dropped first."""
    det = np.asarray(detected_px, dtype=float).reshape(-1, 2)
    for u0, v0, u1, v1 in image.ignore_boxes:
        det = det[~((det[:, 0] >= u0) & (det[:, 0] <= u1) & (det[:, 1] >= v0) & (det[:, 1] <= v1))]
    truth = image.truth_px
    if len(det) == 0 or len(truth) == 0:
        return Score(np.empty(0), len(truth), len(det))
    pairs = cKDTree(truth).sparse_distance_matrix(cKDTree(det), MATCH_RADIUS_PX, output_type="ndarray")
    used_t, used_d, errors = set(), set(), []
    for i, j, d in sorted(pairs.tolist(), key=lambda p: p[2]):
        if i not in used_t and j not in used_d:
            used_t.add(i), used_d.add(j), errors.append(d)
    return Score(np.asarray(errors, dtype=float), len(truth), len(det) - len(errors))


# -------------------------------------------------------------------------------------- detectors


def our_detectors(jig: JigConfig) -> dict[str, tuple[Detector, str]]:
    """Ours as the pipeline calls it, plus the former options when the signature offers newer ones.

    The pipeline's settings come from :func:`sensing_setup` (scale, threshold and, where they exist, the
    ``candidates``, ``refine`` and ``model`` fields), each passed only if ``detect_markers`` takes it
    (``inspect.signature``). Returns ``{name: (detector, note)}``; the note says what was found.
    """
    setup = sensing_setup(jig)
    params = inspect.signature(detect_markers).parameters
    base: dict = {"sigma_px": setup.sigma_px, "threshold": setup.threshold or DEFAULT_THRESHOLD}
    for name in ("candidates", "refine", "model"):
        if name in params and getattr(setup, name, None) is not None:
            base[name] = getattr(setup, name)
    if "tables" in params and base.get("refine", params["refine"].default) == "model":
        # the sub-pixel tables read once, as the estimator's detector does (not from disk per call)
        base["tables"] = kernel_tables(base.get("model") or MarkerModel.for_sigma(setup.sigma_px))
    notes = []
    for name in ("candidates", "refine"):
        if name not in params:
            notes.append(f"no `{name}` keyword yet")
        else:
            notes.append(f"{name}={base.get(name, params[name].default)!r}")
    if "model" in base:
        notes.append("the pipeline's marker model")
    out = {
        "ours": (lambda im: detect_markers(im, **base).xy_px, "as the pipeline calls it: " + ", ".join(notes))
    }
    if "candidates" in params and base.get("candidates", params["candidates"].default) != "full":
        full = {**base, "candidates": "full"}
        out["ours candidates=full"] = (
            lambda im: detect_markers(im, **full).xy_px,
            "full-resolution candidates",
        )
    if "refine" in params and base.get("refine", params["refine"].default) != "quadratic":
        quadratic = {**base, "refine": "quadratic"}
        quadratic.pop("model", None)
        quadratic.pop("tables", None)
        out["ours refine=quadratic"] = (
            lambda im: detect_markers(im, **quadratic).xy_px,
            "the former refinement (3x3 quadratic fit of the LoG response)",
        )
    return out


@dataclass(frozen=True)
class PeerSettings:
    """Tuned settings of the peers (see :func:`tune_peers`)."""

    sigma_px: float
    log_threshold: float
    blob_log_threshold: float
    blob_params: peers.BlobParams = field(default_factory=peers.BlobParams)


BLOB_LOG_THRESHOLDS = (0.01, 0.02, 0.03, 0.05, 0.08)
BLOB_MIN_THRESHOLDS = (30.0, 50.0, 70.0)
BLOB_CIRCULARITIES = (0.5, 0.7)
BLOB_STEPS = (5.0, 10.0)


def blob_log_sigmas(sigma_px: float) -> dict:
    """blob_log's scale range: the markers' LoG scale +-25 % (the marker size varies ~15-19 px), 3 scales."""
    return {"min_sigma": 0.75 * sigma_px, "max_sigma": 1.25 * sigma_px, "num_sigma": 3}


def peer_detectors(s: PeerSettings) -> dict[str, tuple[Detector, str]]:
    """The peers with their settings, ``{name: (detector, note)}``."""
    b = s.blob_params
    return {
        "plain LoG + 3x3 quadratic": (
            partial(peers.plain_log, sigma_px=s.sigma_px, threshold=s.log_threshold),
            f"sigma {s.sigma_px:.2f} px, threshold {s.log_threshold:g} (ours)",
        ),
        "skimage blob_log": (
            partial(peers.skimage_blob_log, **blob_log_sigmas(s.sigma_px), threshold=s.blob_log_threshold),
            f"sigma {0.75 * s.sigma_px:.2f}-{1.25 * s.sigma_px:.2f} px, 3 scales, "
            f"threshold {s.blob_log_threshold:g}",
        ),
        "cv2 SimpleBlobDetector": (
            partial(peers.cv2_blob, params=b),
            f"thresholds {b.min_threshold:g}:{b.threshold_step:g}:{b.max_threshold:g}, "
            f"area {b.min_area_px2:g}-{b.max_area_px2:g} px^2, circularity >= {b.min_circularity:g}",
        ),
    }


def _best(candidates: dict, image: Image, run: Callable) -> object:
    scores = {key: score(run(key), image) for key in candidates}
    return max(scores, key=lambda k: (round(scores[k].f1, 4), -scores[k].rmse_px))


def tune_peers(
    jig: JigConfig, tuning: Image, blob_log_thresholds: Sequence[float] = BLOB_LOG_THRESHOLDS
) -> PeerSettings:
    """Tune blob_log's threshold and SimpleBlobDetector's thresholds, step and circularity on one image.

    The plain LoG uses our scale and threshold (it is the same response). Grid search: the setting with
    the largest F1, then the smallest RMSE.
    """
    setup = sensing_setup(jig)
    sigma = setup.sigma_px
    threshold = setup.threshold or DEFAULT_THRESHOLD
    blob_log_t = _best(
        dict.fromkeys(blob_log_thresholds),
        tuning,
        lambda t: peers.skimage_blob_log(tuning.pixels, **blob_log_sigmas(sigma), threshold=t),
    )
    grid = {
        (lo, c, st): peers.BlobParams(min_threshold=lo, min_circularity=c, threshold_step=st)
        for lo in BLOB_MIN_THRESHOLDS
        for c in BLOB_CIRCULARITIES
        for st in BLOB_STEPS
    }
    key = _best(grid, tuning, lambda k: peers.cv2_blob(tuning.pixels, params=grid[k]))
    return PeerSettings(sigma, threshold, float(blob_log_t), grid[key])


# ---------------------------------------------------------------------------------------- running


@dataclass(frozen=True)
class DetectorResult:
    """One detector over all images: seconds per call and the summed score."""

    name: str
    note: str
    seconds: np.ndarray
    score: Score


def run_detectors(
    detectors: dict[str, tuple[Detector, str]], images: Sequence[Image], repeats: int
) -> list[DetectorResult]:
    """Time and score every detector on every image; the detectors take turns on each image."""
    seconds: dict[str, list[float]] = {name: [] for name in detectors}
    scores: dict[str, Score] = {name: Score(np.empty(0), 0, 0) for name in detectors}
    for detect, _note in detectors.values():  # warm-up: caches, compiled code
        detect(images[0].pixels)
    for image in images:
        found: dict[str, np.ndarray] = {}
        for _ in range(repeats):
            for name, (detect, _note) in detectors.items():
                t0 = time.perf_counter()
                found[name] = detect(image.pixels)
                seconds[name].append(time.perf_counter() - t0)
        for name in detectors:
            scores[name] = scores[name] + score(found[name], image)
    return [DetectorResult(n, detectors[n][1], np.asarray(seconds[n]), scores[n]) for n in detectors]


def time_estimates(
    pairs: Sequence[RenderedPair], jig: JigConfig, method: str, repeats: int
) -> dict[str, np.ndarray]:
    """Seconds per stage (``timings`` of an :class:`~softjig.sensing.estimator.Estimator` built once, as
    every caller estimating frames builds it) and in total over ``repeats`` runs cycling through the pairs
    (one warm-up run first)."""
    estimator = Estimator(jig, method=method)
    estimator.estimate(pairs[0].left, pairs[0].right, part_diameter_mm=50.0)
    records: dict[str, list[float]] = {}
    for k in range(repeats):
        pair = pairs[k % len(pairs)]
        timings: dict[str, float] = {}
        t0 = time.perf_counter()
        estimator.estimate(pair.left, pair.right, part_diameter_mm=50.0, timings=timings)
        total = time.perf_counter() - t0
        for stage, value in timings.items():
            records.setdefault(stage, []).append(value)
        records.setdefault("total", []).append(total)
    return {stage: np.asarray(values) for stage, values in records.items()}


def cramer_rao_bound_px(jig: JigConfig) -> tuple[float | None, str]:
    """The Cramer-Rao bound of a nominal marker's centre (2-D RMS, px) and a note saying where it is from.

    Uses ``softjig.evaluation.cramer_rao.centre_crb_px`` on the pipeline's marker model
    (``sensing_setup(jig).marker``: the marker at the membrane's apex, nominal physics) when both exist.
    """
    try:
        from softjig.evaluation.cramer_rao import centre_crb_px
    except ImportError:
        return None, "Cramer-Rao bound: softjig.evaluation.cramer_rao is not importable yet"
    model = getattr(sensing_setup(jig), "marker", None)
    if model is None:
        return None, "Cramer-Rao bound: sensing_setup(jig) has no marker model yet"
    bound = float(centre_crb_px(model))
    return bound, (
        f"CRB = {bound:.3f} px: centre_crb_px of the pipeline's marker model (a nominal marker at the apex, "
        "centred on a pixel, correlated speckle); RMSE/CRB compares every marker's error with it"
    )


# ---------------------------------------------------------------------------------------- tables


@dataclass(frozen=True)
class Table:
    title: str
    headers: tuple[str, ...]
    rows: list[tuple[str, ...]]
    notes: list[str] = field(default_factory=list)


def _ms(values: np.ndarray) -> tuple[str, str]:
    q1, med, q3 = np.percentile(1e3 * np.asarray(values), [25, 50, 75])
    return f"{med:.2f}", f"{q1:.2f}-{q3:.2f}"


def estimate_table(method: str, records: dict[str, np.ndarray]) -> Table:
    rows = [(stage, *_ms(values)) for stage, values in records.items()]
    n = len(records["total"])
    return Table(
        f"estimate_pair, method={method!r}: time per stage ({n} runs, one default 1280x720 pair, 1 thread)",
        ("stage", "median ms", "IQR ms"),
        rows,
        ["total: the whole call, wall time; the stages are the `timings` it reports"],
    )


def detector_table(results: list[DetectorResult], n_images: int, bound_px: float | None) -> Table:
    ours = results[0]
    ours_ms, ours_rmse = float(np.median(ours.seconds)), ours.score.rmse_px
    headers = ["detector", "median ms", "IQR ms", "RMSE px", "median px", "recall", "FP/image",
               "time/ours", "RMSE/ours"]  # fmt: skip
    if bound_px is not None:
        headers.append("RMSE/CRB")
    rows = []
    for r in results:
        med, iqr = _ms(r.seconds)
        s = r.score
        row = [r.name, med, iqr, f"{s.rmse_px:.3f}",
               f"{np.median(s.errors_px):.3f}" if len(s.errors_px) else "nan",
               f"{s.recall:.3f}", f"{s.n_false / n_images:.1f}",
               f"{float(np.median(r.seconds)) / ours_ms:.2f}", f"{s.rmse_px / ours_rmse:.2f}"]  # fmt: skip
        if bound_px is not None:
            row.append(f"{s.rmse_px / bound_px:.2f}")
        rows.append(tuple(row))
    notes = [f"{r.name}: {r.note}" for r in results]
    notes.append(
        f"{n_images} images ({ours.score.n_truth} visible markers); a match is within "
        f"{MATCH_RADIUS_PX:g} px; time includes each detector's own image conversion; "
        "input: the rendered uint8 image"
    )
    return Table("Marker detectors on the same images (one thread)", tuple(headers), rows, notes)


def machine_table() -> Table:
    cpu = "unknown"
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    try:
        import skimage

        skimage_version = skimage.__version__
    except ImportError:
        skimage_version = "not installed"
    root = Path(__file__).resolve().parents[1]
    try:
        commit = subprocess.run(
            ["git", "rev-parse", "--short", "HEAD"], cwd=root, capture_output=True, text=True, check=True
        ).stdout.strip()
        dirty = subprocess.run(
            ["git", "status", "--porcelain", "--untracked-files=no"], cwd=root, capture_output=True, text=True
        ).stdout.strip()
        commit += " + uncommitted changes" if dirty else ""
    except (OSError, subprocess.CalledProcessError):
        commit = "unknown"
    rows = [
        ("CPU", cpu),
        ("cores", str(os.cpu_count())),
        ("load average (1 min) at the end", f"{os.getloadavg()[0]:.2f}"),
        ("Python", platform.python_version()),
        ("NumPy", np.__version__),
        ("OpenCV", cv2.__version__),
        ("scikit-image", skimage_version),
        ("softjig commit", commit),
    ]
    return Table("Machine and versions", ("", ""), rows)


def format_text(table: Table) -> str:
    widths = [max(len(str(c)) for c in col) for col in zip(table.headers, *table.rows, strict=True)]
    lines = [table.title, "  ".join(h.ljust(w) for h, w in zip(table.headers, widths, strict=True))]
    lines += ["  ".join(str(c).ljust(w) for c, w in zip(row, widths, strict=True)) for row in table.rows]
    lines += [f"  * {note}" for note in table.notes]
    return "\n".join(lines) + "\n"


def format_markdown(table: Table) -> str:
    lines = [f"### {table.title}", "", "| " + " | ".join(table.headers) + " |"]
    lines.append("|" + "|".join("---" for _ in table.headers) + "|")
    lines += ["| " + " | ".join(str(c) for c in row) + " |" for row in table.rows]
    if table.notes:
        lines.append("")
        lines += [f"- {note}" for note in table.notes]
    return "\n".join(lines) + "\n"


# ------------------------------------------------------------------------------------------- main


@dataclass(frozen=True)
class Plan:
    """How much the suite runs."""

    pairs: int
    estimate_repeats: int
    detector_repeats: int
    blob_log_thresholds: tuple[float, ...] = BLOB_LOG_THRESHOLDS  # blob_log is slow: ~1 s per image


QUICK = Plan(pairs=2, estimate_repeats=8, detector_repeats=1, blob_log_thresholds=(0.02, 0.03))
FULL = Plan(pairs=8, estimate_repeats=40, detector_repeats=3)


def run_suite(plan: Plan, jig: JigConfig | None = None, log: Callable[[str], None] = print) -> list[Table]:
    """Render, time and score everything; return the tables."""
    jig = jig or default_jig()
    pairs, render_s = render_pairs(jig, plan.pairs)
    log(f"rendered {plan.pairs} pairs")
    (tuning_pair,), _ = render_pairs(jig, 1, seed0=1000, theta0_deg=18.0)
    settings = tune_peers(jig, images_of([tuning_pair])[0], plan.blob_log_thresholds)
    log("tuned the peers")
    tables = []
    for method in METHODS:
        tables.append(estimate_table(method, time_estimates(pairs, jig, method, plan.estimate_repeats)))
        log(f"timed estimate_pair ({method})")
    detectors = {**our_detectors(jig), **peer_detectors(settings)}
    images = images_of(pairs)
    results = run_detectors(detectors, images, plan.detector_repeats)
    bound, note = cramer_rao_bound_px(jig)
    table = detector_table(results, len(images), bound)
    table.notes.append(note)
    table.notes.append(
        f"peers tuned on a separate pair (seed 1000, azimuth 18 deg): blob_log threshold from "
        f"{plan.blob_log_thresholds}, SimpleBlobDetector min threshold from {BLOB_MIN_THRESHOLDS}, step from "
        f"{BLOB_STEPS}, circularity from {BLOB_CIRCULARITIES}; best F1, then RMSE"
    )
    tables.append(table)
    tables.append(
        Table(
            "Simulator: render_pair, one default stereo pair (as-built jig, 50 mm cylinder, 10 deg)",
            ("renders", "median ms", "IQR ms"),
            [(str(len(render_s)), *_ms(np.asarray(render_s)))],
            ["wall time, after one untimed warm-up render; one thread"],
        )
    )
    tables.append(machine_table())
    return tables


def write_results(tables: list[Table], path: Path, command: str) -> None:
    from softjig.files import write_text_atomic

    stamp = time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())
    head = f"# softjig benchmark results\n\nProduced by `{command}` on {stamp}.\n\n"
    write_text_atomic(path, head + "\n".join(format_markdown(t) for t in tables))


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="fewer pairs and repeats (under a minute)")
    parser.add_argument("--write", type=Path, metavar="RESULTS.md", help="also write the tables as Markdown")
    args = parser.parse_args(argv)
    cv2.setNumThreads(1)
    t0 = time.perf_counter()
    tables = run_suite(
        QUICK if args.quick else FULL, log=lambda m: print(f"[{time.perf_counter() - t0:5.1f} s] {m}")
    )
    print()
    for table in tables:
        print(format_text(table))
    print(f"suite took {time.perf_counter() - t0:.1f} s")
    if args.write:
        command = "python benchmarks/suite.py" + (" --quick" if args.quick else "") + f" --write {args.write}"
        write_results(tables, args.write, command)
        print(f"wrote {args.write}")


if __name__ == "__main__":
    main()
