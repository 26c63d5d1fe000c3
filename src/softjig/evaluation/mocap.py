"""Motion-capture ground truth: the paper's ``T_d = inv(T_j) T_o``, ``n_d = R_d z``, and OptiTrack Motive's
CSV export of rigid bodies.

The transform (pure)
--------------------
The mocap system gives the jig's rigid body pose ``T_j = T_mocap_jig`` and the object's ``T_o =
T_mocap_obj`` in its own frame; the object's pose relative to the jig is ``T_d = inv(T_j) @ T_o``
(``= T_jig_obj``) and its principal normal is ``n_d = R_d @ (0, 0, 1)`` (``DESIGN.md`` §1). The mocap's
global frame (Motive's is y-up) cancels out. This assumes, as the paper does, that the jig's rigid body
frame is the jig frame J and that the object's rigid body ``z`` axis is its bottom face's normal; when
they are not, pass ``T_jigbody_J`` (J's pose in the jig's rigid-body frame, e.g. from the fiducials'
known positions) and ``object_axis`` (the bottom face's normal in the object's rigid-body frame).

Motive's CSV export (I/O)
-------------------------
As documented by OptiTrack ("Data Export: CSV") and written by Motive 2.x/3.x with the header enabled::

    Format Version,1.23,Take Name,...,Rotation Type,Quaternion,Length Units,Millimeters,...
    <blank line>
    ,Type,Rigid Body,Rigid Body,...          asset types (also Rigid Body Marker, Marker, Bone, ...)
    ,Name,jig,jig,...                         asset names
    ,ID,1,1,...                               asset IDs (later versions may add a Parent row)
    ,,Rotation,Rotation,Rotation,Rotation,Position,Position,Position,Mean Marker Error,...
    Frame,Time (Seconds),X,Y,Z,W,X,Y,Z,,...
    0,0.000000,0.01,...                       one line per frame; occluded values are empty cells

Rigid bodies have rotation ``X, Y, Z, W`` (a unit quaternion, scalar last) when exported with
``Rotation Type = Quaternion``, and ``Position X, Y, Z`` in the ``Length Units`` of the header (meters,
centimeters or millimeters; converted to mm here). Other columns (markers, marker quality) are ignored.
"""

from __future__ import annotations

import csv
import io
import math
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from softjig.errors import InputError
from softjig.files import write_text_atomic
from softjig.geometry import invert_pose

__all__ = [
    "MotiveTake",
    "RigidBodyTrack",
    "mocap_normals",
    "motive_csv_text",
    "normals_at",
    "parse_motive_csv",
    "pose_from_quaternion_xyzw",
    "read_motive_csv",
    "relative_poses",
    "write_motive_csv",
]

_UNITS_TO_MM = {"meters": 1000.0, "centimeters": 10.0, "millimeters": 1.0}
_HEADER_LABELS = ("Type", "Name", "ID", "Parent")
_Z = np.array([0.0, 0.0, 1.0])


# ---------------------------------------------------------------------------------- the transform


def _check_poses(T: np.ndarray, name: str) -> np.ndarray:
    T = np.asarray(T, dtype=float)
    if T.shape[-2:] != (4, 4) or T.ndim not in (2, 3):
        raise InputError(f"{name} must be a 4x4 pose or (n, 4, 4) poses, got shape {T.shape}")
    return T


def relative_poses(T_mocap_jig: np.ndarray, T_mocap_obj: np.ndarray) -> np.ndarray:
    """The paper's ``T_d = inv(T_j) @ T_o``: the object's pose in the jig's rigid-body frame.

    Parameters
    ----------
    T_mocap_jig, T_mocap_obj : (4, 4) or (n, 4, 4) rigid poses of the jig and the object in the mocap
        frame (mm). NaN poses (untracked frames) give NaN.

    Returns
    -------
    np.ndarray
        ``T_jig_obj``, shaped like the broadcast inputs.
    """
    Tj, To = _check_poses(T_mocap_jig, "T_mocap_jig"), _check_poses(T_mocap_obj, "T_mocap_obj")
    if Tj.ndim == 2 and To.ndim == 2:
        return invert_pose(Tj) @ To
    Tj, To = np.broadcast_arrays(Tj.reshape(-1, 4, 4), To.reshape(-1, 4, 4))
    return np.array([invert_pose(a) @ b for a, b in zip(Tj, To, strict=True)])


