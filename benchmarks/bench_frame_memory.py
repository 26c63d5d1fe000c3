"""Peak memory of rendering and estimating one stereo pair against the image size.

The config's resolution cap (``softjig.config.MAX_IMAGE_PIXELS``) is derived from these figures. Each size
runs in a fresh process (peak RSS is per process), the default jig's cameras scaled by ``SCALE`` (the
focal length with them, so the jig fills the image the same way).

    python benchmarks/bench_frame_memory.py            # scales 1, 2, 3: 1280x720, 2560x1440, 3840x2160
    python benchmarks/bench_frame_memory.py 1 1.5 2
"""

from __future__ import annotations

import subprocess
import sys

CHILD = r"""
import resource, sys
from dataclasses import replace
import numpy as np
from softjig.config import CylinderPart, default_jig
from softjig.sensing.pipeline import estimate_pair
from softjig.sim.asbuilt import nominal_as_built
from softjig.sim.parts import PartPose
from softjig.sim.render import render_pair

scale = float(sys.argv[1])
jig = default_jig()
w, h = int(1280 * scale), int(720 * scale)

def cam(c):
    return replace(c, width_px=w, height_px=h, fx_px=925 * scale, fy_px=925 * scale, cx_px=(w - 1) / 2,
                   cy_px=(h - 1) / 2)

jig = jig.replace(cameras=replace(jig.cameras, left=cam(jig.cameras.left), right=cam(jig.cameras.right)))
base = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
pose = PartPose(0.1, 0.3, 3.0)
pair = render_pair(nominal_as_built(jig), CylinderPart(50.0), pose, np.random.default_rng(0))
rendered = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
estimate_pair(pair.left, pair.right, jig)
peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
print(f"{w}x{h}\t{w * h / 1e6:.1f}\t{base / 1024:.0f}\t{rendered / 1024:.0f}\t{peak / 1024:.0f}")
"""


def main(scales: list[str]) -> None:
    print("image\tMpx\timports MB\trender peak MB\trender+estimate peak MB")
    for scale in scales or ["1", "2", "3"]:
        out = subprocess.run([sys.executable, "-c", CHILD, scale], capture_output=True, text=True, check=True)
        print(out.stdout.strip())


if __name__ == "__main__":
    main(sys.argv[1:])
