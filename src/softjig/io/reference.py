"""Choosing the unloaded reference a refractive estimate measures its indentations against.

The refractive method measures how far each marker lies below the unloaded membrane: the jig's own
unloaded frame (a *reference frame*) when there is one, else the nominal rest shape. The reference frame
is more accurate (it holds the jig as built, not as drawn), so every command that estimates takes it the
same way, from here:

- a dataset's first frame marked ``reference`` (:func:`dataset_reference`: ``softjig estimate DATASET``,
  a replay in ``softjig live``/``serve``), or the reference frame of another dataset of the same rig;
- a stereo pair of the unloaded jig (:func:`reference_from_pair`: ``--reference-left/--reference-right``,
  the ``reference`` request of ``softjig serve``).

Either is checked like ``softjig survey`` checks its frame: refused when a part seems pressed in
(:func:`softjig.sensing.survey.check_unloaded`), or when too few of its markers are the rig's; a
recorder's mark is not taken on trust.

A reference of another rig (other cameras' resolution, another marker layout) is refused: its markers
would be compared with markers they are not.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np

from softjig.config import JigConfig
from softjig.errors import EstimationError, InputError
from softjig.jig_shape import rest_marker_points_mm
from softjig.sensing.identities import ReferenceMarkers, identify_markers, rest_shape_reference
from softjig.sensing.survey import check_unloaded, min_matched_markers

if TYPE_CHECKING:
    from softjig.io.dataset import Dataset
    from softjig.sensing.estimator import Estimator

__all__ = [
    "REFERENCE_FRAME",
    "REST_SHAPE",
    "check_same_rig",
    "dataset_reference",
    "recorded_reference",
    "reference_from_pair",
    "reference_source",
]

#: What an estimate says its indentations were measured against (``indentation_reference``).
REFERENCE_FRAME = "reference frame"
REST_SHAPE = "rest shape"


def reference_source(reference: ReferenceMarkers | None) -> str:
    """``"reference frame"`` or ``"rest shape"`` (``None``: the estimator's default, the rest shape)."""
    return REST_SHAPE if reference is None else reference.source


def check_same_rig(reference_jig: JigConfig, jig: JigConfig, where: str) -> None:
    """Refuse a reference recorded on another rig than ``jig``: other image sizes, or another number of
    markers (of two drawn layouts: a surveyed one, ``markers.centers_mm``, holds only the markers seen).

    Raises
    ------
    InputError
        Naming what differs and what to do.
    """
    ref_cam, cam = reference_jig.cameras.left, jig.cameras.left
    if (ref_cam.width_px, ref_cam.height_px) != (cam.width_px, cam.height_px):
        raise InputError(
            f"{where} was recorded with {ref_cam.width_px}x{ref_cam.height_px} px cameras but the config's "
            f"are {cam.width_px}x{cam.height_px}: take the reference frame of this rig"
        )
    if reference_jig.markers.centers_mm or jig.markers.centers_mm:
        return  # a surveyed layout (explicit, of the markers seen) counts fewer markers than its drawing
    n_ref, n = len(rest_marker_points_mm(reference_jig)), len(rest_marker_points_mm(jig))
    if n_ref != n:
        raise InputError(
            f"{where} was recorded on a rig of {n_ref} markers but the config's has {n}: take the reference "
            "frame of this rig"
        )


def check_unloaded_reference(reference: ReferenceMarkers, jig: JigConfig, where: str) -> None:
    """Refuse a reference whose markers are not the rig's, or that a part pushes in.

    Its markers are matched to the nominal rest shape within half a pitch (too few matched: another rig,
    or not the jig at all), then checked for a compact dent as ``softjig survey`` checks its frame.

    Raises
    ------
    InputError
        Too few markers of the rig, or a loaded frame (the dent's place and depth named).
    """
    nominal = rest_shape_reference(jig)
    points = reference.xyz_mm
    ids = identify_markers(points, nominal, max_lateral_mm=jig.markers.pitch_mm / 2.0).ids
    known = ids >= 0
    if known.sum() < min_matched_markers(jig, len(nominal.xyz_mm)):
        raise InputError(
            f"{where}: only {int(known.sum())} of its {len(points)} markers lie within half a pitch of one "
            f"of the rig's {len(nominal)}: is it a pair of the unloaded jig, taken by the cameras of this "
            "rig.toml?"
        )
    matched = points[known]
    dent = check_unloaded(matched, nominal.xyz_mm[ids[known], 2], jig)
    if dent.loaded:
        centre = matched[dent.dented, :2].mean(axis=0)
        raise InputError(
            f"{where} is loaded: {int(dent.dented.sum())} neighbouring markers around ({centre[0]:.0f}, "
            f"{centre[1]:.0f}) mm are pushed in by up to {dent.residual_mm.max():.1f} mm (noise "
            f"{dent.sigma_mm:.2f} mm, threshold {dent.threshold_mm:.2f} mm): a part is pressed onto the jig. "
            "Take the reference while the jig is empty and released"
        )


def reference_from_pair(
    left: np.ndarray,
    right: np.ndarray,
    jig: JigConfig,
    *,
    estimator: Estimator | None = None,
    where: str = "the reference pair",
) -> ReferenceMarkers:
    """The reference markers of a stereo pair of the unloaded jig, checked (see the module docstring).

    Parameters
    ----------
    left, right : the pair's images, of the config's cameras.
    jig : the nominal jig of the cameras.
    estimator : an estimator of ``jig`` whose model to share (none: one is built).
    where : how messages name the pair.

    Raises
    ------
    InputError
        Images of other cameras (size), too few of the rig's markers, or a loaded pair.
    """
    from softjig.sensing.estimator import Estimator

    probe = Estimator(jig) if estimator is None else estimator.with_reference(None)
    try:
        reference = probe.reference_from_pair(left, right)
    except EstimationError as exc:
        raise InputError(f"{where}: {exc}") from None
    except InputError as exc:
        raise InputError(f"{where}: {exc}") from None
    check_unloaded_reference(reference, probe.jig, where)
    return reference


def dataset_reference(
    dataset: Dataset, jig: JigConfig, *, estimator: Estimator | None = None
) -> ReferenceMarkers | None:
    """The reference markers from the dataset's first frame marked ``reference``, checked, if it has one.

    A recorder marks the frame (``"reference": true``), but nothing proves the jig was empty then: the
    frame is checked as a pair given by hand is (:func:`reference_from_pair`, as ``softjig survey`` and
    serve's ``reference`` request check theirs), so a loaded or unusable frame is refused instead of
    silently shifting every indentation measured against it. ``softjig estimate DATASET`` and a replay of
    the dataset take it from here alike, so they agree.

    Parameters
    ----------
    dataset : the dataset (its ``rig.toml`` must be of the rig of ``jig``).
    jig : the nominal jig the estimates use (``--config``, or the dataset's own).
    estimator : an estimator of ``jig`` whose model to share.

    Raises
    ------
    InputError
        The dataset is of another rig (:func:`check_same_rig`), or its reference frame is unreadable, not
        of the rig's markers, or loaded; the message names the frame and offers ``--no-reference``.
    """
    check_same_rig(dataset.jig, jig, f"the reference frame of {dataset.root}")
    for frame in dataset:
        if frame.reference:
            where = f"frame {frame.index} of {dataset.root} (marked reference)"
            return recorded_reference(frame.load_left, frame.load_right, jig, where, estimator=estimator)
    return None


def recorded_reference(
    load_left: Callable[[], np.ndarray],
    load_right: Callable[[], np.ndarray],
    jig: JigConfig,
    where: str,
    *,
    estimator: Estimator | None = None,
) -> ReferenceMarkers:
    """The reference markers of a frame a recorder marked ``reference`` (a dataset's, a bag's), loaded
    and checked as :func:`reference_from_pair` checks a pair given by hand.

    Raises
    ------
    InputError
        The frame is unreadable, not of the rig's markers, or loaded: ``where`` names it, and the message
        offers ``--no-reference``.
    """
    try:
        return reference_from_pair(load_left(), load_right(), jig, estimator=estimator, where=where)
    except InputError as exc:
        text = str(exc).rstrip(".")
        message = text if text.startswith(where) else f"{where}: {text}"
        message += "" if message.endswith("?") else "."
        raise InputError(
            f"{message} The indentations would be measured against a wrong reference: fix or unmark that "
            'frame ("reference": true), or estimate against the nominal rest shape with --no-reference'
        ) from None