def mocap_normals(
    T_mocap_jig: np.ndarray,
    T_mocap_obj: np.ndarray,
    *,
    T_jigbody_J: np.ndarray | None = None,
    object_axis: Sequence[float] = (0.0, 0.0, 1.0),
) -> np.ndarray:
    """The object's principal normal in J from mocap poses: ``n_d = R_d @ z`` (``DESIGN.md`` §1).

    Parameters
    ----------
    T_mocap_jig, T_mocap_obj : (4, 4) or (n, 4, 4) poses of the jig's and the object's rigid bodies.
    T_jigbody_J : (4, 4) the jig frame J's pose in the jig's rigid-body frame; identity (the paper's
        assumption) by default. With it, ``n_J = R_J_jigbody @ R_d @ axis``.
    object_axis : the object's bottom-face normal in its rigid-body frame, ``z`` by default.

    Returns
    -------
    np.ndarray
        (3,) or (n, 3) unit normals in J.
    """
    T_d = relative_poses(T_mocap_jig, T_mocap_obj)
    axis = np.asarray(object_axis, dtype=float)
    if axis.shape != (3,) or not np.isfinite(axis).all() or np.linalg.norm(axis) == 0:
        raise InputError(f"object_axis must be a non-zero 3-vector, got {object_axis!r}")
    axis = axis / np.linalg.norm(axis)
    n = T_d[..., :3, :3] @ axis
    if T_jigbody_J is not None:
        T = _check_poses(T_jigbody_J, "T_jigbody_J")
        if T.ndim != 2:
            raise InputError("T_jigbody_J must be one 4x4 pose")
        n = n @ invert_pose(T)[:3, :3].T
    return n


def pose_from_quaternion_xyzw(quaternion_xyzw: np.ndarray, position_mm: np.ndarray) -> np.ndarray:
    """(n, 4, 4) poses from (n, 4) quaternions ``(x, y, z, w)`` and (n, 3) positions (mm); rows with any
    NaN (untracked) give all-NaN poses. Quaternions are normalised."""
    q = np.atleast_2d(np.asarray(quaternion_xyzw, dtype=float))
    p = np.atleast_2d(np.asarray(position_mm, dtype=float))
    if q.shape[1:] != (4,) or p.shape[1:] != (3,) or len(q) != len(p):
        raise InputError(f"need (n, 4) quaternions and (n, 3) positions, got {q.shape} and {p.shape}")
    T = np.full((len(q), 4, 4), np.nan)
    ok = np.isfinite(q).all(axis=1) & np.isfinite(p).all(axis=1) & (np.linalg.norm(q, axis=1) > 0)
    if ok.any():
        T[ok] = np.eye(4)
        T[ok, :3, :3] = Rotation.from_quat(q[ok]).as_matrix()
        T[ok, :3, 3] = p[ok]
    return T


# --------------------------------------------------------------------------------- Motive's CSV


@dataclass(frozen=True, eq=False)
class RigidBodyTrack:
    """One rigid body of a Motive take.

    Attributes
    ----------
    name, id : the asset's name and ID.
    quaternion_xyzw : (n, 4) orientation per frame, NaN where untracked.
    position_mm : (n, 3) position per frame (mm), NaN where untracked.
    mean_marker_error_mm : (n,) Motive's mean marker error (mm), or ``None`` if not exported.
    """

    name: str
    id: str
    quaternion_xyzw: np.ndarray
    position_mm: np.ndarray
    mean_marker_error_mm: np.ndarray | None = None

    @property
    def tracked(self) -> np.ndarray:
        """(n,) whether the body was tracked in each frame."""
        return np.isfinite(self.quaternion_xyzw).all(axis=1) & np.isfinite(self.position_mm).all(axis=1)

    def poses(self) -> np.ndarray:
        """(n, 4, 4) poses in the mocap frame (mm), all-NaN where untracked."""
        return pose_from_quaternion_xyzw(self.quaternion_xyzw, self.position_mm)


