"""`softjig estimate BAG`: every stereo pair of a ROS 2 bag to estimates (the bag branch of ``estimate``).

The rows are those of a dataset (:mod:`softjig.io.batch`: the estimate contract's fields and the
frame's ``index``, or its ``error`` and ``exit_code``) plus each pair's header stamps, ``stamp_left_ns``
and ``stamp_right_ns`` (JSON Lines; a CSV keeps the dataset's columns). A softjig bag (``/softjig/frame``)
gives each pair its dataset index, part and reference flag, so estimating it equals estimating the
dataset it came from; another bag's pairs are numbered from 0, and loaded.
"""

from __future__ import annotations

import itertools
import sys
import time
import warnings
from collections import deque
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import typer

from softjig.cli.app import load_config, stderr_console, warn
from softjig.errors import EstimationError, InputError

if TYPE_CHECKING:
    from softjig.calibration.tilt import TiltCalibration
    from softjig.io.rosbag import BagPair


class _Pairs:
    """The bag's pairs as :func:`~softjig.io.batch.estimate_dataset` takes them: iterable once, and
    sized by a bound no bag reaches (the number of pairs is known only once they are read, and a bag's
    message counts may be wrong: the estimation ends when the pairs do, never before). Each pair's stamps
    are queued for its row, which comes back in the same order."""

    def __init__(self, pairs: Iterator[BagPair]) -> None:
        self._pairs = pairs
        self.stamps: deque[dict[str, int]] = deque()

    def __len__(self) -> int:
        return sys.maxsize

    def __iter__(self) -> Iterator[BagPair]:
        for pair in self._pairs:
            self.stamps.append(pair.stamps)
            yield pair


def estimate_bag(
    path: Path,
    config: Path | None,
    part_diameter: float | None,
    cal: TiltCalibration | None,
    method: str,
    out: Path | None,
    workers: int | None,
    progress: bool,
    use_reference: bool,
    left_topic: str | None,
    right_topic: str | None,
    stamp_tolerance_s: float,
    *,
    part_size: bool = True,
) -> None:
    """Estimate every pair of a bag and stream the rows to ``out`` (default ``BAG_estimates.jsonl`` beside
    the bag). The reference frame (refractive method) is a softjig bag's reference pair that comes before
    its first loaded pair, as simulations and recordings write it."""
    from softjig.io.bag_convert import no_pairs_error
    from softjig.io.batch import BatchSettings
    from softjig.io.rosbag import BagReader, BagTruncationWarning

    if out is None:
        out = path.parent / f"{path.stem if path.is_file() else path.name}_estimates.jsonl"
    _check_out(out, path)
    t0 = time.perf_counter()
    with warnings.catch_warnings():  # a truncated bag's note is shown below, once, as a warning line
        warnings.simplefilter("ignore", BagTruncationWarning)
        reader = BagReader(path).open()
    with reader:
        for note in reader.notes:
            warn(note)
        topics = reader.choose_topics(left_topic, right_topic)
        if topics.reason != "given":
            warn(f"reading left images from {topics.left}, right from {topics.right} ({topics.reason})")
        jig = load_config(config) if config else reader.rig()
        if jig is None:
            raise InputError(
                f"{path} carries no softjig rig (/softjig/rig): pass --config RIG.toml (the cameras' rig)"
            )
        stream = reader.pairs(topics, tolerance_s=stamp_tolerance_s)
        pairs = iter(stream)
        lead, reference = _lead_pairs(pairs, jig, use_reference=use_reference and method == "refractive")
        if not lead:
            raise no_pairs_error(path, topics, stream)
        settings = BatchSettings(
            jig=jig,
            part_diameter_mm=part_diameter,
            calibration=cal,
            method=method,
            reference=reference,
            frame_part_size=part_size,
        )
        sized = _Pairs(itertools.chain(lead, pairs))
        tally = _write_rows(
            sized, settings, out, workers=workers, progress=progress, total=stream.upper_bound
        )
    typer.echo(
        f"estimated {tally.n_loaded - tally.n_failed} of {tally.n_loaded} loaded pairs of {path} in "
        f"{time.perf_counter() - t0:.1f} s ({method}"
        + (", indentations against the reference frame" if reference is not None else "")
        + f"); wrote {out}"
    )
    if stream.unpaired:
        warn(
            f"{stream.unpaired} images of {topics.left} / {topics.right} found no partner within "
            f"{stamp_tolerance_s * 1000:g} ms and were skipped (--stamp-tolerance)"
        )
    _check_tally(tally, path, out)


