"""Oracle of the compiled ray solve of :mod:`softjig.optics`
(:func:`softjig._optics_kernels.layered_directions`): the same Newton iteration written with NumPy arrays,
one operation over all points at a time (the production code until the estimator's set-up needed it
cheaper). The kernel must give the same bits."""

from __future__ import annotations

import numpy as np

from softjig.optics import _NEWTON_MAX_ITER as NEWTON_MAX_ITER


def numpy_layered_directions(
    cz: np.ndarray, rel: np.ndarray, pz: np.ndarray, z_if: np.ndarray, n_reg: np.ndarray, sets: np.ndarray
) -> np.ndarray:
    """Unit initial directions of points above the first interface (refracted_ray_directions), from
    cameras at heights ``cz`` (per point), ``rel`` the points less their camera's centre.

    The points of a set (``sets``: a set index per point) are iterated until all of them
    converged, then frozen: a set's directions do not depend on the other sets solved with it (an
    iterate that converged still moves by an ulp at the next step).
    """
    # vertical distance travelled in each region, shape (R, M) (regions first: fast reductions)
    lo = np.concatenate([cz[None, :], np.broadcast_to(z_if[:, None], (len(z_if), len(cz)))])
    hi = np.concatenate([z_if, [np.inf]])
    h = np.clip(np.minimum(pz[None, :], hi[:, None]) - lo, 0.0, None)
    crossed = h > 0
    n_min = np.min(np.where(crossed, n_reg[:, None], np.inf), axis=0)  # (M,)
    a = n_reg[:, None] ** 2  # (R, 1)
    b = np.where(crossed, a - n_min[None, :] ** 2, 0.0)  # (R, M), >= 0 where used
    w = h * n_min[None, :]  # (R, M)
    wa = w * a
    rho = np.hypot(rel[:, 0], rel[:, 1])

    # g(t) = sum_i w_i t / sqrt(a_i + b_i t^2) - rho,  g'(t) = sum_i w_i a_i / (a_i + b_i t^2)^1.5
    # Increasing and concave in t >= 0, g(0) = -rho <= 0: Newton from t = 0 climbs monotonically.
    t = np.zeros_like(rho)
    tol = 4.0 * np.finfo(float).eps
    n_sets = int(sets[-1]) + 1
    active = np.ones(n_sets, dtype=bool)
    for _ in range(NEWTON_MAX_ITER):
        inv_sq = 1.0 / np.sqrt(a + b * (t * t))
        g = t * np.einsum("ij,ij->j", w, inv_sq) - rho
        dg = np.einsum("ij,ij->j", wa, inv_sq * inv_sq * inv_sq)
        step = g / dg
        t_new = np.maximum(t - step, 0.0)
        unsettled = ~(np.abs(t_new - t) <= tol * t_new)
        if n_sets == 1:
            t = t_new
            if not unsettled.any():
                break
            continue
        moving = active[sets]
        t = np.where(moving, t_new, t)
        active &= np.bincount(sets, weights=unsettled & moving, minlength=n_sets) > 0
        if not active.any():
            break
    # tan(theta_0) in region 0 from the invariant
    a0 = n_reg[0] ** 2
    tan0 = n_min * t / np.sqrt(a0 + (a0 - n_min**2) * t * t)
    scale = np.divide(tan0, rho, out=np.zeros_like(rho), where=rho > 0)
    d = np.column_stack([rel[:, 0] * scale, rel[:, 1] * scale, np.ones_like(rho)])
    d /= np.linalg.norm(d, axis=1)[:, None]
    return d