@dataclass(frozen=True, eq=False)
class MotiveTake:
    """A Motive CSV export's rigid bodies.

    Attributes
    ----------
    metadata : the first line's key/value pairs (``Format Version``, ``Take Name``, ``Length Units``...).
    frame : (n,) Motive's frame numbers.
    time_s : (n,) time of each frame (s).
    bodies : the rigid bodies by name.
    """

    metadata: dict[str, str]
    frame: np.ndarray
    time_s: np.ndarray
    bodies: dict[str, RigidBodyTrack]

    def body(self, name: str) -> RigidBodyTrack:
        """A rigid body by name; :class:`InputError` listing the names there are."""
        if name not in self.bodies:
            raise InputError(
                f"the take has no rigid body {name!r}; it has: {', '.join(self.bodies) or 'none'}"
            )
        return self.bodies[name]


def _cell_float(text: str, where: str) -> float:
    text = text.strip()
    if not text:
        return math.nan
    try:
        return float(text)
    except ValueError:
        raise InputError(f"{where}: {text!r} is not a number") from None


def parse_motive_csv(text: str, *, source: str = "Motive CSV") -> MotiveTake:
    """Parse the text of a Motive CSV export (see the module docstring) into its rigid bodies.

    Raises
    ------
    InputError
        No header (export with "Header information" on), Euler rotations (export with
        Rotation Type = Quaternion), unknown length units, missing rows, or a value that is not a number.
    """
    lines = list(csv.reader(io.StringIO(text.lstrip("\ufeff"))))
    if not lines or not lines[0] or lines[0][0].strip() != "Format Version":
        raise InputError(
            f"{source}: the first line is not Motive's header ('Format Version,...'): export the take from "
            "Motive as CSV with 'Header information' enabled"
        )
    first = [c.strip() for c in lines[0]]
    metadata = {first[k]: first[k + 1] for k in range(0, len(first) - 1, 2) if first[k]}
    rotation = metadata.get("Rotation Type", "Quaternion")
    if rotation.lower() != "quaternion":
        raise InputError(
            f"{source}: rotations are exported as {rotation!r}; export again with Rotation Type = Quaternion"
        )
    units = metadata.get("Length Units", "Meters")
    if units.lower() not in _UNITS_TO_MM:
        raise InputError(
            f"{source}: unknown Length Units {units!r} (expected Meters, Centimeters, Millimeters)"
        )
    to_mm = _UNITS_TO_MM[units.lower()]
    try:
        axis_row = next(k for k, row in enumerate(lines) if row and row[0].strip() == "Frame")
    except StopIteration:
        raise InputError(
            f"{source}: no 'Frame,Time (Seconds),...' row: is this a Motive CSV export?"
        ) from None
    labelled: dict[str, list[str]] = {}
    for row in lines[1 : axis_row - 1]:
        label = (row[0].strip() or (row[1].strip() if len(row) > 1 else "")) if row else ""
        if label in _HEADER_LABELS:
            labelled[label] = row
    if axis_row < 2 or "Type" not in labelled or "Name" not in labelled:
        raise InputError(f"{source}: the 'Type' and 'Name' header rows are missing above the 'Frame' row")
    component, axes = lines[axis_row - 1], lines[axis_row]
    width = len(axes)

    def cell(row: list[str], k: int) -> str:
        return row[k].strip() if k < len(row) else ""

    # Columns of each rigid body: (name) -> {"id", (component, axis) -> column}
    columns: dict[str, dict] = {}
    for k in range(2, width):
        if cell(labelled["Type"], k) != "Rigid Body":
            continue
        name = cell(labelled["Name"], k)
        entry = columns.setdefault(name, {"id": cell(labelled.get("ID", []), k)})
        entry[(cell(component, k), cell(axes, k))] = k
    data = [row for row in lines[axis_row + 1 :] if row and any(c.strip() for c in row)]
    n = len(data)
    frame = np.zeros(n, dtype=int)
    time_s = np.full(n, np.nan)
    values = np.full((n, width), np.nan)
    for i, row in enumerate(data):
        where = f"{source}, data line {i + 1}"
        try:
            frame[i] = int(row[0])
        except ValueError:
            raise InputError(f"{where}: frame number {row[0]!r} is not an integer") from None
        time_s[i] = _cell_float(cell(row, 1), where)
        for name, entry in columns.items():
            for key, k in entry.items():
                if key != "id":
                    values[i, k] = _cell_float(cell(row, k), f"{where}, {name} {key[0]} {key[1]}")
    bodies: dict[str, RigidBodyTrack] = {}
    for name, entry in columns.items():
        need = [("Rotation", a) for a in "XYZW"] + [("Position", a) for a in "XYZ"]
        missing = [f"{c} {a}" for c, a in need if (c, a) not in entry]
        if missing:
            raise InputError(f"{source}: rigid body {name!r} lacks the columns {', '.join(missing)}")
        q = values[:, [entry[("Rotation", a)] for a in "XYZW"]]
        p = values[:, [entry[("Position", a)] for a in "XYZ"]] * to_mm
        err_col = next((k for key, k in entry.items() if key != "id" and key[0] == "Mean Marker Error"), None)
        err = None if err_col is None else values[:, err_col] * to_mm
        bodies[name] = RigidBodyTrack(name, entry["id"], q, p, err)
    if not bodies:
        raise InputError(f"{source}: no rigid body: export with 'Rigid Bodies' enabled")
    return MotiveTake(metadata, frame, time_s, bodies)


