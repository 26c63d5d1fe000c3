"""Datasets on disk: one reader and one writer for recordings, simulations and replays.

A dataset is a folder (``DESIGN.md`` §3)::

    rig.toml               the NOMINAL jig: what a user knows (the estimator reads this)
    frames.jsonl           one JSON object per stereo frame, in order
    left/NNNNNN.png        lossless images, 8 or 16 bit, gray or colour
    right/NNNNNN.png
    truth/NNNNNN.npz       simulations only: every marker's xyz_mm, axis, in_contact, left_px,
                           right_px, visible_left, visible_right
    as_built.toml          simulations only: the as-built jig the images were rendered from,
    as_built_markers.npz   with its markers' real (x, y); for analysis only, never read by the estimator

A frame object in ``frames.jsonl`` has ``index``, ``left`` and ``right`` (paths relative to the folder),
optionally ``time_s``, and where known ``alpha_deg``, ``theta_deg``, ``part`` (``kind``,
``diameter_mm``, ... as written by :func:`softjig.config.part_to_dict`) and ``truth`` (``normal``
``[x, y, z]`` in J, ``push_depth_mm``, ``markers``: the relative path of the frame's ``.npz``,
``T_J_part``: the part's 4x4 pose in J). An unloaded reference frame has ``reference: true`` and no
``alpha_deg`` nor ``part``. Any other key is kept as is (:attr:`Frame.meta`).

**Crash safety.** :class:`DatasetWriter` writes each image and ``.npz`` atomically
(:mod:`softjig.files`) and appends the frame's line to ``frames.jsonl`` (flush + fsync) only after
its files exist, so a recorder killed at any moment leaves every completed frame readable. A kill in the
middle of the append can leave a truncated last line; :meth:`Dataset.open` skips it with a warning, as it
does any line that is not JSON. Two frames with one index are refused.

**Overwriting** (``--overwrite``) replaces only a dataset softjig simulated, recognised by its as-built
files (:func:`is_simulation`), never a recording, and atomically (:class:`DatasetWriter`).

**Paths stay inside.** ``left``, ``right`` and ``truth.markers`` are relative to the folder: an absolute
path or one climbing out with ``..`` is refused when the dataset is opened, and a path leading out through
a symbolic link when its file is read.

**Laziness.** :meth:`Dataset.open` reads ``rig.toml`` and checks every line of ``frames.jsonl`` in one
streaming pass, but keeps only where each frame's line starts (16 bytes per frame): a frame is parsed
again from its line when asked for (``ds[i]``, ``for frame in ds``), so a dataset of any length opens in
flat memory and :class:`Frame` objects live only as long as their user keeps them. Images and truth are
read when asked for (:meth:`Frame.load_left`, :meth:`Frame.load_right`, :meth:`Frame.load_truth_markers`).
Parts are parsed once per distinct part (a pydantic validator per frame would dominate the opening).

Every problem with the files is an :class:`~softjig.errors.InputError` (or its subclass
:class:`~softjig.errors.ConfigError` for ``rig.toml``) naming the file and what to do.
"""

from __future__ import annotations

import io
import json
import math
import os
import re
import shutil
import warnings
from array import array
from collections.abc import Generator, Iterator, Mapping
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path, PurePosixPath, PureWindowsPath
from typing import TYPE_CHECKING, Any, overload

import cv2
import numpy as np

from softjig.config import JigConfig, Part, dumps_jig, load_jig, loads_jig, part_from_dict, save_jig
from softjig.errors import ConfigError, InputError
from softjig.files import fsync_folder, write_bytes_atomic, write_text_atomic

if TYPE_CHECKING:
    from softjig.sim.asbuilt import AsBuiltJig

__all__ = [
    "AS_BUILT_MARKERS_NAME",
    "AS_BUILT_NAME",
    "FRAMES_NAME",
    "RIG_NAME",
    "TRUTH_MARKER_FIELDS",
    "Dataset",
    "DatasetLineWarning",
    "DatasetTruncationWarning",
    "DatasetWriter",
    "Frame",
    "FrameTruth",
    "encode_png",
    "is_dataset_member",
    "is_simulation",
    "load_image",
]

RIG_NAME = "rig.toml"
FRAMES_NAME = "frames.jsonl"
AS_BUILT_NAME = "as_built.toml"
AS_BUILT_MARKERS_NAME = "as_built_markers.npz"
_SUBDIRS = ("left", "right", "truth")
_DATASET_MEMBERS = (RIG_NAME, FRAMES_NAME, AS_BUILT_NAME, AS_BUILT_MARKERS_NAME, *_SUBDIRS)
#: Files softjig itself writes into a dataset folder besides the dataset (``estimate``'s default results,
#: the demo's simulated motion capture): an overwrite may replace them with the dataset.
WRITTEN_BESIDE = ("estimates.jsonl", "estimates.csv", "mocap.csv")
#: Where an overwrite writes the new dataset (beside the old one) until it is complete, and where the old
#: one goes for the moment of the swap: ``<folder><suffix>``.
STAGING_SUFFIX, RETIRED_SUFFIX = ".softjig-new", ".softjig-old"
_MEMBER_FILE = {"left": re.compile(r"\d{6,}\.png"), "right": re.compile(r"\d{6,}\.png"),
                "truth": re.compile(r"\d{6,}\.npz")}  # fmt: skip
_TEMPORARY = re.compile(r"\..+\.tmp")


