"""One batched Levenberg-Marquardt solver for many small, independent least-squares problems.

Every pixel of an image is its own problem with a few parameters (P = 1 to 4). The caller
supplies the Gauss-Newton normal equations at trial points; the solver runs all pixels at
once, each with its own damping, and stops each pixel on its own. It is the project's one
least-squares solver: the polarized-RGB inversion (:mod:`.rgb_invert`), the spectral fits of
angle and thickness (:mod:`.spectral_fit`, :mod:`.spectral_stokes`), the joint fit of one film
index with every pixel's angle and thickness (one problem, its systems solved by
:func:`solve_arrow`) and the spectrometer fits of ``fit-spectrum`` (:mod:`.spectrum_fit`) use it.

Each iteration evaluates the model once per still-active pixel, at the trial point
``x + step`` with ``step = -(H + λ D)⁻¹ g``, ``D = diag(max(H_ii, floor))``; the trial is
kept when the cost drops (then λ shrinks), else λ grows.

Examples
--------
Fit ``y = a exp(b t)`` to two pixels at once:

>>> t = np.linspace(0.0, 1.0, 20)
>>> truth = np.array([[2.0, -1.0], [0.5, 0.7]])
>>> y = truth[:, :1] * np.exp(truth[:, 1:] * t)
>>> def normal_equations(x, idx):
...     e = np.exp(x[:, 1:] * t)
...     r = x[:, :1] * e - y[idx]                                   # residuals
...     J = np.stack([e, x[:, :1] * t * e], axis=-1)               # dr/dx
...     return J.transpose(0, 2, 1) @ J, np.einsum("nmp,nm->np", J, r), (r ** 2).sum(1), None
>>> fit = levenberg_marquardt(np.ones((2, 2)), normal_equations, iterations=50)
>>> np.round(fit.x, 6).tolist()
[[2.0, -1.0], [0.5, 0.7]]
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["LMResult", "levenberg_marquardt", "solve_small", "solve_arrow"]


@dataclass
class LMResult:
    """Per pixel: ``x`` (N, P) the solution, ``H`` (N, P, P) and ``g`` (N, P) the normal
    equations there (``JᵀJ`` and ``Jᵀr``), ``cost`` (N,), ``aux`` what the caller's function
    returned beside them at the solution (or None), ``iterations`` run."""

    x: np.ndarray
    H: np.ndarray
    g: np.ndarray
    cost: np.ndarray
    aux: np.ndarray | None
    iterations: int


def solve_small(A, b):
    """Solve many small systems ``A x = b`` (A: (N, P, P), b: (N, P)); closed forms for P ≤ 2."""
    P = b.shape[-1]
    if P == 1:
        return b / A[:, :, 0]
    if P == 2:
        a, c, d = A[:, 0, 0], A[:, 0, 1], A[:, 1, 1]
        e = A[:, 1, 0]
        det = a * d - c * e
        return np.stack([(d * b[:, 0] - c * b[:, 1]) / det, (a * b[:, 1] - e * b[:, 0]) / det], axis=-1)
    return np.linalg.solve(A, b[:, :, None])[:, :, 0]


def solve_arrow(A, b, block: int):
    """Solve ``A x = b`` for "arrow" matrices: one shared parameter first, then blocks of
    ``block`` parameters that couple only to themselves and to the shared one (a joint fit of
    one object-wide value and every pixel's own), by the Schur complement on the shared one.

    ``A`` (n, P, P) with ``P = 1 + block m``; entries outside the arrow are ignored.

    >>> rng = np.random.default_rng(0)
    >>> M = np.zeros((7, 7)); M[0] = M[:, 0] = rng.normal(size=7)
    >>> for i in range(3):
    ...     B = rng.normal(size=(2, 2)); M[1 + 2 * i:3 + 2 * i, 1 + 2 * i:3 + 2 * i] = B @ B.T + 3 * np.eye(2)
    >>> M[0, 0] = 40.0; b = rng.normal(size=7)
    >>> bool(np.allclose(solve_arrow(M[None], b[None], 2)[0], np.linalg.solve(M, b)))
    True
    """
    n, P = b.shape
    m = (P - 1) // block
    idx = 1 + np.arange(m * block).reshape(m, block)
    blocks = A[:, idx[:, :, None], idx[:, None, :]]                    # (n, m, block, block)
    c = A[:, 0, 1:].reshape(n, m, block)
    rest = b[:, 1:].reshape(n, m, block)
    Bc = np.linalg.solve(blocks, c[..., None])[..., 0]                 # B⁻¹ c
    Bb = np.linalg.solve(blocks, rest[..., None])[..., 0]              # B⁻¹ b
    schur = A[:, 0, 0] - np.einsum("nmk,nmk->n", c, Bc)
    x0 = (b[:, 0] - np.einsum("nmk,nmk->n", c, Bb)) / schur
    return np.concatenate([x0[:, None], (Bb - Bc * x0[:, None, None]).reshape(n, m * block)], axis=1)


def levenberg_marquardt(x0, normal_equations, iterations: int, *, project=None, max_step=None,
                        step_tol=None, rel_tol: float = 0.0, lam0: float = 1e-3, lam_down: float = 0.3,
                        lam_up: float = 10.0, lam_min: float = 0.0, lam_max: float = 1e8,
                        floor_rel: float = 1e-9, floor_abs: float = 0.0, converged=None, solve=None) -> LMResult:
    """Minimise every pixel's cost from ``x0`` (N, P).

    Parameters
    ----------
    normal_equations : callable ``(x (n, P), idx (n,)) -> (H (n, P, P), g (n, P), cost (n,), aux)``
        The Gauss-Newton matrix ``JᵀJ``, the gradient ``Jᵀr`` (``J`` the Jacobian of the
        residuals ``r``), the cost ``Σ r²`` and anything per pixel to keep with the solution
        (an (n, ...) array, or None), at points ``x`` of the pixels ``idx``.
    iterations : maximum number of iterations.
    project : callable ``x -> x`` putting trial points back in the domain (in place allowed).
    max_step : (P,) largest step per parameter (steps are clipped), or None.
    step_tol : (P,) a pixel stops once a step (accepted or not) is below this in every parameter.
    rel_tol : a pixel stops once an accepted step lowers its cost by less than this fraction.
    lam0, lam_down, lam_up, lam_min, lam_max : damping start, factors on success and failure,
        lower bound; a pixel whose damping exceeds ``lam_max`` stops.
    floor_rel, floor_abs : the damping's diagonal is ``max(H_ii, floor_rel max_j H_jj) + floor_abs``.
    converged : callable ``(step (n, P), H (n, P, P), cost (n,), accepted (n,)) -> (n,) bool``, optional
        A stopping rule of the caller's: the pixels for which it returns True stop. It sees
        each active pixel's step, the normal matrix and cost the step was made from, and
        whether the step was accepted (for example: an accepted step below a fraction of the
        parameter's standard error ``sqrt(cost / dof / H_ii)``).
    solve : callable ``(A (n, P, P), b (n, P)) -> (n, P)``, optional
        Solver of the damped systems, for problems with structure (default :func:`solve_small`;
        :func:`solve_arrow` for one shared parameter and many pixels' own).
    """
    x = np.array(x0, dtype=np.float64)
    N, P = x.shape
    all_idx = np.arange(N)
    H, g, cost, aux = normal_equations(x, all_idx)
    H, g, cost = np.array(H, dtype=np.float64), np.array(g, dtype=np.float64), np.array(cost, dtype=np.float64)
    aux = None if aux is None else np.array(aux)
    lam = np.full(N, float(lam0))
    active = np.ones(N, dtype=bool)
    max_step = None if max_step is None else np.asarray(max_step, dtype=np.float64)
    step_tol = None if step_tol is None else np.asarray(step_tol, dtype=np.float64)
    it = 0
    for it in range(1, iterations + 1):
        idx = np.nonzero(active)[0]
        if idx.size == 0:
            it -= 1
            break
        Hi, cost_i = H[idx], cost[idx]
        diag = np.einsum("nii->ni", Hi)
        scale = np.maximum(diag, floor_rel * diag.max(axis=1, keepdims=True)) + floor_abs
        A = Hi + (lam[idx][:, None] * scale)[:, :, None] * np.eye(P)[None]
        step = -(solve_small if solve is None else solve)(A, g[idx])
        if max_step is not None:
            step = np.clip(step, -max_step, max_step)
        xn = x[idx] + step
        if project is not None:
            xn = project(xn)
        Hn, gn, cn, auxn = normal_equations(xn, idx)
        better = cn < cost[idx]
        ib = idx[better]
        rel = (cost[idx] - cn)[better] / np.maximum(cost[ib], 1e-300)
        x[ib], H[ib], g[ib], cost[ib] = xn[better], Hn[better], gn[better], cn[better]
        if aux is not None:
            aux[ib] = auxn[better]
        lam[ib] = np.maximum(lam[ib] * lam_down, lam_min)
        worse = idx[~better]
        lam[worse] *= lam_up
        done = np.zeros(N, dtype=bool)
        if step_tol is not None:
            # a step below the tolerance ends the pixel whether or not it lowered the cost: at
            # that point the cost's own rounding (single-precision kernels) decides, not the model
            done[idx] = np.all(np.abs(step) < step_tol, axis=1)
        if rel_tol > 0:
            done[ib] |= rel < rel_tol
        if converged is not None:
            done[idx] |= np.asarray(converged(step, Hi, cost_i, better), dtype=bool)
        done[idx] |= lam[idx] >= lam_max
        active &= ~done
    return LMResult(x, H, g, cost, aux, it)