def read_motive_csv(path: str | os.PathLike[str]) -> MotiveTake:
    """Read a Motive CSV export (see :func:`parse_motive_csv`)."""
    from softjig.files import read_text_file

    text = read_text_file(path, "Motive CSV", encoding="utf-8-sig")
    return parse_motive_csv(text, source=str(path))


def motive_csv_text(
    poses_mm: Mapping[str, np.ndarray],
    *,
    frame_rate_hz: float = 120.0,
    units: str = "Millimeters",
    take_name: str = "softjig",
) -> str:
    """A Motive-layout CSV (rigid bodies, quaternions, with mean marker error 0) of (n, 4, 4) poses (mm)
    per body name; NaN poses are written as empty (occluded) cells. For tests and simulated mocap."""
    if units.lower() not in _UNITS_TO_MM:
        raise InputError(f"unknown units {units!r} (Meters, Centimeters, Millimeters)")
    scale = 1.0 / _UNITS_TO_MM[units.lower()]
    names = list(poses_mm)
    arrays = [_check_poses(poses_mm[name], name).reshape(-1, 4, 4) for name in names]
    n = len(arrays[0]) if arrays else 0
    if any(len(a) != n for a in arrays):
        raise InputError("every rigid body needs one pose per frame")
    head = (
        f"Format Version,1.23,Take Name,{take_name},Capture Frame Rate,{frame_rate_hz:.6f},"
        f"Export Frame Rate,{frame_rate_hz:.6f},Capture Start Time,2024-01-01 12.00.00.000 PM,"
        f"Total Frames in Take,{n},Total Exported Frames,{n},Rotation Type,Quaternion,"
        f"Length Units,{units},Coordinate Space,Global"
    )
    types, labels, ids, comps, axes = [",Type"], [",Name"], [",ID"], [","], ["Frame,Time (Seconds)"]
    for k, name in enumerate(names):
        types.append(",".join(["Rigid Body"] * 8))
        labels.append(",".join([name] * 8))
        ids.append(",".join([str(k + 1)] * 8))
        comps.append(",".join(["Rotation"] * 4 + ["Position"] * 3 + ["Mean Marker Error"]))
        axes.append("X,Y,Z,W,X,Y,Z,")
    out = [head, "", ",".join(types), ",".join(labels), ",".join(ids), ",".join(comps), ",".join(axes)]
    for i in range(n):
        cells = [str(i), f"{i / frame_rate_hz:.6f}"]
        for T in arrays:
            if not np.isfinite(T[i]).all():
                cells += [""] * 8
                continue
            q = Rotation.from_matrix(T[i, :3, :3]).as_quat()
            cells += [f"{v:.9f}" for v in q] + [f"{v * scale:.9f}" for v in T[i, :3, 3]] + ["0.000000"]
        out.append(",".join(cells))
    return "\n".join(out) + "\n"


