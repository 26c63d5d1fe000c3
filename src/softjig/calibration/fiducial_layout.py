"""The fiducials a user prints and sticks on the base plate: a sheet at exact scale, and a check.

The sheet (:func:`fiducial_sheet`) shows the whole plate at 1:1 **as the cameras see it from below**
(``DESIGN.md`` §1: image ``x`` along J's ``+x``, image ``y`` along J's ``+y``): print it at 100 % (no
"fit to page"), check the 100 mm scale bar with a ruler, and fix it under the plate with the printed side
facing the cameras, its ``+x`` arrow along the stereo baseline (from the left camera to the right one)
and its cross on the jig axis, then cut out each marker with its white border and stick it where it is
drawn (paper over the whole plate would hide the membrane; or print on transparent film).
Each marker is drawn exactly where ``fiducials.centers_mm`` puts it,
``fiducials.size_mm`` wide (its own black border included), in the orientation
:func:`softjig.sensing.fiducials.fiducial_corners_J` assumes, with the white quiet zone around it that
the paper stays clear of. The page is the plate plus a margin (a 220 mm plate needs A3; the PDF's page
size is exact, so any printer at 100 % gives the right scale). Drawing uses matplotlib's object API
(no pyplot, no windows).

The check (:func:`check_fiducials`) finds the fiducials in a stereo pair, measures the stereo head's
pose from them (:func:`softjig.sensing.jigframe.jig_frame_from_fiducials`) and reports each one's
reprojection error: a fiducial stuck in the wrong place, or the wrong id, stands out.
"""

from __future__ import annotations

import io
from dataclasses import dataclass
from typing import Literal

import cv2
import numpy as np

from softjig.aruco import aruco_dictionary
from softjig.config import FiducialConfig, JigConfig
from softjig.geometry import invert_pose
from softjig.sensing.fiducials import detect_fiducials, fiducial_corners_J

__all__ = ["FiducialCheck", "check_fiducials", "fiducial_sheet", "projected_fiducials", "with_fiducials"]

MM_PER_INCH = 25.4


def with_fiducials(
    jig: JigConfig,
    *,
    ids: tuple[int, ...] | None = None,
    centers_mm: tuple[tuple[float, float], ...] | None = None,
    size_mm: float | None = None,
    dictionary: str | None = None,
) -> JigConfig:
    """``jig`` with its fiducial layout changed where given (validated: ConfigError names the field)."""
    f = jig.fiducials
    new = FiducialConfig(
        dictionary=dictionary or f.dictionary,
        ids=tuple(ids) if ids is not None else f.ids,
        centers_mm=tuple(tuple(c) for c in centers_mm) if centers_mm is not None else f.centers_mm,  # type: ignore[misc]
        size_mm=size_mm if size_mm is not None else f.size_mm,
        z_mm=f.z_mm,
    )
    return jig.replace(fiducials=new)


def projected_fiducials(jig: JigConfig) -> dict[str, np.ndarray]:
    """Where each fiducial's corners fall in each camera per the config
    (``{"left": (M, 4, 2), "right": ...}``,
    px, with distortion) and whether each one lies wholly inside that image (``"left_inside"``, ...)."""
    corners = fiducial_corners_J(jig.fiducials).reshape(-1, 3)
    out: dict[str, np.ndarray] = {}
    for side in ("left", "right"):
        cam = getattr(jig.cameras, side)
        T = invert_pose(cam.T_J_cam)
        rvec, _ = cv2.Rodrigues(T[:3, :3])
        px, _ = cv2.projectPoints(corners, rvec, T[:3, 3], cam.K, np.asarray(cam.distortion, float))
        quads = px.reshape(-1, 4, 2)
        out[side] = quads
        inside = (quads[..., 0] >= 0) & (quads[..., 0] <= cam.width_px - 1)
        inside &= (quads[..., 1] >= 0) & (quads[..., 1] <= cam.height_px - 1)
        out[f"{side}_inside"] = inside.all(axis=1)
    return out