def _foreign_entries(root: Path) -> list[str]:
    """What a folder holds that :class:`DatasetWriter` (or softjig beside it) did not write: an overwrite
    must not delete it. Relative paths, sorted."""
    foreign = []
    for entry in sorted(root.iterdir()):
        name = entry.name
        if _TEMPORARY.fullmatch(name) and entry.is_file():
            continue
        if name in _MEMBER_FILE and entry.is_dir() and not entry.is_symlink():
            pattern = _MEMBER_FILE[name]
            foreign += [
                f"{name}/{sub.name}"
                for sub in sorted(entry.iterdir())
                if not (sub.is_file() and (pattern.fullmatch(sub.name) or _TEMPORARY.fullmatch(sub.name)))
            ]
        elif name not in (RIG_NAME, FRAMES_NAME, AS_BUILT_NAME, AS_BUILT_MARKERS_NAME, *WRITTEN_BESIDE) or (
            not entry.is_file() or entry.is_symlink()
        ):
            foreign.append(name + ("/" if entry.is_dir() else ""))
    return foreign


#: The arrays of a frame's truth ``.npz`` (each with one row per marker).
TRUTH_MARKER_FIELDS = (
    "xyz_mm",
    "axis",
    "in_contact",
    "left_px",
    "right_px",
    "visible_left",
    "visible_right",
)
_TRUTH_EXTRA_FIELDS = ("fiducial_corners_left_px", "fiducial_corners_right_px")

PNG_COMPRESSION = 1  # zlib level: lossless either way; 1 is much faster to write than the default 3
_RESERVED_KEYS = ("index", "left", "right")


class DatasetLineWarning(UserWarning):
    """A line of a dataset's ``frames.jsonl`` is not JSON (garbage, a bad edit) and was skipped."""


class DatasetTruncationWarning(DatasetLineWarning):
    """A dataset's last ``frames.jsonl`` line was cut short (a recorder killed mid-write) and skipped."""


def _member_path(root: Path, relative: str, what: str) -> Path:
    """``root / relative``, checked to stay inside the dataset folder ``root`` once every ``..`` and
    symbolic link is resolved: a dataset names only its own files (a ``frames.jsonl`` naming
    ``../../etc/passwd`` must not make softjig read, or a recorder copy, files from elsewhere).

    Raises
    ------
    InputError
        The path leaves the dataset folder (``what`` names the frame and the key).
    """
    path = root / relative
    try:
        inside = path.resolve().is_relative_to(root.resolve())
    except (OSError, RuntimeError):  # a symlink loop
        inside = False
    if not inside:
        raise InputError(
            f"{what} {relative!r} is outside the dataset folder {root}: a dataset names only files inside "
            "its folder; copy the file into the dataset and name it relative to the folder"
        )
    return path


def is_dataset_member(path: str | os.PathLike[str]) -> bool:
    """Whether ``path`` is (or would be) one of the files of *some* softjig dataset: a ``rig.toml``,
    ``frames.jsonl`` or as-built file beside a ``frames.jsonl`` and a ``rig.toml``, or a file in the
    ``left/``, ``right/`` or ``truth/`` folder of such a folder. Outputs must not be written there."""
    path = Path(path).resolve()

    def is_dataset(folder: Path) -> bool:
        return (folder / FRAMES_NAME).is_file() and (folder / RIG_NAME).is_file()

    if path.name in (RIG_NAME, FRAMES_NAME, AS_BUILT_NAME, AS_BUILT_MARKERS_NAME) and is_dataset(path.parent):
        return True
    return path.parent.name in _SUBDIRS and is_dataset(path.parent.parent)


def is_simulation(path: str | os.PathLike[str]) -> bool:
    """Whether the dataset folder ``path`` is one softjig simulated: it holds the as-built jig its images
    were rendered from (``as_built.toml`` and ``as_built_markers.npz``, regular files).

    That pair is the dataset's provenance: softjig writes it for simulations only (``simulate``, ``demo``,
    every version since the first), never for a recording (``live --record``, ``convert`` from a bag, which
    carry a replay's truth over but not its as-built jig), and a user's own dataset has no reason to hold
    it. A simulation can be rendered again from its seed; a recording cannot, so only a simulation may be
    replaced by an overwrite (:class:`DatasetWriter`). Per-frame ``truth`` is no such sign: a recording of
    a replayed simulation carries it.
    """
    root = Path(path)
    return all(
        (root / name).is_file() and not (root / name).is_symlink()
        for name in (AS_BUILT_NAME, AS_BUILT_MARKERS_NAME)
    )


def _same_file(a: Path, b: Path) -> bool:
    try:
        return os.path.samefile(a, b)
    except OSError:
        return False


def _check_relative(relative: str, where: str, key: str) -> None:
    """Refuse, when a dataset is opened, a path that cannot stay inside the folder whatever is on disk:
    absolute, with a drive, or climbing out with ``..``."""
    posix, windows = PurePosixPath(relative), PureWindowsPath(relative)
    parts = windows.parts if "\\" in relative else posix.parts
    if posix.is_absolute() or windows.drive or windows.root or ".." in parts:
        raise InputError(
            f"{where}: {key} {relative!r} is outside the dataset folder: a dataset names only files "
            "inside its folder, relative to it (like left/000000.png)"
        )


# ------------------------------------------------------------------------------------------ images


