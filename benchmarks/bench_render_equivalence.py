"""Are two renderers' images statistically the same? Localisation and tilt errors of the estimator on each.

Run ``python benchmarks/bench_render_equivalence.py --src OLD_SRC NEW_SRC [--frames 36] [--seeds 2]
[--estimate-with SRC]`` (for example ``--src /work/main/src src --estimate-with src``). Each source folder
renders, in its own process (``PYTHONPATH``), the same frames of the default jig as built (seed 0):
cylinders of 40 and 60 mm at tilts of 5, 10 and 20 degrees, azimuths in 60-degree steps, each frame with its
own seed, repeated with ``--seeds`` seed offsets; then the pairs are estimated (``method="refractive"``),
by each source's own estimator, or all by the one of ``--estimate-with`` (so that only the renderers
differ: the estimator changed too since older trees).

Printed per source: the markers' localisation RMSE and median (px; the detected markers within 2 px of a
visible marker's truth, as ``bench_estimate.py``), the tilt error RMSE (deg; the angle between the
estimated and the true normal) and the mean and standard deviation of the grey levels; then the paired
differences frame by frame, and, for scale, the standard error of each figure over the frames (the noise
a change must stay within).
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import json  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

DIAMETERS_MM = (40.0, 60.0)
ALPHAS_DEG = (5.0, 10.0, 20.0)
THETA_STEP_DEG = 60.0
MATCH_RADIUS_PX = 2.0


def _frames(n: int, seeds: int) -> list[tuple[float, float, float, int]]:
    grid = [
        (d, a, t, 0) for d in DIAMETERS_MM for a in ALPHAS_DEG for t in np.arange(0.0, 360.0, THETA_STEP_DEG)
    ][:n]
    return [(d, a, t, 1000 * s + k) for s in range(seeds) for k, (d, a, t, _) in enumerate(grid)]


def _render(frames: list[tuple[float, float, float, int]], path: str) -> None:
    """Render the frames with the softjig importable here; save the images and their truth to ``path``."""
    from softjig.config import CylinderPart, default_jig
    from softjig.sim.asbuilt import draw_as_built
    from softjig.sim.parts import PartPose
    from softjig.sim.render import render_pair

    jig = default_jig()
    as_built = draw_as_built(jig, rng=0)
    arrays = {}
    for k, (d, a, t, seed) in enumerate(frames):
        pose = PartPose(alpha_rad=np.radians(a), theta_rad=np.radians(t))
        pair = render_pair(as_built, CylinderPart(diameter_mm=d), pose, seed)
        m = pair.markers
        arrays.update(
            {
                f"{k}/left": pair.left,
                f"{k}/right": pair.right,
                f"{k}/left_px": m.left_px[m.visible_left],
                f"{k}/right_px": m.right_px[m.visible_right],
                f"{k}/normal": pose.T_J_part(jig)[:3, 2],
            }
        )
    np.savez(path, **arrays)


def _estimate(frames: list[tuple[float, float, float, int]], path: str) -> list[dict[str, float]]:
    """Estimate the saved frames with the softjig importable here: each frame's figures."""
    import cv2
    from scipy.spatial import cKDTree

    from softjig.config import default_jig
    from softjig.sensing.pipeline import estimate_pair

    cv2.setNumThreads(1)
    jig = default_jig()
    saved = np.load(path)
    rows = []
    for k, (d, _, _, _) in enumerate(frames):
        left, right = saved[f"{k}/left"], saved[f"{k}/right"]
        result = estimate_pair(left, right, jig, part_diameter_mm=d)
        errors = []
        for markers, px in ((result.left, saved[f"{k}/left_px"]), (result.right, saved[f"{k}/right_px"])):
            distance, _ = cKDTree(markers.xy_px).query(px)
            errors.append(distance[distance < MATCH_RADIUS_PX])
        e = np.concatenate(errors)
        est = np.asarray(result.estimate.normal, dtype=float)
        tilt = np.degrees(np.arccos(np.clip(abs(float(est @ saved[f"{k}/normal"])), -1.0, 1.0)))
        rows.append(
            {
                "sum_sq_px": float(np.sum(e**2)),
                "n_markers": len(e),
                "median_px": float(np.median(e)),
                "tilt_error_deg": float(tilt),
                "grey_mean": float(np.mean(left)),
                "grey_std": float(np.std(left.astype(float))),
            }
        )
    return rows


def _child(src: str, n: int, seeds: int, mode: str, path: str) -> list[dict[str, float]]:
    """Run ``mode`` (``render`` or ``estimate``, on ``path``) in a process importing softjig from ``src``."""
    env = dict(os.environ, PYTHONPATH=str(Path(src).resolve()))
    argv = [sys.executable, __file__, f"--child-{mode}", path, "--frames", str(n), "--seeds", str(seeds)]
    done = subprocess.run(argv, env=env, capture_output=True, text=True)
    if done.returncode != 0:
        raise SystemExit(f"{src}: exit {done.returncode}\n{done.stderr}")
    return json.loads(done.stdout) if mode == "estimate" else []


