"""Estimating a ROS 2 bag of mono8 pairs against the same frames as a PNG dataset, on one worker.

Simulates a paper sweep (1280x720 mono8, the default jig), converts it to a bag (``softjig convert``'s
:func:`~softjig.io.bag_convert.dataset_to_bag`, zstd chunks: softjig's writer), and writes its loaded
frames into a second bag with another library's writer (mcap-ros2-support: mcap's ``Writer``, zstd
level 3, 1 MiB chunks, no softjig topics), then for each source times, per frame:

* ``read``: getting the pair's two images into memory (PNG decode; bag: zstd chunk, CDR, pairing),
* ``read + estimate``: that and one :class:`~softjig.sensing.estimator.Estimator`'s ``estimate`` (refractive
  method, against the reference frame), what ``softjig estimate --workers 1`` spends per frame.

and, for each bag, ``zstd``: the CPU its chunks' decompression alone takes a pair (every chunk of the file
through one ``zstandard`` context, over the bag's pairs): the share of ``read`` that the writer's zstd
level decides (softjig's level 1 chunks decompress at ~2 GB/s; a negative level stores camera images
nearly as they are, in a bag ~1.6 times larger, and decompresses several times faster).

One warm-up pass first (Numba caches, per-jig tables), then ``--rounds`` timed passes. Each figure is
given as the median over the loaded frames and as their mean (the total over the frames after the first,
which pays for opening the source, divided by the loaded frames): where a bag's zstd chunk holds several
pairs (softjig's 4 MiB chunks until December 2026 held ~2.4), only one frame in two or three pays for
decompressing it and the median leaves that out; the mean is what a recording costs. Target (issue 15):
a bag's ``read + estimate`` at most 6 ms a frame.

``--src OLD/src NEW/src`` measures each source tree in its own warm worker process (``PYTHONPATH`` = that
tree): each writes its own bag (its own writer) and reads the same other-library bag; the workers take
turns, ``--rounds`` passes each, the order alternating, and the table gives each figure's median over the
rounds, tree beside tree (one pass, ~3 s a tree, is short enough for the load to stay alike).

``--zstd-level L [L ...]`` writes softjig's bags at zstd level ``L``: one level for every tree, or one a
tree (``--src NEW NEW --zstd-level 1 -1`` measures two levels side by side; a tree whose
``dataset_to_bag`` takes no ``zstd_level`` takes only its own level).

Run: ``python benchmarks/bench_bag.py [--frames-per-alpha 12] [--out DIR] [--src A B --rounds 3]``. The
numbers depend on the machine's load (the shared development machine runs several sessions at once):
quote medians and say so.
"""

from __future__ import annotations

import argparse
import contextlib
import inspect
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")


def timed_frames(frames, estimator, *, estimate: bool):
    """``(reference, wall s, CPU s)`` per frame of ``frames``: from asking for the frame to having its
    images (and, ``estimate``, the estimate of a loaded frame)."""
    from softjig.errors import SoftjigError

    it = iter(frames)
    while True:
        t0, c0 = time.perf_counter(), time.process_time()
        frame = next(it, None)
        if frame is None:
            return
        left, right = frame.load_left(), frame.load_right()
        if not frame.reference and estimate:
            with contextlib.suppress(SoftjigError):
                estimator.estimate(left, right)
        yield frame.reference, time.perf_counter() - t0, time.process_time() - c0


def _time_source(frames, jig, reference, *, estimate: bool) -> tuple[list[float], list[float], float]:
    """:func:`frame_figures` of ``frames`` with an Estimator of ``jig`` against ``reference``."""
    from softjig.sensing.estimator import Estimator

    estimator = Estimator(jig, reference=reference, method="refractive")  # once, as estimate_dataset does
    return frame_figures(frames, estimator, estimate=estimate)