def load_image(path: str | os.PathLike[str]) -> np.ndarray:
    """Read an image file as stored: ``uint8`` or ``uint16``, ``(H, W)`` gray or ``(H, W, 3)`` RGB.

    Colour files are converted from OpenCV's BGR to RGB (``DESIGN.md`` §1); an alpha channel is dropped.

    Raises
    ------
    InputError
        If the file does not exist, is not a file, cannot be read, or is not an image OpenCV decodes.
    """
    path = Path(path)
    if not path.exists():
        raise InputError(
            f"image {path} does not exist: check the path (a dataset's frames.jsonl "
            "names its images relative to the dataset folder)"
        )
    if not path.is_file():
        raise InputError(f"image {path} is not a file")
    try:
        data = np.fromfile(path, dtype=np.uint8)
    except OSError as exc:
        raise InputError(f"cannot read image {path}: {exc}") from None
    image = cv2.imdecode(data, cv2.IMREAD_UNCHANGED) if data.size else None
    if image is None:
        raise InputError(
            f"cannot decode image {path}: the file is empty, truncated or not an image "
            "format OpenCV reads (use PNG); re-record or re-simulate that frame"
        )
    if image.dtype not in (np.uint8, np.uint16):
        raise InputError(f"image {path} has pixel type {image.dtype}; softjig reads 8- or 16-bit images")
    if image.ndim == 3:
        if image.shape[2] == 1:
            image = image[:, :, 0]
        elif image.shape[2] == 3:
            image = cv2.cvtColor(image, cv2.COLOR_BGR2RGB)
        elif image.shape[2] == 4:
            image = cv2.cvtColor(image, cv2.COLOR_BGRA2RGB)
        else:
            raise InputError(f"image {path} has {image.shape[2]} channels; expected 1, 3 or 4")
    return image


def _check_image(image: np.ndarray, name: str) -> np.ndarray:
    image = np.asarray(image)
    if image.dtype not in (np.uint8, np.uint16):
        raise InputError(f"{name} image must be uint8 or uint16, got {image.dtype}")
    if not (image.ndim == 2 or (image.ndim == 3 and image.shape[2] == 3)):
        raise InputError(f"{name} image must have shape (H, W) or (H, W, 3), got {image.shape}")
    if image.size == 0:
        raise InputError(f"{name} image is empty (shape {image.shape})")
    return image


def encode_png(image: np.ndarray, *, compression: int = PNG_COMPRESSION) -> bytes:
    """Lossless PNG bytes of a ``uint8``/``uint16`` image, ``(H, W)`` gray or ``(H, W, 3)`` RGB.

    Expensive for large images; :class:`DatasetWriter` accepts these bytes in place of the array so that
    worker processes can encode while one process writes.
    """
    image = _check_image(image, "the")
    if image.ndim == 3:
        image = cv2.cvtColor(image, cv2.COLOR_RGB2BGR)
    params = [
        cv2.IMWRITE_PNG_COMPRESSION,
        compression,
        # For noisy sensor images, the "average" filter plus Huffman coding alone is both faster
        # (~2x) and smaller than zlib's default strategy; still lossless.
        cv2.IMWRITE_PNG_STRATEGY,
        cv2.IMWRITE_PNG_STRATEGY_HUFFMAN_ONLY,
        cv2.IMWRITE_PNG_FILTER,
        cv2.IMWRITE_PNG_FILTER_AVG,
    ]
    ok, buf = cv2.imencode(".png", np.ascontiguousarray(image), params)
    if not ok:  # pragma: no cover - OpenCV encodes any valid uint8/uint16 array
        raise InputError(f"OpenCV could not encode an image of shape {image.shape} as PNG")
    return buf.tobytes()


# ----------------------------------------------------------------------------------------- frames


@dataclass(frozen=True, eq=False)
class FrameTruth:
    """Ground truth of a simulated frame.

    Attributes
    ----------
    normal : (3,) the part's true principal normal in J, or ``None`` (reference frame).
    push_depth_mm : the true push depth (``DESIGN.md`` §1), or ``None``.
    markers : path of the frame's truth ``.npz`` relative to the dataset folder, or ``None``.
    T_J_part : (4, 4) the part's true pose in J, or ``None``.
    """

    normal: np.ndarray | None = None
    push_depth_mm: float | None = None
    markers: str | None = None
    T_J_part: np.ndarray | None = None


@dataclass(frozen=True)
class Frame:
    """One stereo frame of a dataset: its metadata, and its images and truth on demand.

    Attributes
    ----------
    root : the dataset folder.
    index : the frame's index as written in ``frames.jsonl``.
    left, right : image paths relative to ``root``.
    time_s : capture time (s), if known.
    alpha_deg, theta_deg : the part's tilt and tilt azimuth (commanded or true), if known.
    part : the part pressed into the jig, if known.
    reference : whether this is an unloaded reference frame.
    truth : ground truth (simulations), or ``None``.
    meta : the frame's whole JSON object, including keys softjig does not interpret.
    """

    root: Path
    index: int
    left: str
    right: str
    time_s: float | None = None
    alpha_deg: float | None = None
    theta_deg: float | None = None
    part: Part | None = None
    reference: bool = False
    truth: FrameTruth | None = field(default=None, compare=False)
    meta: dict[str, Any] = field(default_factory=dict, compare=True, hash=False)

    @property
    def left_path(self) -> Path:
        """Path of the left image (checked to be inside the dataset folder, see :meth:`load_left`)."""
        return _member_path(self.root, self.left, f"frame {self.index}: left image")

    @property
    def right_path(self) -> Path:
        """Path of the right image (checked to be inside the dataset folder)."""
        return _member_path(self.root, self.right, f"frame {self.index}: right image")

    def load_left(self) -> np.ndarray:
        """The left image (see :func:`load_image`).

        Raises
        ------
        InputError
            The image is unreadable, or outside the dataset folder (a symbolic link or ``..`` leading out).
        """
        return load_image(self.left_path)

    def load_right(self) -> np.ndarray:
        """The right image (see :func:`load_image`)."""
        return load_image(self.right_path)

    def load_truth_markers(self) -> dict[str, np.ndarray]:
        """Every marker's truth: a dict with the arrays of :data:`TRUTH_MARKER_FIELDS` (and the
        fiducials' true corners when stored).

        Raises
        ------
        InputError
            If the frame has no truth markers (a recording) or the ``.npz`` is missing or unreadable.
        """
        if self.truth is None or self.truth.markers is None:
            raise InputError(
                f"frame {self.index} of {self.root} has no truth markers: only simulated datasets have them"
            )
        path = _member_path(self.root, self.truth.markers, f"frame {self.index}: truth.markers")
        if not path.is_file():
            raise InputError(
                f"truth file {path} of frame {self.index} does not exist: the dataset is "
                "incomplete; re-simulate it"
            )
        try:
            with np.load(path, allow_pickle=False) as npz:
                return {name: npz[name] for name in npz.files}
        except (OSError, ValueError, EOFError) as exc:
            raise InputError(f"cannot read truth file {path} of frame {self.index}: {exc}") from None