def fiducial_sheet(
    jig: JigConfig, *, fmt: Literal["png", "pdf"] = "pdf", dpi: int = 600, margin_mm: float = 12.0
) -> bytes:
    """The printable sheet (module docstring) as PNG or PDF bytes, at exact scale.

    Parameters
    ----------
    jig : the jig (plate size, membrane footprint, fiducial layout).
    fmt : ``"pdf"`` (vector, exact page size) or ``"png"`` (``dpi`` pixels per inch, stored in the file).
    dpi : resolution of the PNG (and of the markers' raster in the PDF, which is drawn without smoothing).
    margin_mm : white margin around the plate (mm).
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    from matplotlib.patches import Circle, FancyArrow, Rectangle

    p, f = jig.plate, jig.fiducials
    w_mm, h_mm = p.size_x_mm + 2 * margin_mm, p.size_y_mm + 2 * margin_mm
    fig = Figure(figsize=(w_mm / MM_PER_INCH, h_mm / MM_PER_INCH), dpi=dpi)
    FigureCanvasAgg(fig)
    ax = fig.add_axes((0.0, 0.0, 1.0, 1.0))
    ax.set_axis_off()
    ax.set_xlim(-w_mm / 2, w_mm / 2)
    ax.set_ylim(h_mm / 2, -h_mm / 2)  # +y downwards: the cameras' view (image y along J's +y)
    ax.set_aspect("equal")
    line = {"color": "0.55", "linewidth": 0.3}
    ax.add_patch(
        Rectangle((-p.size_x_mm / 2, -p.size_y_mm / 2), p.size_x_mm, p.size_y_mm, fill=False, **line)
    )
    ax.add_patch(Circle((0, 0), jig.membrane.footprint_radius_mm, fill=False, linestyle="--", **line))
    ax.plot([-5, 5], [0, 0], **line)
    ax.plot([0, 0], [-5, 5], **line)
    ax.add_patch(FancyArrow(8, 0, 18, 0, width=0.4, head_width=2.5, head_length=3, color="0.3"))
    ax.add_patch(FancyArrow(0, 8, 0, 18, width=0.4, head_width=2.5, head_length=3, color="0.3"))
    text = {"fontsize": 6, "color": "0.25"}
    ax.text(30, 0, "+x (left camera → right camera)", va="center", **text)
    ax.text(0, 31, "+y", ha="center", va="top", **text)
    d = aruco_dictionary(f.dictionary)
    cells = d.markerSize + 2
    half = f.size_mm / 2
    for marker_id, (cx, cy) in zip(f.ids, f.centers_mm, strict=True):
        img = cv2.aruco.generateImageMarker(d, int(marker_id), cells, borderBits=1)
        ax.imshow(
            img,
            cmap="gray",
            vmin=0,
            vmax=255,
            interpolation="nearest",
            resample=False,
            extent=(cx - half, cx + half, cy + half, cy - half),
            zorder=3,
        )
        ax.text(
            cx,
            cy + half * (1 + 2 / cells) + 2.0,
            f"id {marker_id}  ({cx:g}, {cy:g}) mm",
            ha="center",
            va="top",
            **text,
        )
    # the 100 mm scale bar, along the bottom margin
    y_bar = p.size_y_mm / 2 + margin_mm * 0.45
    ax.plot([-50, 50], [y_bar, y_bar], color="black", linewidth=0.8)
    for x in (-50, 50):
        ax.plot([x, x], [y_bar - 1.5, y_bar + 1.5], color="black", linewidth=0.8)
    ax.text(0, y_bar - 1.0, "100 mm: check with a ruler", ha="center", va="bottom", **text)
    ax.text(
        -w_mm / 2 + 3,
        -h_mm / 2 + 3,
        f"softjig fiducials {f.dictionary}, {f.size_mm:g} mm, on the plate's bottom face "
        f"(z = {f.z_mm:g} mm). "
        "Print at 100 % (no scaling). This is the view from the cameras. Cut out each marker with its white "
        "border and stick it printed side down where it is drawn (use the sheet as a template).",
        va="top",
        **text,
    )
    buf = io.BytesIO()
    fig.savefig(buf, format=fmt, dpi=dpi, facecolor="white")
    return buf.getvalue()


@dataclass(frozen=True)
class FiducialCheck:
    """What a stereo pair says about the fiducials.

    Attributes
    ----------
    found_left, found_right : ids found in each image.
    missing : configured ids found in neither image.
    reprojection_rms_px : RMS reprojection error of every corner found, with the pose measured from them
        all (``nan`` if too few were found to measure it).
    per_fiducial_rms_px : ``{id: rms}`` of each fiducial's corners (both images).
    T_J_left : (4, 4) the left camera's pose measured (``None`` if not measured).
    ok : every configured fiducial found in at least one image and the RMS below the limit.
    problems : what is wrong, in words a user can act on.
    """

    found_left: tuple[int, ...]
    found_right: tuple[int, ...]
    missing: tuple[int, ...]
    reprojection_rms_px: float
    per_fiducial_rms_px: dict[int, float]
    T_J_left: np.ndarray | None
    ok: bool
    problems: tuple[str, ...]

    def to_dict(self) -> dict:
        """JSON form."""
        return {
            "ok": self.ok,
            "found_left": list(self.found_left),
            "found_right": list(self.found_right),
            "missing": list(self.missing),
            "reprojection_rms_px": self.reprojection_rms_px,
            "per_fiducial_rms_px": {str(k): v for k, v in self.per_fiducial_rms_px.items()},
            "T_J_left": None if self.T_J_left is None else self.T_J_left.tolist(),
            "problems": list(self.problems),
        }


def _gray_u8(image: np.ndarray) -> np.ndarray:
    img = np.asarray(image)
    if img.ndim == 3:
        img = cv2.cvtColor(img, cv2.COLOR_RGB2GRAY)
    return (img >> 8).astype(np.uint8) if img.dtype == np.uint16 else img.astype(np.uint8)


def _joint_pose(found: list[dict[int, np.ndarray]], jig: JigConfig) -> tuple[np.ndarray, np.ndarray] | None:
    """Both cameras' poses in J from every corner found, the right camera held at its configured pose
    relative to the left one (as :mod:`softjig.sensing.jigframe` does, but never rejecting a poor fit:
    the check's job is to report it)."""
    from scipy.optimize import least_squares

    from softjig.geometry import pose_from_rotvec_translation

    if min(len(f) for f in found) < 2:
        return None
    fid = jig.fiducials
    corners_J = dict(zip(fid.ids, fiducial_corners_J(fid), strict=True))
    cams = (jig.cameras.left, jig.cameras.right)
    T_left_right = invert_pose(cams[0].T_J_cam) @ cams[1].T_J_cam
    obj = [np.concatenate([corners_J[i] for i in f]) for f in found]
    img = [np.concatenate([f[i] for i in f]) for f in found]
    dists = [np.asarray(c.distortion, float) for c in cams]
    ok, rvec, tvec = cv2.solvePnP(obj[0], img[0], cams[0].K, dists[0], flags=cv2.SOLVEPNP_IPPE)
    if not ok:
        return None

    def project(k: int, T_cam_J: np.ndarray) -> np.ndarray:
        r, _ = cv2.Rodrigues(T_cam_J[:3, :3])
        return cv2.projectPoints(obj[k], r, T_cam_J[:3, 3], cams[k].K, dists[k])[0].reshape(-1, 2)

    def residuals(x: np.ndarray) -> np.ndarray:
        T_left_J = pose_from_rotvec_translation(x[:3], x[3:])
        return np.concatenate(
            [
                (project(0, T_left_J) - img[0]).ravel(),
                (project(1, invert_pose(T_left_right) @ T_left_J) - img[1]).ravel(),
            ]
        )

    fit = least_squares(residuals, np.concatenate([rvec.ravel(), tvec.ravel()]), method="lm")
    T_J_left = invert_pose(pose_from_rotvec_translation(fit.x[:3], fit.x[3:]))
    return T_J_left, T_J_left @ T_left_right


def check_fiducials(
    left: np.ndarray, right: np.ndarray, jig: JigConfig, *, max_rms_px: float = 1.0
) -> FiducialCheck:
    """Find the configured fiducials in a (raw or rectified) stereo pair of ``jig``'s cameras and check
    that they sit where the config says (module docstring).

    Parameters
    ----------
    left, right : the images (gray or RGB, uint8/uint16) of ``jig.cameras``.
    jig : the jig; its cameras' intrinsics, distortion and relative pose are trusted.
    max_rms_px : the largest acceptable reprojection RMS (px).
    """
    fid = jig.fiducials
    gl, gr = _gray_u8(left), _gray_u8(right)
    found = [detect_fiducials(gl, fid), detect_fiducials(gr, fid)]
    missing = tuple(i for i in fid.ids if i not in found[0] and i not in found[1])
    problems = []
    if missing:
        problems.append(
            f"fiducials {list(missing)} were found in neither image: check they are printed from the "
            f"{fid.dictionary} dictionary with those ids, lit, and inside both cameras' view"
        )
    frame = _joint_pose(found, jig)
    per: dict[int, float] = {}
    rms = float("nan")
    T_J_left = None
    if frame is None:
        problems.append("too few fiducials in each image to measure the cameras' pose (2 per image needed)")
    else:
        T_J_left, T_J_right = frame
        corners_J = dict(zip(fid.ids, fiducial_corners_J(fid), strict=True))
        sq: dict[int, list[float]] = {}
        for side, T_J_cam, f in (("left", T_J_left, found[0]), ("right", T_J_right, found[1])):
            cam = getattr(jig.cameras, side)
            T = invert_pose(T_J_cam)
            rvec, _ = cv2.Rodrigues(T[:3, :3])
            for i, px in f.items():
                proj, _ = cv2.projectPoints(
                    corners_J[i], rvec, T[:3, 3], cam.K, np.asarray(cam.distortion, float)
                )
                sq.setdefault(i, []).extend(np.sum((proj.reshape(-1, 2) - px) ** 2, axis=1).tolist())
        per = {i: float(np.sqrt(np.mean(v))) for i, v in sorted(sq.items())}
        rms = float(np.sqrt(np.mean(np.concatenate([np.asarray(v) for v in sq.values()]))))
        for i, e in per.items():
            if e > max_rms_px:
                problems.append(
                    f"fiducial {i} reprojects {e:.2f} px from where it is seen (limit {max_rms_px} px): "
                    "it is not where fiducials.centers_mm says, "
                    "or fiducials.size_mm is wrong; measure and fix the config"
                )
    return FiducialCheck(
        tuple(sorted(found[0])),
        tuple(sorted(found[1])),
        missing,
        rms,
        per,
        T_J_left,
        ok=not problems,
        problems=tuple(problems),
    )