def frame_figures(frames, estimator, *, estimate: bool) -> tuple[list[float], list[float], float]:
    """Wall and CPU seconds per loaded frame: from asking for the frame to having its images (and its
    estimate), and the mean CPU seconds a loaded frame. The source's opening (a bag's metadata and type
    definitions, ~0.1-0.3 s once) falls on the first frame (a dataset's or softjig bag's reference
    frame, which the medians leave out), which the mean leaves out: the mean is the CPU of the frames
    after the first over their number. Of this benchmark and bench_frame's."""
    wall, cpu = [], []
    total, after_first = 0.0, 0
    for k, (is_reference, spent_wall, spent) in enumerate(timed_frames(frames, estimator, estimate=estimate)):
        if k > 0:
            total, after_first = total + spent, after_first + 1
        if not is_reference:
            wall.append(spent_wall)
            cpu.append(spent)
    return wall, cpu, total / max(after_first, 1)


FOREIGN_LEFT, FOREIGN_RIGHT = "/camera/left/image_raw", "/camera/right/image_raw"
SOURCES = ("PNG dataset", "bag, softjig's writer", "bag, mcap-ros2-support")


def write_foreign_bag(dataset, path: Path) -> None:
    """The dataset's loaded pairs as a single ``.mcap`` written by mcap-ros2-support (mcap's ``Writer``
    defaults: zstd level 3, 1 MiB chunks), mono8 ``sensor_msgs/msg/Image`` on two camera topics."""
    from mcap_ros2.writer import Writer
    from rosbags.typesys import Stores, get_typestore

    msgdef, _ = get_typestore(Stores.ROS2_HUMBLE).generate_msgdef("sensor_msgs/msg/Image", ros_version=2)
    tmp = path.with_name(path.name + ".part")
    with open(tmp, "wb") as fh:
        writer = Writer(fh)
        schema = writer.register_msgdef("sensor_msgs/msg/Image", msgdef)
        stamp = 1_700_000_000_000_000_000
        for frame in dataset:
            if frame.reference:
                continue
            stamp += 33_333_333
            for topic, image in ((FOREIGN_LEFT, frame.load_left()), (FOREIGN_RIGHT, frame.load_right())):
                header = {"stamp": {"sec": stamp // 10**9, "nanosec": stamp % 10**9}, "frame_id": "cam"}
                msg = {"header": header, "height": image.shape[0], "width": image.shape[1],
                       "encoding": "mono8", "is_bigendian": 0, "step": image.shape[1],
                       "data": image.tobytes()}  # fmt: skip
                writer.write_message(topic, schema, msg, log_time=stamp)
        writer.finish()
    tmp.replace(path)


def zstd_cpu_s(path: Path) -> float:
    """CPU seconds spent decompressing every zstd chunk of the MCAP file (or a bag folder's) ``path``."""
    import zstandard
    from mcap.records import Chunk
    from mcap.stream_reader import StreamReader

    decompressor = zstandard.ZstdDecompressor()
    spent = 0.0
    for file in [path] if path.is_file() else sorted(path.glob("*.mcap")):
        with open(file, "rb") as fh:
            for record in StreamReader(fh, emit_chunks=True, record_size_limit=2**31).records:
                if isinstance(record, Chunk) and record.compression == "zstd":
                    c0 = time.process_time()
                    decompressor.decompress(record.data, max_output_size=record.uncompressed_size)
                    spent += time.process_time() - c0
    return spent


def sources(data: Path, bag: Path, zstd_level: int | None = None) -> tuple[dict, object, object, dict]:
    """``({name: frames maker}, jig, reference, {bag source's name: (its path, its pairs)})``: the dataset,
    softjig's bag (written to ``bag`` afresh by this tree's writer) and the other library's bag in
    ``data``; warmed up (Numba, tables, page cache)."""
    import cv2

    cv2.setNumThreads(1)
    from softjig.io.bag_convert import dataset_to_bag
    from softjig.io.batch import dataset_reference
    from softjig.io.dataset import Dataset
    from softjig.io.rosbag import BagReader

    dataset = Dataset.open(data / "dataset")
    jig = dataset.jig
    level = {} if zstd_level is None else {"zstd_level": zstd_level}  # else the tree's default
    if level and "zstd_level" not in inspect.signature(dataset_to_bag).parameters:  # an older tree
        from softjig.io.mcap_chunks import ZSTD_LEVEL

        if zstd_level != ZSTD_LEVEL:
            raise SystemExit(f"this tree writes zstd level {ZSTD_LEVEL} only, not {zstd_level}")
        level = {}
    dataset_to_bag(dataset, bag, estimate=False, start_unix_s=1.7e9, overwrite=True, **level)  # its writer
    reference = dataset_reference(dataset, jig)

    def bag_frames(path):
        def frames():
            with BagReader(path) as reader:
                yield from reader.pairs(reader.choose_topics())

        return frames

    makers = (lambda: dataset, bag_frames(bag), bag_frames(data / "foreign.mcap"))
    made = dict(zip(SOURCES, makers, strict=True))
    for source in made.values():
        _time_source(source(), jig, reference, estimate=True)
    bags = {SOURCES[1]: bag, SOURCES[2]: data / "foreign.mcap"}
    return made, jig, reference, {name: (path, sum(1 for _ in made[name]())) for name, path in bags.items()}


def measure(made: dict, jig, reference, bags: dict) -> dict[str, list[float]]:
    """Each source's figures (ms a frame) of one pass: read wall / CPU median / CPU mean, read + estimate
    likewise, a bag's zstd CPU a pair (NaN for the dataset), and the frames."""
    results = {}
    med = statistics.median
    for name, source in made.items():
        read, read_cpu, read_mean = _time_source(source(), jig, reference, estimate=False)
        full, full_cpu, full_mean = _time_source(source(), jig, reference, estimate=True)
        zstd = zstd_cpu_s(bags[name][0]) / bags[name][1] if name in bags else float("nan")
        figures = [med(read), med(read_cpu), read_mean, med(full), med(full_cpu), full_mean, zstd]
        results[name] = [1000 * x for x in figures] + [len(full)]
    return results


def worker(data: Path, bag: Path, zstd_level: int | None) -> None:
    """A warm tree: one JSON line of :func:`measure` for each ``time`` line on stdin."""
    made = sources(data, bag, zstd_level)
    print(json.dumps({"ready": True}), flush=True)
    for line in sys.stdin:
        if line.strip() == "time":
            print(json.dumps(measure(*made)), flush=True)


def prepare(root: Path, frames_per_alpha: int) -> None:
    """The simulated dataset and the other-library bag in ``root`` (kept between runs)."""
    from softjig.config import default_jig
    from softjig.io.dataset import Dataset
    from softjig.io.simulated import simulate_dataset
    from softjig.sim.scenarios import paper_sweep

    ds_path = root / "dataset"
    if not (ds_path / "frames.jsonl").exists():
        step = 360.0 / frames_per_alpha
        specs = list(paper_sweep(diameters_mm=(50,), alphas_deg=(5, 10, 15, 20), theta_step_deg=step))
        simulate_dataset(ds_path, specs, default_jig(), seed=7, workers=os.cpu_count(), progress=False)
    if not (root / "foreign.mcap").exists():
        write_foreign_bag(Dataset.open(ds_path), root / "foreign.mcap")


def _sizes(root: Path, bags: list[Path]) -> str:
    png = sum(p.stat().st_size for p in (root / "dataset" / "left").iterdir()) * 2 / 2**20
    ours = [sum(p.stat().st_size for p in b.glob("*.mcap")) / 2**20 for b in bags]
    foreign = (root / "foreign.mcap").stat().st_size / 2**20
    ours_mb = " / ".join(f"{m:.0f}" for m in ours)
    return f"PNG {png:.0f} MiB, softjig's bag {ours_mb} MiB, other library's {foreign:.0f} MiB"


def _table(trees: list[dict[str, list[list[float]]]], labels: list[str]) -> None:
    """Medians over the rounds, each tree's row beside the other's."""
    print(
        f"{'source':<24} {'tree':<6} {'read ms/frame':>24} {'read+estimate ms/frame':>26} {'zstd':>6} "
        f"{'frames':>7}"
    )
    print(f"{'':<24} {'':<6} {'wall / CPU / CPU mean':>24} {'wall / CPU / CPU mean':>26} {'CPU':>6}")
    for name in SOURCES:
        for label, tree in zip(labels, trees, strict=True):
            rounds = tree.get(name)
            if not rounds:
                continue
            v = [statistics.median(r[i] for r in rounds) for i in range(8)]
            zstd = "-" if v[6] != v[6] else f"{v[6]:.2f}"  # NaN: not a bag
            print(
                f"{name:<24} {label:<6} {v[0]:>8.2f} / {v[1]:>5.2f} / {v[2]:>5.2f} "
                f"{v[3]:>10.2f} / {v[4]:>5.2f} / {v[5]:>5.2f} {zstd:>6} {int(v[7]):>7}"
            )


def _rounds(
    srcs: list[str | None], root: Path, bags: list[Path], rounds: int, levels: list[int | None]
) -> list[dict]:
    """Each tree's figures, round by round (the trees take turns, the order alternating)."""
    trees: list[dict[str, list[list[float]]]] = [{} for _ in srcs]
    if srcs == [None]:
        made = sources(root, bags[0], levels[0])
        for _ in range(rounds):
            for name, figures in measure(*made).items():
                trees[0].setdefault(name, []).append(figures)
        return trees
    procs = []
    for src, bag, level in zip(srcs, bags, levels, strict=True):
        env = {**os.environ, "PYTHONPATH": str(src)}
        argv = [sys.executable, __file__, "--out", str(root), "--child", str(bag)]
        argv += [] if level is None else ["--zstd-level", str(level)]
        procs.append(
            subprocess.Popen(argv, env=env, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
        )
    for proc in procs:
        assert proc.stdout is not None and json.loads(proc.stdout.readline())["ready"]
    for r in range(rounds):
        for i in range(len(procs)) if r % 2 == 0 else reversed(range(len(procs))):
            stdin, stdout = procs[i].stdin, procs[i].stdout
            assert stdin is not None and stdout is not None
            stdin.write("time\n")
            stdin.flush()
            for name, figures in json.loads(stdout.readline()).items():
                trees[i].setdefault(name, []).append(figures)
    for proc in procs:
        assert proc.stdin is not None
        proc.stdin.close()
        proc.wait()
    return trees


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames-per-alpha", type=int, default=12, help="theta steps per tilt (4 tilts)")
    parser.add_argument("--out", type=Path, default=None, help="keep the dataset and bags here")
    parser.add_argument("--src", nargs="*", default=None, help="source trees to compare (PYTHONPATH)")
    parser.add_argument("--rounds", type=int, default=1, help="timed passes per tree")
    parser.add_argument(
        "--zstd-level",
        type=int,
        nargs="*",
        default=None,
        help="softjig's bag's zstd level: one for every tree, or one a tree (default: each tree's own)",
    )
    parser.add_argument("--child", type=Path, default=None, help=argparse.SUPPRESS)
    args = parser.parse_args()
    for name in ("frames_per_alpha", "rounds"):  # 0 divided by zero or gave no pass; 0 rounds was made 1
        if getattr(args, name) < 1:
            parser.error(f"--{name.replace('_', '-')} must be at least 1, got {getattr(args, name)}")
    root = args.out or Path(tempfile.mkdtemp(prefix="bench_bag_"))
    levels = args.zstd_level or [None]
    if args.child is not None:
        worker(root, args.child, levels[0])
        return
    srcs = [str(Path(s).resolve()) for s in args.src] if args.src else [None]
    if len(levels) not in (1, len(srcs)):
        parser.error(f"--zstd-level takes one level or one a tree ({len(srcs)}), got {len(levels)}")
    levels = levels * len(srcs) if len(levels) == 1 else levels
    prepare(root, args.frames_per_alpha)
    bags = [root / f"bag{i}" for i in range(len(srcs))]
    trees = _rounds(srcs, root, bags, args.rounds, levels)
    print(f"1280x720 mono8, one worker, one OpenCV thread; {_sizes(root, bags)} (zstd chunks)")
    labels = [f"t{i}" for i in range(len(srcs))]
    _table(trees, labels)
    for label, src, level in zip(labels, srcs, levels, strict=True):
        print(f"{label}: {src or 'this interpreter'}" + ("" if level is None else f", zstd level {level}"))
    print(
        f"medians over {args.rounds} round(s); wall times suffer from the shared "
        "machine's load (CPU time, this process only, less so); load average now "
        f"{os.getloadavg()[0]:.1f} on {os.cpu_count()} CPUs"
    )


if __name__ == "__main__":
    main()
