"""What each compiled kernel of the image-side stages gains a pair, against its NumPy or OpenCV counterpart.

Run: ``python benchmarks/bench_kernels.py [--repeats 200]``. One default stereo pair (as-built jig of seed 0,
50 mm cylinder, 10 deg), the inputs each kernel sees in ``estimate_pair``; one thread. Each kernel and its
counterpart take turns (``--repeats`` rounds of each); the script prints the medians per call, the calls a
pair makes and the gain a pair. Issue 16's rule: a kernel stays only where it gains at least 0.2 ms a pair.

Counterparts: the coarse peaks' NumPy path (``detect._local_maxima`` + ``detect._refine_quadratic``, cv2's
dilation and a k-d tree for plateaus); the sub-pixel fit's NumPy gather and one BLAS product of the windows
(a lower bound: before any Newton step); ArUco's detector in windows around the expected fiducials (what the
fast path replaces); SciPy's Levenberg-Marquardt for the head's pose; the vectorised point-in-quad test
(``tests/oracles/jigframe.py``); and, for the border test that is NumPy now, a compiled loop. The estimator's
kernels (contact, self-check) run on the inputs of their first call in an estimate of the pair, against the
NumPy/SciPy code they replace (k-d trees, Delaunay, a sparse graph's components, SVD fits).
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import math  # noqa: E402
import statistics  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from collections.abc import Callable  # noqa: E402
from pathlib import Path  # noqa: E402

import cv2  # noqa: E402
import numba  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from scipy.sparse import coo_matrix  # noqa: E402
from scipy.sparse.csgraph import connected_components  # noqa: E402
from scipy.spatial import Delaunay, cKDTree  # noqa: E402

from oracles.jigframe import inside_fiducials as numpy_inside_fiducials  # noqa: E402
from softjig.config import CylinderPart, default_jig  # noqa: E402
from softjig.sensing import _contact_kernels, detect, jigframe, selfcheck, subpixel  # noqa: E402
from softjig.sensing._detect_kernels import coarse_peaks  # noqa: E402
from softjig.sensing._fiducial_kernels import locate  # noqa: F401, E402  (loaded before timing)
from softjig.sensing.estimator import Estimator  # noqa: E402
from softjig.sensing.fiducials import (  # noqa: E402
    capture_table,
    cell_patterns,
    detect_fiducials,
    locate_quads_near,
)
from softjig.sensing.pipeline import sensing_setup  # noqa: E402
from softjig.sim.asbuilt import draw_as_built  # noqa: E402
from softjig.sim.parts import PartPose  # noqa: E402
from softjig.sim.render import render_pair  # noqa: E402

RULE_MS = 0.2
#: The estimator's kernels are counted over an estimate with the part's size known and one size-free.
SIZES = (50.0, None)


@numba.njit(cache=True, nogil=True)
def _compiled_inside_border(xy, w, h, border):
    keep = np.empty(xy.shape[0], np.bool_)
    for i in range(xy.shape[0]):
        u, v = math.floor(xy[i, 0] + 0.5), math.floor(xy[i, 1] + 0.5)
        keep[i] = border <= u < w - border and border <= v < h - border
    return keep


def _coarse_response(gray: np.ndarray, sigma: float) -> tuple[np.ndarray, int]:
    """The pyramid's coarse response as ``detect._pyramid_candidates`` computes it, and the NMS half-width."""
    factor = detect.pyramid_factor(sigma)
    small = gray
    for _ in range(factor.bit_length() - 1):
        h2, w2 = small.shape[0] // 2, small.shape[1] // 2
        small = cv2.resize(small[: 2 * h2, : 2 * w2], (w2, h2), interpolation=cv2.INTER_AREA)
    s_coarse = detect._coarse_sigma(sigma, factor)
    gain = (sigma / factor) ** 2 * (1.0 + 0.125 / s_coarse**2) / (1.0 + 0.125 / sigma**2) / 255.0
    response = cv2.Laplacian(detect._coarse_blur(small, s_coarse), cv2.CV_32F, ksize=1, scale=-gain)
    return response, max(1, int(2 * sigma) // factor)


def _numpy_peaks(response: np.ndarray, threshold: float, half_width: int) -> None:
    rows, cols = detect._local_maxima(response, threshold=threshold, half_width=half_width, border=1)
    detect._refine_quadratic(response, rows, cols)


def _numpy_product(
    gray: np.ndarray, start: np.ndarray, model: subpixel.MarkerModel, tables: np.ndarray
) -> None:
    half = model.half_width_px
    centre = np.floor(start + 0.5).astype(np.intp)
    r = np.arange(-half, half + 1)
    rows = np.clip(centre[:, 1, None, None] + r[None, :, None], 0, gray.shape[0] - 1)
    cols = np.clip(centre[:, 0, None, None] + r[None, None, :], 0, gray.shape[1] - 1)
    windows = gray[rows, cols].reshape(len(start), -1).astype(np.float32)
    windows @ tables


def _median_us(fn: Callable[[], object], samples: list[float]) -> None:
    t0 = time.perf_counter()
    fn()
    samples.append((time.perf_counter() - t0) * 1e6)


def _cases(pair, jig) -> list[tuple[str, int, Callable[[], object], Callable[[], object]]]:
    """``(kernel, calls a pair, kernel call, counterpart call)`` on the left image's inputs."""
    setup = sensing_setup(jig)
    gray = pair.left
    response, half_width = _coarse_response(gray, setup.sigma_px)
    thr = np.float32(setup.threshold or detect.DEFAULT_THRESHOLD)
    frame = jigframe.jig_frame_from_config(jig)
    quads = frame.fiducial_quads_left_px
    quads_bytes = np.ascontiguousarray(quads, dtype=float).tobytes()
    start = detect.detect_markers(gray, sigma_px=setup.sigma_px, model=setup.marker).xy_px
    start = np.ascontiguousarray(start + np.random.default_rng(0).uniform(-0.4, 0.4, start.shape))
    found = [
        detect_fiducials(pair.left, jig.fiducials, expected_quads_px=frame.fiducial_quads_left_px),
        detect_fiducials(pair.right, jig.fiducials, expected_quads_px=frame.fiducial_quads_right_px),
    ]
    constants = jigframe.frame_constants(jig)  # what an estimator builds once
    corners = constants.corners_J_by_id
    tables, fit = subpixel.kernel_tables(setup.marker), subpixel.fit_tables(setup.marker)
    table = capture_table(quads_bytes, len(quads), gray.shape)
    white = cell_patterns(jig.fiducials.dictionary, tuple(jig.fiducials.ids))
    obj = [np.concatenate([corners[i] for i in f]) for f in found]
    img = [np.concatenate([f[i] for i in f]) for f in found]
    h, w = gray.shape
    return [
        (
            "detect coarse_peaks",
            2,
            lambda: coarse_peaks(response, thr, half_width, detect._FIT_PINV, detect._MAX_REFINE_OFFSET_PX),
            lambda: _numpy_peaks(response, float(thr), half_width),
        ),
        (
            "subpixel refine_all",
            2,
            lambda: subpixel.refine_centres(gray, start, setup.marker, tables=tables),
            lambda: _numpy_product(gray, start, setup.marker, fit),
        ),
        (
            "fiducials locate",
            2,
            lambda: locate_quads_near(gray, jig.fiducials, quads_bytes, table=table, white=white),
            lambda: detect_fiducials(gray, jig.fiducials, expected_quads_px=quads),
        ),
        (
            "jigframe gauss_newton",
            1,
            lambda: jigframe._fit_pose_gauss_newton(obj, img, jig, constants),
            lambda: jigframe._fit_pose_lm(obj, img, jig, constants),
        ),
        (
            "jigframe inside_quads",
            2,
            lambda: jigframe.inside_fiducials(start, quads),
            lambda: numpy_inside_fiducials(start, quads),
        ),
        (
            "detect inside_border (NumPy now)",
            6,
            lambda: _compiled_inside_border(start, w, h, 8),
            lambda: detect._inside_border(start, w, h, 8),
        ),
    ]


# --- The estimator's kernels (contact, self-check, uncertainty) --------------------------------------------
# Their inputs and calls a pair are recorded from one estimate of the pair (part size known, as
# bench_estimate.py), each counterpart is the NumPy/SciPy code the kernel replaced.


def _np_indentation(points, reference_z, radius):
    raw = reference_z - points[:, 2]
    distance, index = cKDTree(points[:, :2]).query(points[:, :2], k=9, distance_upper_bound=radius)
    near = np.isfinite(distance[:, 1:])
    k = near.sum(axis=1)
    values = np.where(near, raw[np.minimum(index[:, 1:], len(raw) - 1)], 0.0)
    enough = k >= 3
    residual = (raw[enough] - values[enough].sum(axis=1) / k[enough]) / np.sqrt(1 + 1 / k[enough])
    noise = max(1.4826 * np.median(np.abs(residual)), 1e-6)
    zero = np.median(raw)
    for _ in range(5):
        at_rest = raw[np.abs(raw - zero) < 2.5 * noise]
        new_zero = np.median(at_rest) if len(at_rest) >= 3 else zero
        if abs(new_zero - zero) < 1e-3 * noise:
            break
        zero = new_zero
    return raw - zero, zero, noise


def _np_count_within(query, points, radius, inclusive):
    return cKDTree(points).query_ball_point(query, radius, return_length=True)


def _np_violations(xy, contact, above, below, radius):
    index = np.flatnonzero(contact)
    members = xy[index]
    count = 0
    if above.any():
        counts = cKDTree(members).query_ball_point(members, radius, return_length=True) - 1
        core = index[counts >= 4]
        core = index if len(core) < 3 else core
        count += int((Delaunay(xy[core]).find_simplex(xy[above]) >= 0).sum())
    if below.any():
        count += int((Delaunay(members).find_simplex(xy[below]) >= 0).sum())
    return count


def _np_flood(xy, start, allowed, radius):
    nodes = np.flatnonzero(start | allowed)
    pairs = cKDTree(xy[nodes]).query_pairs(radius, output_type="ndarray")
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(len(nodes), len(nodes)))
    _, label = connected_components(graph, directed=False)
    reached = np.zeros(len(xy), dtype=bool)
    reached[nodes[np.isin(label, label[start[nodes]])]] = True
    return reached