def _frame_from_json(root: Path, obj: Any, where: str) -> Frame:
    """Parse one ``frames.jsonl`` object; ``where`` names the file and line for error messages."""
    if not isinstance(obj, dict):
        raise InputError(f"{where}: expected a JSON object, got {type(obj).__name__}")
    missing = [k for k in _RESERVED_KEYS if k not in obj]
    if missing:
        raise InputError(
            f"{where}: the frame lacks {', '.join(missing)} (every frame needs index, left and right)"
        )
    index = obj["index"]
    if not isinstance(index, int) or isinstance(index, bool) or index < 0:
        raise InputError(f"{where}: index must be a non-negative integer, got {index!r}")
    for side in ("left", "right"):
        if not isinstance(obj[side], str) or not obj[side]:
            raise InputError(
                f"{where}: {side} must be an image path relative to the dataset, got {obj[side]!r}"
            )
        _check_relative(obj[side], where, side)

    def number(key: str) -> float | None:
        value = obj.get(key)
        if value is None:
            return None
        if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
            raise InputError(f"{where}: {key} must be a finite number, got {value!r}")
        return float(value)

    part = None
    if obj.get("part") is not None:
        if not isinstance(obj["part"], dict):
            raise InputError(
                f'{where}: part must be an object like {{"kind": "cylinder", "diameter_mm": 50}}'
            )
        try:
            part = _part_from_json(json.dumps(obj["part"], sort_keys=True))
        except ConfigError as exc:
            raise InputError(f"{where}: {exc}") from None
    truth = _truth_from_json(obj.get("truth"), where)
    reference = obj.get("reference", False)
    if not isinstance(reference, bool):
        raise InputError(f"{where}: reference must be true or false, got {reference!r}")
    return Frame(
        root=root,
        index=index,
        left=obj["left"],
        right=obj["right"],
        time_s=number("time_s"),
        alpha_deg=number("alpha_deg"),
        theta_deg=number("theta_deg"),
        part=part,
        reference=reference,
        truth=truth,
        meta=obj,
    )


@lru_cache(maxsize=256)
def _part_from_json(text: str) -> Part:
    """A frame's part from its JSON text, parsed once per distinct part (a sweep has a handful).

    :func:`softjig.config.part_from_dict` builds a pydantic validator per call, seconds over a long
    replay. Parts are frozen, so every frame of one part can share the object."""
    return part_from_dict(json.loads(text))


def _truth_from_json(obj: Any, where: str) -> FrameTruth | None:
    if obj is None:
        return None
    if not isinstance(obj, dict):
        raise InputError(f"{where}: truth must be an object, got {type(obj).__name__}")

    def array(key: str, shape: tuple[int, ...]) -> np.ndarray | None:
        if obj.get(key) is None:
            return None
        try:
            value = np.asarray(obj[key], dtype=float)
        except (TypeError, ValueError):
            value = None
        if value is None or value.shape != shape or not np.all(np.isfinite(value)):
            raise InputError(f"{where}: truth.{key} must be {shape} finite numbers, got {obj[key]!r}")
        return value

    push = obj.get("push_depth_mm")
    if push is not None and (isinstance(push, bool) or not isinstance(push, int | float)):
        raise InputError(f"{where}: truth.push_depth_mm must be a number, got {push!r}")
    markers = obj.get("markers")
    if markers is not None and not isinstance(markers, str):
        raise InputError(f"{where}: truth.markers must be a relative path, got {markers!r}")
    if markers is not None:
        _check_relative(markers, where, "truth.markers")
    return FrameTruth(
        normal=array("normal", (3,)),
        push_depth_mm=None if push is None else float(push),
        markers=markers,
        T_J_part=array("T_J_part", (4, 4)),
    )


# ---------------------------------------------------------------------------------------- reader


@dataclass(frozen=True, eq=False)
class _LineIndex:
    """Where each frame's line of ``frames.jsonl`` starts: its byte offset and its 1-based line number
    (blank lines are skipped, so a frame's position and its line differ). 16 bytes per frame."""

    path: Path
    offsets: array
    line_numbers: array
    size: int  # bytes of the file up to the end of the last frame's line

    def __len__(self) -> int:
        return len(self.offsets)