def _lead_pairs(pairs: Iterator[BagPair], jig, *, use_reference: bool) -> tuple[list[BagPair], Any]:
    """Read the pairs up to the first loaded one; the reference frame from the first reference pair among
    them when ``use_reference`` (else ``None``)."""
    from softjig.io.reference import recorded_reference

    lead = []
    reference = None
    for pair in pairs:  # a reference pair before the first loaded one
        lead.append(pair)
        if not pair.reference:
            break
        if reference is None and use_reference:
            where = f"the bag's pair {pair.index} (marked reference)"
            reference = recorded_reference(lambda p=pair: p.left, lambda p=pair: p.right, jig, where)
    return lead, reference


@dataclass
class _Tally:
    """What the rows of a bag said: loaded pairs, those that failed (the first of them), and reference
    pairs after the first loaded one (not used)."""

    n_loaded: int = 0
    n_failed: int = 0
    late_references: int = 0
    first_failure: dict | None = None


def _write_rows(
    sized: _Pairs, settings: Any, out: Path, *, workers: int | None, progress: bool, total: int | None
) -> _Tally:
    """Estimate the pairs and stream each row, with its pair's stamps, to ``out``."""
    from rich.progress import Progress

    from softjig.io.batch import RowsWriter, estimate_dataset

    tally = _Tally()
    with (
        RowsWriter(out) as writer,
        Progress(console=stderr_console(), disable=not progress, transient=True) as bar,
    ):
        task = bar.add_task("estimating", total=total)
        for row in estimate_dataset(sized, settings, workers=workers):
            row = {**row, **sized.stamps.popleft()}
            writer.write(row)
            bar.advance(task)
            if row.get("reference") is True:
                tally.late_references += tally.n_loaded > 0
                continue
            tally.n_loaded += 1
            if "error" in row:
                tally.n_failed += 1
                tally.first_failure = tally.first_failure or row
    return tally


def _check_tally(tally: _Tally, path: Path, out: Path) -> None:
    """Warn of unused reference pairs and of failed pairs; exit 3 when no loaded pair gave an estimate."""
    if tally.late_references:
        warn(
            f"{tally.late_references} reference frames after the first loaded one were not used as the "
            "reference"
        )
    if tally.n_loaded == 0:
        raise EstimationError(f"{path} holds only unloaded reference frames: no pair with a part to estimate")
    if tally.first_failure is not None:
        message = (
            f"{tally.n_failed} pairs gave no estimate (see their 'error' in {out}), e.g. pair "
            f"{tally.first_failure['index']}: {tally.first_failure['error']}"
        )
        if tally.n_failed == tally.n_loaded:  # every error is written; the run itself failed (exit 3)
            raise EstimationError(f"no pair of {path} gave an estimate: {message}")
        warn(message)


def _check_out(out: Path, bag: Path) -> None:
    """An InputError if ``out`` is not a results file name or is one of the bag's own files."""
    if out.suffix.lower() not in (".jsonl", ".json", ".ndjson", ".csv"):
        raise InputError(f"--out {out}: the results file must end in .jsonl or .csv")
    from softjig.io.outputs import same_path

    members = [bag] if bag.is_file() else [p for p in bag.iterdir() if p.is_file()]
    if any(same_path(out, member) for member in members):  # links too
        raise InputError(f"--out {out} is one of the bag's own files: writing there would destroy it")