def _results(sources: list[str], estimate_with: str | None, n: int, seeds: int) -> dict[str, list[dict]]:
    """Each source's frames rendered by it and estimated by ``estimate_with`` (by itself if None)."""
    results = {}
    with tempfile.TemporaryDirectory() as tmp:
        for k, src in enumerate(sources):
            path = str(Path(tmp) / f"frames{k}.npz")
            _child(src, n, seeds, "render", path)
            results[src] = _child(estimate_with or src, n, seeds, "estimate", path)
            Path(path).unlink()
    return results


def _figures(rows: list[dict[str, float]]) -> dict[str, float]:
    sq = np.array([r["sum_sq_px"] for r in rows])
    n = np.array([r["n_markers"] for r in rows])
    tilt = np.array([r["tilt_error_deg"] for r in rows])
    per_frame_rmse = np.sqrt(sq / n)
    return {
        "localisation RMSE px": float(np.sqrt(sq.sum() / n.sum())),
        "median px (mean of frames)": float(np.mean([r["median_px"] for r in rows])),
        "tilt error RMSE deg": float(np.sqrt(np.mean(tilt**2))),
        "grey mean": float(np.mean([r["grey_mean"] for r in rows])),
        "grey std": float(np.mean([r["grey_std"] for r in rows])),
        "_se localisation RMSE px": float(np.std(per_frame_rmse, ddof=1) / np.sqrt(len(rows))),
        "_se tilt error RMSE deg": float(np.std(tilt, ddof=1) / np.sqrt(len(rows))),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--src", nargs="+", required=False, default=None, help="source folders (PYTHONPATH)")
    parser.add_argument("--frames", type=int, default=36, help="frames of the grid per seed (default 36)")
    parser.add_argument("--seeds", type=int, default=2, help="seed offsets per frame (default 2)")
    parser.add_argument(
        "--estimate-with",
        default=None,
        help="estimate every source's frames with this source folder's softjig (default: each with its own)",
    )
    parser.add_argument("--child-render", default=None, help=argparse.SUPPRESS)
    parser.add_argument("--child-estimate", default=None, help=argparse.SUPPRESS)
    args = parser.parse_args()
    grid_size = len(_frames(sys.maxsize, 1))
    if not 1 <= args.frames <= grid_size:
        parser.error(f"--frames must be between 1 and {grid_size} (the grid), got {args.frames}")
    if args.seeds < 1 or args.frames * args.seeds < 2:
        parser.error(
            f"--seeds must be at least 1 and --frames x --seeds at least 2 (the figures' standard error over "
            f"the frames), got --frames {args.frames} --seeds {args.seeds}"
        )
    frames = _frames(args.frames, args.seeds)
    if args.child_render:
        _render(frames, args.child_render)
        return
    if args.child_estimate:
        json.dump(_estimate(frames, args.child_estimate), sys.stdout)
        return
    sources = args.src or ["src"]
    results = _results(sources, args.estimate_with, args.frames, args.seeds)
    figures = {src: _figures(rows) for src, rows in results.items()}
    by = f"estimated by {args.estimate_with}" if args.estimate_with else "each estimated by its own source"
    print(f"{len(frames)} default-jig frames (D 40/60 mm, tilts 5/10/20 deg, refractive estimate; {by})")
    names = [k for k in next(iter(figures.values())) if not k.startswith("_")]
    print(f"  {'':28s}" + "".join(f"{Path(s).resolve().parent.name:>14s}" for s in sources))
    for name in names:
        print(f"  {name:28s}" + "".join(f"{figures[s][name]:14.4f}" for s in sources))
    if len(sources) >= 2:
        old, new = results[sources[0]], results[sources[-1]]
        d_tilt = np.array([b["tilt_error_deg"] - a["tilt_error_deg"] for a, b in zip(old, new, strict=True)])
        d_rmse = np.array(
            [
                np.sqrt(b["sum_sq_px"] / b["n_markers"]) - np.sqrt(a["sum_sq_px"] / a["n_markers"])
                for a, b in zip(old, new, strict=True)
            ]
        )
        f0, f1 = figures[sources[0]], figures[sources[-1]]
        print("paired, frame by frame (new - old):")
        print(f"  localisation RMSE: mean {d_rmse.mean():+.5f} px, max |.| {np.abs(d_rmse).max():.5f} px")
        print(f"  tilt error:        mean {d_tilt.mean():+.5f} deg, max |.| {np.abs(d_tilt).max():.5f} deg")
        print(
            "noise (standard error over the frames): localisation RMSE "
            f"{f0['_se localisation RMSE px']:.4f} px, tilt error {f0['_se tilt error RMSE deg']:.4f} deg; "
            f"differences of the totals: {f1['localisation RMSE px'] - f0['localisation RMSE px']:+.5f} px, "
            f"{f1['tilt error RMSE deg'] - f0['tilt error RMSE deg']:+.5f} deg"
        )


if __name__ == "__main__":
    main()