def write_motive_csv(path: str | os.PathLike[str], poses_mm: Mapping[str, np.ndarray], **kwargs) -> None:
    """Write :func:`motive_csv_text` atomically."""
    write_text_atomic(path, motive_csv_text(poses_mm, **kwargs))


def normals_at(
    take: MotiveTake,
    *,
    jig_body: str,
    object_body: str,
    frames: Sequence[int] | np.ndarray | None = None,
    times_s: Sequence[float] | np.ndarray | None = None,
    max_dt_s: float | None = None,
    T_jigbody_J: np.ndarray | None = None,
    object_axis: Sequence[float] = (0.0, 0.0, 1.0),
) -> np.ndarray:
    """The mocap's normals in J (:func:`mocap_normals`) at given Motive frame numbers or times.

    Parameters
    ----------
    take : the imported take.
    jig_body, object_body : the names of the jig's and the object's rigid bodies.
    frames : (n,) Motive frame numbers to look up (exact match), or
    times_s : (n,) times (s, on the take's clock) matched to the nearest sample, within ``max_dt_s``
        (default: one and a half sample periods).
    T_jigbody_J, object_axis : see :func:`mocap_normals`.

    Returns
    -------
    np.ndarray
        (n, 3) unit normals in J; NaN rows where a body was untracked or nothing matched.
    """
    if (frames is None) == (times_s is None):
        raise InputError("give either Motive frame numbers or times to look the mocap up at")
    T_j, T_o = take.body(jig_body).poses(), take.body(object_body).poses()
    if frames is not None:
        wanted = np.asarray(frames, dtype=int)
        lookup = {int(f): k for k, f in enumerate(take.frame)}
        rows = np.array([lookup.get(int(f), -1) for f in wanted], dtype=int)
    else:
        t = np.asarray(times_s, dtype=float)
        if len(take.time_s) == 0:
            rows = np.full(len(t), -1)
        else:
            order = np.argsort(take.time_s)
            ts = take.time_s[order]
            pos = np.clip(np.searchsorted(ts, t), 1, max(len(ts) - 1, 1))
            left = np.clip(pos - 1, 0, len(ts) - 1)
            right = np.clip(pos, 0, len(ts) - 1)
            nearest = np.where(np.abs(ts[left] - t) <= np.abs(ts[right] - t), left, right)
            if max_dt_s is None:
                period = float(np.median(np.diff(ts))) if len(ts) > 1 else np.inf
                max_dt_s = 1.5 * period
            rows = np.where(np.abs(ts[nearest] - t) <= max_dt_s, order[nearest], -1)
    out = np.full((len(rows), 3), np.nan)
    ok = rows >= 0
    if ok.any():
        out[ok] = mocap_normals(
            T_j[rows[ok]], T_o[rows[ok]], T_jigbody_J=T_jigbody_J, object_axis=object_axis
        )
    return out