def _np_face_depth(points, depth, normal, offset):
    height = -(offset + points[:, :2] @ normal[:2]) / normal[2]
    return np.nan_to_num(depth, nan=-np.inf) - (height - points[:, 2])


def _np_footprint(hull, half_pitch):
    nxt = np.roll(hull, -1, axis=0)
    cross = hull[:, 0] * nxt[:, 1] - nxt[:, 0] * hull[:, 1]
    area = cross.sum() / 2.0
    centroid = np.array([((hull[:, 0] + nxt[:, 0]) * cross).sum(), ((hull[:, 1] + nxt[:, 1]) * cross).sum()])
    centroid /= 6.0 * area
    perimeter = np.linalg.norm(nxt - hull, axis=1).sum()
    outward = hull - centroid
    norms = np.linalg.norm(outward, axis=1, keepdims=True)
    return abs(area), centroid, perimeter, hull + half_pitch * outward / norms


def _np_half(points, sigma):
    centroid = points.mean(axis=0)
    _, _, vt = np.linalg.svd(points - centroid, full_matrices=False)
    n = vt[2] * np.sign(vt[2, 2])
    xy = points[:, :2] - centroid[:2]
    cov = sigma**2 * np.linalg.inv(xy.T @ xy)
    a, b = -n[0] / n[2], -n[1] / n[2]
    jac = np.array([[-(1.0 + b * b), a * b], [a * b, -(1.0 + a * a)], [-a, -b]]) / (1 + a * a + b * b) ** 1.5
    return n, np.sqrt(np.trace(jac @ cov @ jac.T))