class Dataset:
    """A dataset folder, opened lazily (:meth:`open`): ``len(ds)``, ``ds[i]``, ``for frame in ds``.

    ``ds[i]`` is the ``i``-th frame in file order (``frame.index`` for datasets softjig wrote). Frames are
    parsed from ``frames.jsonl`` when asked for, never all held: iterating streams the file, ``ds[i]``
    reads one line (the last frame asked for is kept, so ``ds[i]`` twice reads it once), and
    :meth:`iter_frames` streams a range. :attr:`frames` builds every frame at once (memory grows with the
    dataset's length: for small datasets and tests).

    Only the frames complete when the dataset was opened are seen: lines appended later (a recorder still
    running) are not, and a ``frames.jsonl`` rewritten since raises :class:`~softjig.errors.InputError`
    when its frames are read.
    """

    def __init__(
        self, root: Path, jig: JigConfig, index: _LineIndex, warnings_: list[str] | None = None
    ) -> None:
        self.root = root
        self.jig = jig  #: the nominal jig of ``rig.toml``
        self._index = index
        self._last: tuple[int, Frame] | None = None  # the frame ds[i] returned last
        self.warnings: list[str] = list(warnings_ or [])  #: problems met while opening

    @classmethod
    def open(cls, path: str | os.PathLike[str]) -> Dataset:
        """Open a dataset folder: read its ``rig.toml``, check ``frames.jsonl`` (no image).

        Every line of ``frames.jsonl`` is parsed and checked once, streaming, and forgotten: only where
        each frame's line starts is kept (see the class docstring).

        Raises
        ------
        InputError
            Missing folder, missing ``rig.toml`` or ``frames.jsonl``, a line that is not a valid frame, a
            frame index used twice, a path outside the folder (each named by its line). A line that is
            not JSON is skipped with a :class:`DatasetLineWarning` instead (a truncated *last* line, a
            recorder killed mid-write: :class:`DatasetTruncationWarning`).
        ConfigError
            ``rig.toml`` is invalid (the message names the file and the field).
        """
        root = Path(path)
        if not root.exists():
            raise InputError(
                f"dataset folder {root} does not exist: give the folder written by "
                "`softjig simulate` or a recorder"
            )
        if not root.is_dir():
            raise InputError(
                f"{root} is not a folder: a dataset is a folder holding {RIG_NAME}, "
                f"{FRAMES_NAME}, left/ and right/"
            )
        rig = root / RIG_NAME
        if not rig.is_file():
            raise InputError(
                f"{rig} does not exist: {root} is not a softjig dataset (a dataset folder "
                f"holds {RIG_NAME}, {FRAMES_NAME}, left/ and right/)"
            )
        try:
            jig = load_jig(rig)
        except ConfigError as exc:
            raise ConfigError(f"{rig}: {exc}" if str(rig) not in str(exc) else str(exc)) from None
        frames_path = root / FRAMES_NAME
        if not frames_path.is_file():
            raise InputError(
                f"{frames_path} does not exist: {root} is not a complete softjig dataset "
                f"(a dataset folder holds {RIG_NAME} and {FRAMES_NAME})"
            )
        index, notes = _index_frames(root, frames_path)
        return cls(root, jig, index, notes)

    def __len__(self) -> int:
        return len(self._index)

    @overload
    def __getitem__(self, i: int) -> Frame: ...

    @overload
    def __getitem__(self, i: slice) -> list[Frame]: ...

    def __getitem__(self, i: int | slice) -> Frame | list[Frame]:
        if isinstance(i, slice):
            start, stop, step = i.indices(len(self))
            if step == 1:
                return list(self.iter_frames(start, stop))
            return [self._frame_at(k) for k in range(start, stop, step)]
        n = len(self)
        k = int(i) + n if int(i) < 0 else int(i)
        if not 0 <= k < n:
            raise IndexError(f"frame {i} out of range: {self.root} has {n} frames")
        return self._frame_at(k)

    def __iter__(self) -> Iterator[Frame]:
        return self.iter_frames()

    def __repr__(self) -> str:
        return f"Dataset({str(self.root)!r}, {len(self)} frames)"

    def iter_frames(self, start: int = 0, stop: int | None = None) -> Generator[Frame, None, None]:
        """Stream the frames ``start <= i < stop`` in file order (one pass over their lines, one frame
        held at a time). Negative and out-of-range bounds are clipped as in a slice.

        Raises
        ------
        InputError
            ``frames.jsonl`` cannot be read, or changed since the dataset was opened.
        """
        start, stop, _ = slice(start, stop).indices(len(self))
        if start >= stop:
            return
        offsets = self._index.offsets
        with self._open_frames() as fh:
            fh.seek(offsets[start])
            pos, k = offsets[start], start
            for raw in fh:
                line_start, pos = pos, pos + len(raw)
                if not raw.strip() or line_start < offsets[k]:  # blank, or a line skipped when opened
                    continue
                if line_start != offsets[k]:
                    break
                yield self._parse(raw, k)
                k += 1
                if k == stop:
                    return
        raise self._changed(k)

    @property
    def frames(self) -> tuple[Frame, ...]:
        """All frames, in file order, parsed at once (memory grows with the dataset: prefer iterating)."""
        return tuple(self.iter_frames())

    def _frame_at(self, k: int) -> Frame:
        if self._last is not None and self._last[0] == k:
            return self._last[1]
        with self._open_frames() as fh:
            fh.seek(self._index.offsets[k])
            raw = fh.readline()
        if not raw.strip():
            raise self._changed(k)
        frame = self._parse(raw, k)
        self._last = (k, frame)
        return frame

    def _open_frames(self) -> io.BufferedReader:
        try:
            fh = open(self._index.path, "rb")  # noqa: SIM115 - the callers close it (`with`)
        except OSError as exc:
            raise InputError(f"cannot read {self._index.path}: {exc}") from None
        if os.fstat(fh.fileno()).st_size < self._index.size:  # shortened since it was opened
            fh.close()
            raise self._changed(len(self) - 1)
        return fh

    def _parse(self, raw: bytes, k: int) -> Frame:
        where = f"{self._index.path}, line {self._index.line_numbers[k]}"
        try:
            obj = json.loads(raw.decode("utf-8"))
        except (UnicodeDecodeError, json.JSONDecodeError):
            raise self._changed(k) from None
        return _frame_from_json(self.root, obj, where)

    def _changed(self, k: int) -> InputError:
        return InputError(
            f"{self._index.path} changed since the dataset was opened (frame {k}, line "
            f"{self._index.line_numbers[k]} is no longer there): open the dataset again"
        )

    def owns(self, path: str | os.PathLike[str]) -> bool:
        """Whether ``path`` is one of this dataset's own files: ``rig.toml``, ``frames.jsonl``, the as-built
        files, anything in ``left/``, ``right/`` or ``truth/``, or a file a frame names. An output must
        never be written there (``estimate DATASET --out DATASET/frames.jsonl`` would destroy the index).
        Links are followed: a path that is the same file as one of those is owned too."""
        target = Path(path).resolve()
        root = self.root.resolve()
        if not target.is_relative_to(root):
            return any(_same_file(target, self.root / name) for name in _DATASET_MEMBERS)
        relative = target.relative_to(root)
        if relative.parts and relative.parts[0] in _DATASET_MEMBERS:
            return True
        if not target.exists():
            return False
        for frame in self:
            names = [frame.left, frame.right]
            if frame.truth is not None and frame.truth.markers is not None:
                names.append(frame.truth.markers)
            if any(_same_file(target, self.root / name) for name in names):
                return True
        return False

    @property
    def has_as_built(self) -> bool:
        """Whether the dataset stores the as-built jig it was simulated from."""
        return (self.root / AS_BUILT_NAME).is_file()

    def as_built(self) -> AsBuiltJig:
        """The as-built jig the images were rendered from (simulations only; for analysis, never for
        estimation).

        Raises
        ------
        InputError
            If the dataset is a recording (no ``as_built.toml``) or the files are unreadable.
        """
        from softjig.sim.asbuilt import AsBuiltJig

        toml_path, npz_path = self.root / AS_BUILT_NAME, self.root / AS_BUILT_MARKERS_NAME
        if not toml_path.is_file():
            raise InputError(
                f"{self.root} has no {AS_BUILT_NAME}: only simulated datasets store the as-built jig"
            )
        try:
            text = toml_path.read_text(encoding="utf-8")
        except (OSError, UnicodeDecodeError) as exc:
            raise InputError(f"cannot read {toml_path}: {exc}") from None
        jig = loads_jig(text, source=str(toml_path))
        if not npz_path.is_file():
            raise InputError(f"{npz_path} does not exist: the dataset is incomplete; re-simulate it")
        try:
            with np.load(npz_path, allow_pickle=False) as npz:
                xy = np.array(npz["marker_xy_mm"], dtype=float)
        except (OSError, ValueError, KeyError, EOFError) as exc:
            raise InputError(f"cannot read {npz_path}: {exc}") from None
        return AsBuiltJig(jig=jig, marker_xy_mm=xy)


