"""Check that a change to the refractive estimator's speed leaves its results as they were.

Run: ``python benchmarks/bench_agreement_speed.py --against OLD_SRC`` where ``OLD_SRC`` is the ``src``
folder of the code to compare with (``git archive <commit> src | tar -x -C /tmp/old``, then
``--against /tmp/old/src``). It estimates the same varied frames (the benchmark's default pair, tilts
0-20 deg at several azimuths, 30-60 mm cylinders and a box, parts off the jig axis; each with and without
the part's size, with the unloaded reference frame and with the rest shape) under both trees, each in
its own process, and asserts identical quality and warnings, the same failures, and normals, sigmas and
push depths equal within 1e-9. Exit status 1 on any difference.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import pickle  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

TOLERANCE = 1e-9


def _frames():
    """``(name, pair, diameter_mm)`` of the varied frames, and the unloaded reference pair."""
    from softjig.config import BoxPart, CylinderPart, default_jig
    from softjig.sim.asbuilt import draw_as_built
    from softjig.sim.parts import PartPose
    from softjig.sim.render import render_pair

    as_built = draw_as_built(default_jig(), rng=0)
    reference = render_pair(as_built, None, None, rng=100)
    cases = [(50.0, 10.0, 36.0 * k, 3.0, (0.0, 0.0), k) for k in range(5)]  # bench_estimate's pairs
    cases += [
        (30.0, 0.0, 0.0, 3.0, (0.0, 0.0), 11),
        (30.0, 15.0, 200.0, 3.5, (0.0, 0.0), 12),
        (40.0, 5.0, 90.0, 2.5, (0.0, 0.0), 13),
        (40.0, 20.0, 300.0, 4.0, (0.0, 0.0), 14),
        (60.0, 8.0, 45.0, 3.0, (0.0, 0.0), 15),
        (60.0, 18.0, 135.0, 3.0, (0.0, 0.0), 16),
        (40.0, 10.0, 250.0, 3.0, (12.0, -6.0), 17),
        (30.0, 12.0, 20.0, 3.0, (-10.0, 8.0), 18),
    ]
    frames = []
    for diameter, alpha, theta, push, centre, seed in cases:
        pose = PartPose(np.radians(alpha), np.radians(theta), push, center_xy_mm=centre)
        frames.append(
            (
                f"cyl{diameter:g} a{alpha:g} t{theta:g} c{centre}",
                render_pair(as_built, CylinderPart(diameter), pose, rng=seed),
                diameter,
            )
        )
    box_pose = PartPose(np.radians(8), np.radians(60), 3.0)
    box = render_pair(as_built, BoxPart(40.0, 40.0, 20.0), box_pose, rng=19)
    frames.append(("box40 a8 t60", box, 40.0))
    return reference, frames


def dump(frames_file: Path, out: Path) -> None:
    """Estimate every frame of ``frames_file`` under the ``softjig`` on the path; write the results to
    ``out`` (pickle)."""
    from softjig.config import default_jig
    from softjig.errors import SoftjigError
    from softjig.sensing.estimator import Estimator

    jig = default_jig()
    reference_pair, frames = pickle.loads(frames_file.read_bytes())
    rest_shape = Estimator(jig)
    reference = rest_shape.reference_from_pair(reference_pair.left, reference_pair.right)
    estimators = {"reference": rest_shape.with_reference(reference), "rest shape": rest_shape}
    results = {}
    for name, pair, diameter in frames:
        for size in (diameter, None):
            for ref_name in ("reference", "rest shape"):
                key = f"{name} size={size} {ref_name}"
                try:
                    result = estimators[ref_name].estimate(pair.left, pair.right, part_diameter_mm=size)
                    e = result.estimate
                except SoftjigError as exc:
                    results[key] = ("error", type(exc).__name__, str(exc))
                    continue
                results[key] = (
                    "ok",
                    e.quality,
                    tuple(e.warnings),
                    np.asarray(e.normal, dtype=float),
                    np.array([e.tilt_sigma_deg, e.push_depth_mm, e.n_points]),
                )
    out.write_bytes(pickle.dumps(results))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--against", type=Path, help="the src folder of the code to compare with")
    parser.add_argument("--dump", type=Path, nargs=2, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.dump is not None:
        dump(*args.dump)
        return
    if args.against is None:
        parser.error("--against OLD_SRC is required")
    here = Path(__file__).resolve().parents[1] / "src"
    frames = Path(f"/tmp/bench_agreement_speed_{os.getpid()}_frames.pkl")
    frames.write_bytes(pickle.dumps(_frames()))  # rendered once, by this tree's simulator
    got = {}
    for label, src in (("old", args.against.resolve()), ("new", here)):
        path = Path(f"/tmp/bench_agreement_speed_{os.getpid()}_{label}.pkl")
        env = dict(os.environ, PYTHONPATH=str(src))
        subprocess.run([sys.executable, __file__, "--dump", str(frames), str(path)], env=env, check=True)
        got[label] = pickle.loads(path.read_bytes())
        path.unlink()
    frames.unlink()
    old, new = got["old"], got["new"]
    bad = []
    for key in old.keys() | new.keys():
        a, b = old.get(key), new.get(key)
        if a is None or b is None or a[0] != b[0] or (a[0] == "error" and a != b):
            bad.append(f"{key}: {a} != {b}")
        elif a[0] == "ok" and (
            a[1:3] != b[1:3]
            or not np.allclose(a[3], b[3], rtol=0, atol=TOLERANCE)
            or not np.allclose(a[4], b[4], rtol=0, atol=TOLERANCE)
        ):
            bad.append(f"{key}:\n  old {a}\n  new {b}")
    n_ok = sum(v[0] == "ok" for v in new.values())
    n_suspect = sum(v[0] == "ok" and v[1] == "suspect" for v in new.values())
    print(f"{len(new)} estimates ({n_ok} made, {n_suspect} suspect, {len(new) - n_ok} refused)")
    if bad:
        print("DIFFERENT:\n" + "\n".join(bad))
        sys.exit(1)
    print(f"identical: quality, warnings, failures; normals, sigmas and push within {TOLERANCE:g}")


if __name__ == "__main__":
    main()