def _np_split_fits(points, sigma, min_points):
    xy = points[:, :2] - points[:, :2].mean(axis=0)
    _, axes = np.linalg.eigh(xy.T @ xy)
    out = []
    for k in range(2):
        along = xy @ axes[:, k]
        side = along > np.median(along)
        out.append((_np_half(points[side], sigma), _np_half(points[~side], sigma)))
    return out


_ESTIMATOR_KERNELS = {  # (module, attribute): NumPy counterpart
    (_contact_kernels, "indentation"): _np_indentation,
    (_contact_kernels, "count_within"): _np_count_within,
    (_contact_kernels, "violations"): _np_violations,
    (_contact_kernels, "flood"): _np_flood,
    (_contact_kernels, "face_depth"): _np_face_depth,
    (_contact_kernels, "footprint"): _np_footprint,
    (selfcheck, "split_fits"): _np_split_fits,
}


def _estimator_cases(pair, jig) -> list[tuple[str, int, Callable[[], object], Callable[[], object]]]:
    """The estimator's kernels, each on the inputs of its first call; calls a pair: the mean of the
    estimates with the part's size known and size-free (:data:`SIZES`)."""
    calls: dict[str, list[tuple]] = {}
    originals = {key: getattr(*key) for key in _ESTIMATOR_KERNELS}

    def recorder(name, kernel):
        def record(*args):
            calls.setdefault(name, []).append(
                tuple(a.copy() if isinstance(a, np.ndarray) else a for a in args)
            )
            return kernel(*args)

        return record

    estimator = Estimator(jig)
    estimator.estimate(pair.left, pair.right, part_diameter_mm=50.0)  # warm-up: compiled code, caches
    try:
        for (module, attribute), kernel in originals.items():
            setattr(module, attribute, recorder(f"{module.__name__.rsplit('.', 1)[1]} {attribute}", kernel))
        for size in SIZES:
            estimator.estimate(pair.left, pair.right, part_diameter_mm=size)
    finally:
        for (module, attribute), kernel in originals.items():
            setattr(module, attribute, kernel)
    cases = []
    for (module, attribute), counterpart in _ESTIMATOR_KERNELS.items():
        name = f"{module.__name__.rsplit('.', 1)[1]} {attribute}"
        if name not in calls:
            print(f"{name}: not called on this pair")
            continue
        args, kernel = calls[name][0], originals[(module, attribute)]
        cases.append(
            (name, len(calls[name]), lambda k=kernel, a=args: k(*a), lambda c=counterpart, a=args: c(*a))
        )
    return cases


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=200)
    args = parser.parse_args()
    cv2.setNumThreads(1)
    jig = default_jig()
    pair = render_pair(
        draw_as_built(jig, rng=0), CylinderPart(50.0), PartPose(np.radians(10), 0.0, 3.0), rng=0
    )
    cases = _cases(pair, jig) + _estimator_cases(pair, jig)
    for _, _, kernel, counterpart in cases:  # warm-up: compiled code, caches
        kernel(), counterpart()
    samples = {name: ([], []) for name, *_ in cases}
    for _ in range(args.repeats):
        for name, _, kernel, counterpart in cases:
            _median_us(kernel, samples[name][0])
            _median_us(counterpart, samples[name][1])
    print(f"{args.repeats} rounds, one default pair, one thread (medians per call)")
    print(f"{'kernel':34s} {'kernel us':>10s} {'other us':>10s} {'calls':>6s} {'gain ms/pair':>13s}")
    for name, calls, *_ in cases:
        k, o = (statistics.median(s) for s in samples[name])
        gain = calls * (o - k) / 1e3
        verdict = "keep" if gain >= RULE_MS else "NumPy"
        print(f"{name:34s} {k:10.1f} {o:10.1f} {calls:6g} {gain:13.3f}  {verdict}")


if __name__ == "__main__":
    main()