def _index_frames(root: Path, frames_path: Path) -> tuple[_LineIndex, list[str]]:
    """Check every line of ``frames.jsonl`` in one streaming pass and keep where each frame starts.

    A line that is not JSON (garbage, a bad edit, the last line of a recorder killed mid-write) is skipped
    with a :class:`DatasetLineWarning` (:class:`DatasetTruncationWarning` for the last line), so one bad
    line costs one frame, not the dataset. A JSON line that is not a valid frame, or a frame index seen
    before, is an error naming the line: those are not accidents of a kill, and guessing which of two
    frames with one index is meant would give a wrong answer."""
    offsets, line_numbers, size = array("q"), array("q"), 0
    notes: list[str] = []
    skipped: list[tuple[str, Exception]] = []  # lines that are not JSON
    last_skipped = False  # whether the last non-blank line is one of them
    first_line: dict[int, int] = {}  # frame index -> the line it was first seen on
    pos = 0
    try:
        with open(frames_path, "rb") as fh:
            for n, raw in enumerate(fh, start=1):
                line_start, pos = pos, pos + len(raw)
                if not raw.strip():
                    continue
                where = f"{frames_path}, line {n}"
                try:
                    obj = json.loads(raw.decode("utf-8"))
                except (UnicodeDecodeError, json.JSONDecodeError) as exc:
                    skipped.append((where, exc))
                    last_skipped = True
                    continue
                last_skipped = False
                frame = _frame_from_json(root, obj, where)  # checked, then forgotten: parsed again when asked
                earlier = first_line.setdefault(frame.index, n)
                if earlier != n:
                    raise InputError(
                        f"{where}: frame index {frame.index} was already used on line {earlier}: every "
                        "frame needs its own index; fix or delete one of the two lines"
                    )
                offsets.append(line_start)
                line_numbers.append(n)
                size = pos
    except OSError as exc:
        raise InputError(f"cannot read {frames_path}: {exc}") from None
    index = _LineIndex(frames_path, offsets, line_numbers, size)
    if last_skipped:
        where, exc = skipped.pop()
        note = (
            f"{where}: the last line is cut short ({exc}), probably by a recorder killed "
            f"mid-write; skipped it and kept the {len(index)} complete frames"
        )
        warnings.warn(note, DatasetTruncationWarning, stacklevel=3)
        notes.append(note)
    if skipped:
        where, exc = skipped[0]
        more = f" and {len(skipped) - 1} more lines" if len(skipped) > 1 else ""
        note = (
            f"{where}{more}: not valid JSON ({exc}); skipped (fix or delete those lines to keep their "
            f"frames), kept the {len(index)} valid frames"
        )
        warnings.warn(note, DatasetLineWarning, stacklevel=3)
        notes.append(note)
    return index, notes


# ---------------------------------------------------------------------------------------- writer


def json_default(value: Any) -> Any:
    """``json.dumps``'s ``default`` for what frames and estimates hold: arrays and NumPy scalars as their
    values, paths in POSIX form."""
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, Path):
        return value.as_posix()
    raise TypeError(f"cannot write {type(value).__name__} as JSON")


def _truth_arrays(truth_markers: Any) -> dict[str, np.ndarray]:
    """The arrays to store from a mapping or an object with the :data:`TRUTH_MARKER_FIELDS` attributes."""
    names = (*TRUTH_MARKER_FIELDS, *_TRUTH_EXTRA_FIELDS)
    if isinstance(truth_markers, Mapping):
        arrays = {k: np.asarray(v) for k, v in truth_markers.items()}
    else:
        arrays = {
            k: np.asarray(getattr(truth_markers, k))
            for k in names
            if getattr(truth_markers, k, None) is not None
        }
    missing = [k for k in TRUTH_MARKER_FIELDS if k not in arrays]
    if missing:
        raise InputError(f"truth markers lack {', '.join(missing)}")
    return arrays


class DatasetWriter:
    """Write a dataset folder frame by frame (a context manager).

    Parameters
    ----------
    path : the dataset folder; created if missing.
    jig : the NOMINAL jig, written as ``rig.toml``.
    as_built : for simulations, the as-built jig the images come from (``as_built.toml`` and
        ``as_built_markers.npz``, for analysis only).
    overwrite : replace an existing dataset in ``path``. Without it a non-empty folder is refused. Even
        with it, only a dataset softjig *simulated* is replaced (:func:`is_simulation`: it holds its
        as-built jig): a recording (``live --record``, ``convert``, a user's own dataset) is never replaced,
        since it cannot be made again; a folder without both ``rig.toml`` and ``frames.jsonl``, or holding
        anything softjig does not write there (a calibration photo, a note: see :data:`WRITTEN_BESIDE`), is
        refused too, so a mistyped path never deletes unrelated files. The
        replacement is atomic: the new dataset is written beside the old one (``path`` +
        :data:`STAGING_SUFFIX`) and swapped in by :meth:`close`; until then, and if the writer is killed,
        the old dataset stays whole (the new frames written so far stay readable in the staging folder).
        Left by an exception, a simulation's (``durable=False``) staging folder is deleted, a recording's
        kept; a new dataset without any frame never replaces the old one.
    png_compression : zlib level of the PNGs (0-9; all lossless).
    durable : fsync every file and line (a recording survives a power cut); ``False`` keeps the writes
        atomic (a killed writer leaves only complete frames) without the disk waits, for data that can be
        regenerated (simulations).

    Examples
    --------
    >>> with DatasetWriter("out/rec", jig) as writer:                     # doctest: +SKIP
    ...     writer.add_frame(left, right, {"time_s": 0.0})
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        jig: JigConfig,
        *,
        as_built: AsBuiltJig | None = None,
        overwrite: bool = False,
        png_compression: int = PNG_COMPRESSION,
        durable: bool = True,
    ) -> None:
        self.root = Path(path)
        self.jig = jig
        self.as_built = as_built
        self.overwrite = overwrite
        self.durable = durable
        self.png_compression = int(png_compression)
        self._next_index = 0
        self._frames_fh: io.BufferedWriter | None = None
        self._dir = self.root  # where the files go: the staging folder while an overwrite is pending
        self._target = self.root  # the folder an overwrite replaces, resolved
        self._replacing = False

    # -- lifecycle
    def open(self) -> DatasetWriter:
        """Prepare the folder and write ``rig.toml`` (called by ``with``)."""
        if self._frames_fh is not None:
            return self
        final = self.root
        if final.exists() and not final.is_dir():
            raise InputError(f"{final} exists and is not a folder: choose another output folder")
        root = final
        if final.is_dir() and any(final.iterdir()):
            if not ((final / FRAMES_NAME).is_file() and (final / RIG_NAME).is_file()):
                raise InputError(
                    f"{final} is not empty and is not a softjig dataset (it lacks {FRAMES_NAME} or "
                    f"{RIG_NAME}): choose an empty or new output folder"
                )
            if not self.overwrite:
                raise InputError(
                    f"{final} already holds a dataset: choose another output folder or "
                    "overwrite it (--overwrite, or overwrite=True)"
                )
            if not is_simulation(final):
                raise InputError(
                    f"{final} holds a recording, not a dataset softjig simulated (it has no {AS_BUILT_NAME} "
                    f"and {AS_BUILT_MARKERS_NAME}, which softjig writes for simulations only): --overwrite "
                    "replaces only a simulation, never a recording (live --record, convert, your own "
                    f"dataset); choose another output folder, or move {final} away yourself first"
                )
            foreign = _foreign_entries(final)
            if foreign:
                shown = ", ".join(foreign[:5]) + (f" and {len(foreign) - 5} more" if len(foreign) > 5 else "")
                raise InputError(
                    f"{final} holds files softjig did not write ({shown}): overwriting would delete them; "
                    "move them out or choose another output folder"
                )
            target = final.resolve()  # a name to put "-new" / "-old" beside, even for "." or a link
            self._target = target
            root = target.with_name(target.name + STAGING_SUFFIX)
            for other in (root, target.with_name(target.name + RETIRED_SUFFIX)):
                if other.exists():
                    raise InputError(
                        f"{other} exists: an earlier overwrite of {final} did not finish (it may hold "
                        f"frames recorded then); look at it, then rename or delete it"
                    )
            self._replacing = True
        self._dir = root
        try:
            root.mkdir(parents=True, exist_ok=True)
            save_jig(self.jig, root / RIG_NAME)
            if self.as_built is not None:
                write_text_atomic(root / AS_BUILT_NAME, dumps_jig(self.as_built.jig))
                buf = io.BytesIO()
                np.savez(buf, marker_xy_mm=np.asarray(self.as_built.marker_xy_mm, dtype=float))
                write_bytes_atomic(root / AS_BUILT_MARKERS_NAME, buf.getvalue())
            for sub in ("left", "right"):
                (root / sub).mkdir(exist_ok=True)
            self._frames_fh = open(root / FRAMES_NAME, "ab")  # noqa: SIM115 - closed in close()
        except BaseException:
            if self._replacing:  # nothing recorded yet: the staging folder goes
                self._replacing = False
                shutil.rmtree(root, ignore_errors=True)
            raise
        return self

    def close(self) -> None:
        """Close ``frames.jsonl`` (called by ``with``); an overwrite is completed here: the new dataset
        replaces the old one."""
        if self._frames_fh is not None:
            self._frames_fh.close()
            self._frames_fh = None
        if self._replacing:
            if self._next_index == 0:  # replacing a dataset by an empty one would lose it for nothing
                self._abandon(keep=False)
                return
            self._replacing = False
            self._swap()

    def _swap(self) -> None:
        """Put the complete new dataset (the staging folder) in place of the old one: two renames, then the
        old one is deleted. A kill between the renames leaves both, under their suffixed names."""
        final, staging = self._target, self._dir
        retired = final.with_name(final.name + RETIRED_SUFFIX)
        try:
            os.rename(final, retired)
            try:
                os.rename(staging, final)
            except OSError:
                os.rename(retired, final)  # put the old one back
                raise
        except OSError as exc:
            raise InputError(
                f"cannot replace {final} by the new dataset {staging}: {exc.strerror or exc}; the new "
                "dataset is complete there"
            ) from None
        self._dir = self.root
        fsync_folder(final.parent)
        shutil.rmtree(retired, ignore_errors=True)

    def _abandon(self, *, keep: bool | None = None) -> None:
        """Left by an exception while overwriting: the old dataset stays; a simulation's staging folder is
        deleted, a recording's kept (its frames are readable there) unless it has none."""
        if self._frames_fh is not None:
            self._frames_fh.close()
            self._frames_fh = None
        if self._replacing:
            self._replacing = False
            if keep is None:
                keep = self.durable and self._next_index > 0
            if not keep:
                shutil.rmtree(self._dir, ignore_errors=True)
            self._dir = self.root

    def __enter__(self) -> DatasetWriter:
        return self.open()

    def __exit__(self, exc_type: type[BaseException] | None, *exc: object) -> None:
        if exc_type is None:
            self.close()
        else:
            self._abandon()

    @property
    def n_frames(self) -> int:
        """How many frames were added."""
        return self._next_index

    # -- frames
    def add_frame(
        self,
        left: np.ndarray | bytes,
        right: np.ndarray | bytes,
        meta: dict[str, Any] | None = None,
        truth_markers: Any = None,
    ) -> int:
        """Write one stereo frame and return its index.

        Parameters
        ----------
        left, right : ``uint8``/``uint16`` images, ``(H, W)`` or ``(H, W, 3)`` RGB; or PNG bytes from
            :func:`encode_png`.
        meta : the frame's JSON metadata (``time_s``, ``alpha_deg``, ``theta_deg``, ``part``, ``truth``,
            ``reference``, anything else JSON can hold; numpy values are converted). ``index``, ``left``
            and ``right`` are set by the writer.
        truth_markers : simulations: a mapping (or an object with those attributes, like the renderer's
            ``MarkerTruth``) holding :data:`TRUTH_MARKER_FIELDS`; stored as ``truth/NNNNNN.npz`` and
            named in ``meta["truth"]["markers"]``.
        """
        if self._frames_fh is None:
            self.open()
        assert self._frames_fh is not None
        meta = dict(meta or {})
        clash = [k for k in _RESERVED_KEYS if k in meta]
        if clash:
            raise InputError(f"frame metadata must not set {', '.join(clash)}: the writer sets them")
        index = self._next_index
        name = f"{index:06d}"
        record: dict[str, Any] = {"index": index, "left": f"left/{name}.png", "right": f"right/{name}.png"}
        record.update(meta)
        if truth_markers is not None:
            truth = dict(record.get("truth") or {})
            truth["markers"] = f"truth/{name}.npz"
            record["truth"] = truth
        try:
            line = json.dumps(record, default=json_default, allow_nan=False, separators=(",", ":"))
        except (TypeError, ValueError) as exc:
            raise InputError(f"frame {index}: metadata cannot be written as JSON: {exc}") from None
        arrays = None if truth_markers is None else _truth_arrays(truth_markers)
        # Files first, the line last: a frame is in frames.jsonl only once its files are complete.
        for side, image in (("left", left), ("right", right)):
            data = image if isinstance(image, bytes) else encode_png(image, compression=self.png_compression)
            write_bytes_atomic(self._dir / side / f"{name}.png", data, durable=self.durable)
        if arrays is not None:
            buf = io.BytesIO()
            np.savez(buf, **arrays)
            write_bytes_atomic(self._dir / "truth" / f"{name}.npz", buf.getvalue(), durable=self.durable)
        self._frames_fh.write(line.encode("utf-8") + b"\n")
        self._frames_fh.flush()
        if self.durable:
            os.fsync(self._frames_fh.fileno())
        self._next_index += 1
        return index
