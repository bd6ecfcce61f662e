"""Refinement by analysis by synthesis: any estimate fitted again to all of a dataset's
captures through the observation model, in the camera noise model's likelihood.

It starts from an estimate (a built-in method's, the paper's or a third party's) and fits, by
Gauss-Newton with Levenberg-Marquardt damping:

* the surface: with the default priors every pixel's surface gradient ``(z_x, z_y)`` (its
  normal ``(-z_x, -z_y, 1)``), held to an integrable field by a prior on its curl, and a
  height field integrated from the result (:func:`thinfilm.reconstruction.surface.integrate_normals`);
  with ``prior="none"`` every pixel's normal on its own (``(v1, v2) = sin² θ (cos 2φ, sin 2φ)``);
* every pixel's film **thickness**;
* the film **index** (one offset for the object, added to its dispersion) where the capture
  can tell it (spectral captures; ``fit_index``).

The residuals are the captures' own (:class:`thinfilm.core.model.Observations`): the polarized
RGB images, or the Stokes cube, or the s spectra alone, each weighted by ``1/σ`` of the camera
noise model at its exposure (:func:`thinfilm.core.noise.capture_variance`; the auto exposure
found again from the captured images), so that the cost is the negative log-likelihood of
Gaussian noise and its Gauss-Newton matrix the Fisher information. The model and its
Jacobian are the observation model's (:meth:`thinfilm.core.model.ObservationModel.normal_equations`,
forward-mode AD in Dr.Jit); the derivatives through the height field are the chain rule on
the sparse difference operators, and each step solves one sparse system (SciPy's SuperLU),
the film index by the Schur complement.

Priors (``prior="default"``), in units of the noise (the cost is Σ r² with r in σ):

``thickness_smoothness_nm`` (:data:`THICKNESS_SMOOTHNESS_NM`)
    the thickness's second differences along x and y have standard deviation 2 nm;
``curl`` (:data:`CURL_SIGMA`)
    the curl of the gradient field on every 2 x 2 cell of pixels has standard deviation 0.01
    (times ``1 + |∇z|²``): a surface's normals are a gradient field; the prior carries the
    shape across regions the captures say little about (near normal incidence, where
    polarization is weak) and fixes the azimuth where the data leave it open;
``curvature`` (:data:`CURVATURE_SIGMA`)
    neighbouring pixels' gradients differ with standard deviation 0.05 (times
    ``(1 + |∇z|²)^1.5``), in a Cauchy loss: smooth where the captures say little, a crease
    or ridge kept.

Pixels whose fit stays far above the noise (an inter-reflection, a shadow: the model has
neither) weigh less: each pixel's cost enters through a Cauchy loss of its χ² per value
(scale :data:`OUTLIER_CHI2`), and pixels that end above ``max_chi2`` are reported invalid.

The uncertainty: each pixel's σ from its own Fisher information at the refined state (the
data alone, the index known; with the priors the estimate is better than that), inflated by
its reduced χ² where that exceeds 1, and for a fitted index the index's own variance carried
into the thickness.
"""

from __future__ import annotations

import time
import warnings

import numpy as np

from thinfilm.core.errors import ThinfilmWarning, UserError

__all__ = ["PRIORS", "THICKNESS_SMOOTHNESS_NM", "CURL_SIGMA", "CURVATURE_SIGMA", "OUTLIER_CHI2", "refine_estimate",
           "capture_of", "observations_of"]

#: the priors of :func:`refine_estimate`
PRIORS = ("default", "none")
#: standard deviation (nm) of the thickness's second differences along x and y (default prior):
#: a thickness that changes linearly costs nothing
THICKNESS_SMOOTHNESS_NM = 2.0
#: standard deviation of the curl of the surface's gradient on a 2 x 2 cell of pixels, over
#: ``1 + |∇z|²`` (default prior): the normals of a surface are a gradient field, curl-free
CURL_SIGMA = 0.01
#: standard deviation of the difference of neighbouring pixels' surface gradients, over
#: ``(1 + |∇z|²)^1.5`` (default prior; a Cauchy loss of scale :data:`OUTLIER_CHI2`, so that a
#: crease costs little more than a bend): carries the surface where the captures say little
CURVATURE_SIGMA = 0.05
#: χ² per value above which a pixel's weight falls (Cauchy weights)
OUTLIER_CHI2 = 9.0
#: draws of the posterior for the σ of the default prior (a σ's relative error about 1/√(2K))
SIGMA_SAMPLES = 48


def capture_of(dataset, estimate) -> str:
    """The capture a refinement fits: the one the estimate was made from
    (:func:`thinfilm.core.bound.estimate_capture`), where the dataset holds it; else the Stokes
    cube, the s spectra or the polarized RGB images, the first the dataset holds."""
    from thinfilm.core.bound import estimate_capture

    have = {"stokes": bool(dataset.stokes), "spectral_s": dataset.spectral_s is not None,
            "polarized_rgb": bool(dataset.polarized_rgb)}
    cap = estimate_capture(estimate, dataset)
    if have.get(cap):
        return cap
    for cap in ("stokes", "spectral_s", "polarized_rgb"):
        if have[cap]:
            return cap
    raise UserError(f"{dataset.path}: the dataset holds no capture to refine on")


def observations_of(dataset, capture: str, mask, rig):
    """The :class:`~thinfilm.core.model.Observations` of the pixels of ``mask`` for ``capture``,
    weighted by the camera noise model (``1/σ``; uniform weights where the dataset records no
    camera noise), and the noise-free check: returns ``(observations, values per pixel (N,),
    noise_known)``."""
    from thinfilm.core.conventions import stokes_design_matrix
    from thinfilm.core.model import Observations
    from thinfilm.core.noise import capture_variance, exposure_gains

    noise = dataset.meta.get("noise") or {}
    known = noise.get("model") == "camera"
    if capture == "polarized_rgb":
        angles = dataset.polarizer_angles_deg
        imgs = np.stack([np.asarray(dataset.polarized_rgb[a], dtype=np.float64) for a in angles])   # (A, H, W, 3)
        data = np.moveaxis(imgs[:, mask], 0, 1)                                                     # (N, A, 3)
        if known:
            gains = exposure_gains(imgs, mask, noise)
            var = capture_variance(imgs[:, mask], gains, noise)                                      # (A, N, 3)
            w = 1.0 / np.sqrt(np.maximum(np.moveaxis(var, 0, 1), 1e-30))
        else:
            w = np.ones_like(data)
        return Observations("polarized_rgb", data, w, angles_deg=angles), data.shape[1] * 3, known
    angles = rig.polarizer_angles_deg
    design = stokes_design_matrix(angles)                                                           # (A, 3)
    if capture == "stokes":
        S = [np.asarray(dataset.stokes[k], dtype=np.float64)[mask] for k in ("S0", "S1", "S2")]     # (N, B)
    else:
        S = [np.asarray(dataset.spectral_s, dtype=np.float64)[mask]]
    n, b = S[0].shape
    if known:
        full = [np.asarray(dataset.stokes[k], dtype=np.float64) for k in ("S0", "S1", "S2")] if dataset.stokes \
            else None
        if full is not None:
            imgs = np.einsum("ak,khwb->ahwb", design, np.stack(full))                               # (A, H, W, B)
        else:  # the s spectra alone: the images of light polarized along s, about
            s_img = np.asarray(dataset.spectral_s, dtype=np.float64)
            imgs = np.stack([0.5 * s_img] * len(angles))
        gains = np.stack([exposure_gains(imgs[..., k], mask, noise) for k in range(b)], axis=1)    # (A, B)
        var_i = np.stack([capture_variance(imgs[:, mask, k], gains[:, k], noise) for k in range(b)], axis=2)
        fit = np.linalg.pinv(design)                                                                # (3, A)
        var_s = np.einsum("ka,anb->knb", fit ** 2, var_i)                                          # (3, N, B)
        if capture == "stokes":
            w = (1.0 / np.sqrt(np.maximum(var_s[0], 1e-30)),
                 1.0 / np.sqrt(np.maximum(0.5 * (var_s[1] + var_s[2]), 1e-30)))
        else:
            # s = S0 + |(S1, S2)|: about var S0 + var S1 along the polarization
            w = 1.0 / np.sqrt(np.maximum(var_s[0] + 0.5 * (var_s[1] + var_s[2]), 1e-30))
    else:
        w = (1.0, 1.0) if capture == "stokes" else 1.0
    if capture == "stokes":
        return Observations("stokes", tuple(S), w), 3 * b, known
    return Observations("spectral_s", S[0], w), b, known


def _v_of_gradient(p, q):
    """``(v1, v2)`` (N, 2) of the normals of surface gradients ``(p, q)`` and ``∂v/∂(p, q)``
    (N, 2, 2)."""
    s = p * p + q * q
    den = 1.0 + s
    v = np.stack([(p * p - q * q) / den, 2 * p * q / den], axis=1)
    d2 = den * den
    J = np.empty((p.size, 2, 2))
    J[:, 0, 0] = 2 * p * (1 + 2 * q * q) / d2
    J[:, 0, 1] = -2 * q * (1 + 2 * p * p) / d2
    J[:, 1, 0] = 2 * q * (1 - p * p + q * q) / d2
    J[:, 1, 1] = 2 * p * (1 + p * p - q * q) / d2
    return v, J


def _operators(mask):
    """Sparse operators on the pixels of ``mask`` (row-major order): the curl of a gradient
    field ``(p, q)`` on every 2 x 2 cell of the mask (cells × 2 N, ``∂p/∂y - ∂q/∂x``, y up)
    and the second differences along x and y (rows × N)."""
    import scipy.sparse as sp

    from .surface import second_differences

    H, W = mask.shape
    n = int(mask.sum())
    idx = -np.ones((H, W), dtype=np.int64)
    idx[mask] = np.arange(n)
    # cell: a = (r, c), b = (r, c + 1) below; c_ = (r - 1, c), d_ = (r - 1, c + 1) above (y up)
    cell = mask[1:, :-1] & mask[1:, 1:] & mask[:-1, :-1] & mask[:-1, 1:]
    a, b = idx[1:, :-1][cell], idx[1:, 1:][cell]
    c_, d_ = idx[:-1, :-1][cell], idx[:-1, 1:][cell]
    m = a.size
    rows = np.tile(np.arange(m), 8)
    cols = np.concatenate([c_, d_, a, b, n + b, n + d_, n + a, n + c_])
    vals = np.concatenate([np.full(2 * m, 0.5), np.full(2 * m, -0.5), np.full(2 * m, -0.5), np.full(2 * m, 0.5)])
    C = sp.csr_matrix((vals, (rows, cols)), shape=(m, 2 * n))
    S = second_differences(mask, idx, n)
    ei, ej = [], []
    for lo, hi in (((slice(None), slice(None, -1)), (slice(None), slice(1, None))),
                   ((slice(None, -1), slice(None)), (slice(1, None), slice(None)))):
        e = mask[lo] & mask[hi]
        ei.append(idx[lo][e])
        ej.append(idx[hi][e])
    ei, ej = np.concatenate(ei), np.concatenate(ej)
    k = ei.size
    E = sp.csr_matrix((np.concatenate([np.full(k, -1.0), np.ones(k)]), (np.tile(np.arange(k), 2), np.concatenate([ei, ej]))),
                      shape=(k, n))
    return _Priors(C, (a, b, c_, d_), S, E, (ei, ej))


class _Priors:
    """The default prior's terms on the unknowns ``z`` (N, 2) (the surface gradient) and ``d``
    (N,): the curl of the gradient field (Gaussian), the thickness's second differences
    (Gaussian), and the gradient's differences between neighbours (a Cauchy loss, so that
    creases and ridges stay sharp), each residual in units of its σ."""

    def __init__(self, C, cells, S, E, edges):
        self.C, self.cells, self.S, self.E, self.edges = C, cells, S, E, edges
        self.w_c, self.w_d, self.w_s = 1.0 / CURL_SIGMA, 1.0 / THICKNESS_SMOOTHNESS_NM, 1.0 / CURVATURE_SIGMA

    def curl_weights(self, z):
        s2 = np.sum(z ** 2, axis=1)
        a, b, c_, d_ = self.cells
        return self.w_c / (1.0 + 0.25 * (s2[a] + s2[b] + s2[c_] + s2[d_]))

    def edge_weights(self, z):
        s2 = np.sum(z ** 2, axis=1)
        i, j = self.edges
        return self.w_s / (1.0 + 0.5 * (s2[i] + s2[j])) ** 1.5

    def residuals(self, z, d):
        """(curl, thickness, smoothness of z_x, smoothness of z_y) residuals."""
        we = self.edge_weights(z)
        return (self.curl_weights(z) * (self.C @ z.T.ravel()), self.w_d * (self.S @ d),
                we * (self.E @ z[:, 0]), we * (self.E @ z[:, 1]))

    def objective(self, z, d):
        rc, rd, rx, ry = self.residuals(z, d)
        k = OUTLIER_CHI2
        return float(np.sum(rc ** 2) + np.sum(rd ** 2) + np.sum(k * np.log1p(rx ** 2 / k))
                     + np.sum(k * np.log1p(ry ** 2 / k)))

    def system(self, z, d):
        """The priors' Gauss-Newton matrix (3 N square, IRLS weights for the Cauchy terms) and
        their gradient ``Jᵀ r`` at ``(z, d)``."""
        import scipy.sparse as sp

        rc, rd, rx, ry = self.residuals(z, d)
        Cw = (sp.diags(self.curl_weights(z)) @ self.C).tocsr()
        we = self.edge_weights(z)
        k = OUTLIER_CHI2
        blocks = []
        grads = []
        for r in (rx, ry):
            irls = 1.0 / (1.0 + r ** 2 / k)
            Ew = (sp.diags(we * np.sqrt(irls)) @ self.E).tocsr()
            blocks.append(Ew.T @ Ew)
            grads.append(self.E.T @ (we * irls * r))
        smooth = sp.block_diag(blocks)
        A = sp.block_diag([Cw.T @ Cw + smooth, self.w_d ** 2 * (self.S.T @ self.S)]).tocsc()
        g = np.concatenate([Cw.T @ rc + np.concatenate(grads), self.w_d * (self.S.T @ rd)])
        return A, g

    def draw(self, z, d, rng, count):
        """``Jᵀ ξ`` of the priors' (IRLS-weighted) rows for ``count`` standard normal draws
        ``ξ``: (3 N, count), covariance the priors' Gauss-Newton matrix."""
        n = d.size
        rc, rd, rx, ry = self.residuals(z, d)
        k = OUTLIER_CHI2
        Cw = self.C.T.multiply(self.curl_weights(z)[None, :]).tocsr()          # (2 N, cells)
        out = np.zeros((3 * n, count))
        out[:2 * n] = Cw @ rng.standard_normal((self.C.shape[0], count))
        we = self.edge_weights(z)
        for c, r in enumerate((rx, ry)):
            w = we * np.sqrt(1.0 / (1.0 + r ** 2 / k))
            out[c * n:(c + 1) * n] += self.E.T @ (w[:, None] * rng.standard_normal((w.size, count)))
        out[2 * n:] = self.w_d * (self.S.T @ rng.standard_normal((self.S.shape[0], count)))
        return out


def refine_estimate(dataset, estimate, prior: str = "default", iterations: int = 8, fit_index=None,
                    max_chi2: float = 50.0, backend: str = "llvm", progress: bool = False):
    """Refine ``estimate`` (:class:`thinfilm.core.io.Estimate`) on ``dataset``
    (:class:`thinfilm.core.io.Dataset` with its captures read); see the module docstring.

    Parameters
    ----------
    prior : ``"default"`` (a height field and smooth thickness) or ``"none"`` (every pixel on
        its own: the maximum-likelihood fit of each pixel).
    iterations : Gauss-Newton iterations.
    fit_index : fit the film index (default: for spectral captures, not for polarized RGB,
        whose three colours barely tell it from the thickness).
    max_chi2 : pixels whose final fit is worse (χ² per value) are reported invalid.

    Returns
    -------
    :class:`thinfilm.core.io.Estimate` with ``normal_sigma_deg`` and ``thickness_sigma_nm``
    and ``info["refine"]`` (prior, iterations, capture, costs, timings).
    """
    import scipy.sparse as sp

    from thinfilm.core.bound import angle_sigma_deg, normal_jacobian
    from thinfilm.core.conventions import angles_to_normals
    from thinfilm.core.io import Estimate
    from thinfilm.core.model import ObservationModel, Rig, state_from_normals, view_frames
    from thinfilm.core.progress import progress_bar

    from .surface import integrate_normals

    if prior not in PRIORS:
        raise UserError(f"prior must be one of {', '.join(PRIORS)}, got {prior!r}", argument="prior")
    t0 = time.perf_counter()
    timings = {}
    shape = dataset.shape
    if estimate.normals.shape[:2] != tuple(shape):
        raise UserError(f"the estimate is {estimate.normals.shape[1]}x{estimate.normals.shape[0]} pixels, the "
                        f"dataset {shape[1]}x{shape[0]}")
    film = dataset.film()
    if not film.is_single:
        raise UserError(f"{dataset.path / 'meta.json'}: the film is a stack; refine fits a single film")
    if estimate.film_ior is not None:
        film = film.with_index(estimate.film_ior)
    capture = capture_of(dataset, estimate)
    if fit_index is None:
        fit_index = capture != "polarized_rgb"
    normals0 = np.asarray(estimate.normals, dtype=np.float64)
    d_img = np.asarray(estimate.thickness_nm, dtype=np.float64)
    mask = (np.asarray(estimate.valid, dtype=bool) & np.all(np.isfinite(normals0), axis=-1) & np.isfinite(d_img)
            & (np.nan_to_num(normals0[..., 2]) > 0.02))
    if dataset.valid is not None:
        mask &= dataset.valid
    n = int(mask.sum())
    if n < 4:
        raise UserError("the estimate has fewer than 4 valid pixels to refine")
    rig = Rig.of_dataset(dataset)
    obs, width, noise_known = observations_of(dataset, capture, mask, rig)
    if not noise_known:
        warnings.warn("refine: the dataset records no camera noise model; every value gets the same weight and "
                      "the sigma is scaled by the fit's residuals", ThinfilmWarning, stacklevel=2)
    model = ObservationModel(rig, film, backend=backend)
    views, e1 = view_frames(rig, shape)
    views, e1 = views[mask], e1[mask]
    timings["prepare"] = time.perf_counter() - t0

    def light_of(v, d):
        u = np.clip(np.hypot(v[:, 0], v[:, 1]), 0.0, 1.0)
        phi = 0.5 * np.arctan2(v[:, 1], v[:, 0])
        nrm = np.stack([np.sqrt(u) * np.cos(phi), np.sqrt(u) * np.sin(phi), np.sqrt(1 - u)], axis=1)
        return state_from_normals(nrm, views, e1, [d], rig.dome_hole_deg).light

    def light_sub(v, d, idx):
        u = np.clip(np.hypot(v[:, 0], v[:, 1]), 0.0, 1.0)
        phi = 0.5 * np.arctan2(v[:, 1], v[:, 0])
        nrm = np.stack([np.sqrt(u) * np.cos(phi), np.sqrt(u) * np.sin(phi), np.sqrt(1 - u)], axis=1)
        return state_from_normals(nrm, views[idx], e1[idx], [d], rig.dome_hole_deg).light

    def pixel_equations(v, d, offset, derivatives=True):
        x = np.concatenate([v, d[:, None]] + ([np.full((n, 1), offset)] if fit_index else []), axis=1)
        fixed = {"light": light_of(v, d)}
        H, g, cost = model.normal_equations(obs, x, "double_angle", fixed=fixed, derivatives=derivatives)
        return H, g, cost

    # the start: the estimate's normals and thickness (a height field integrated from them)
    y0 = np.clip(np.nan_to_num(d_img[mask]), 0.0, None)
    offset = 0.0
    priors = _operators(mask)
    if prior == "default":
        from .surface import normals_to_gradients

        p0, q0 = normals_to_gradients(normals0[mask], max_slope_deg=89.0)
        z = np.stack([p0, q0], axis=1)           # the surface's gradient (z_x, z_y) per pixel
        v, _ = _v_of_gradient(z[:, 0], z[:, 1])
    else:
        u = np.clip(1.0 - normals0[mask][:, 2] ** 2, 0.0, 1.0)
        phi = np.arctan2(normals0[mask][:, 1], normals0[mask][:, 0])
        v = np.stack([u * np.cos(2 * phi), u * np.sin(2 * phi)], axis=1)
        z = None
    sign_ref = normals0[mask][:, :2]
    d = y0.copy()

    bar = progress_bar(iterations, "refine", progress)
    lam = 1e-3
    H, g, cost = pixel_equations(v, d, offset)
    history = []
    if prior == "none":
        # independent pixels: each with its own damping and acceptance (the batched solver),
        # the film index between rounds by the Schur complement of the pixels' blocks
        from .lm import levenberg_marquardt

        def pixel_ne(x, idx):
            vv, dd = x[:, :2], x[:, 2]
            x4 = np.concatenate([x] + ([np.full((idx.size, 1), offset)] if fit_index else []), axis=1)
            sub = ObservationModel.normal_equations
            Hs, gs, cs = sub(model, obs, x4, "double_angle", rows=idx,
                             fixed={"light": light_sub(vv, dd, idx)})
            return Hs[:, :3, :3], gs[:, :3], cs, None

        def project(x):
            uu = np.hypot(x[:, 0], x[:, 1])
            f = np.where(uu > 0.9999, 0.9999 / np.maximum(uu, 1e-300), 1.0)
            x[:, 0] *= f
            x[:, 1] *= f
            x[:, 2] = np.maximum(x[:, 2], 0.0)
            return x

        history.append(float(np.sum(cost)))
        for _ in range(3 if fit_index else 1):
            fit = levenberg_marquardt(np.concatenate([v, d[:, None]], axis=1), pixel_ne, iterations, project=project,
                                      rel_tol=1e-10, step_tol=np.array([1e-9, 1e-9, 1e-5]))
            v, d = fit.x[:, :2], fit.x[:, 2]
            H, g, cost = pixel_equations(v, d, offset)
            if fit_index:
                ok_ = np.all(np.isfinite(H), axis=(1, 2))
                h = H[ok_, :3, 3]
                sol_h = np.linalg.solve(H[ok_, :3, :3] + 1e-12 * np.eye(3), h[:, :, None])[:, :, 0]
                sol_g = np.linalg.solve(H[ok_, :3, :3] + 1e-12 * np.eye(3), g[ok_, :3, None])[:, :, 0]
                schur = float(np.sum(H[ok_, 3, 3] - np.einsum("ni,ni->n", h, sol_h)))
                dn = -float(np.sum(g[ok_, 3] - np.einsum("ni,ni->n", h, sol_g))) / schur if schur > 0 else 0.0
                offset += dn
                H, g, cost = pixel_equations(v, d, offset)
            history.append(float(np.sum(cost)))
            bar.update(1)
        iterations = 0

    def objective(cost, d, z):
        c = float(np.sum(_loss(cost, width)))
        if prior == "default":
            c += priors.objective(z, d)
        return c

    for it in range(iterations):
        cur = objective(cost, d, z)
        history.append(cur)
        A, rhs, border, h_nn, r_n, _ = _system(prior, H, g, _robust(cost, width), z, d, priors, fit_index)
        accepted = False
        for _ in range(6):
            diag = A.diagonal()
            Ad = (A + sp.diags(lam * np.maximum(diag, 1e-12 * max(diag.max(), 1e-300)))).tocsc()
            lu = _factor(Ad)
            step = lu.solve(rhs)
            dn = 0.0
            if fit_index:
                Bb = lu.solve(border)
                schur = h_nn * (1.0 + lam) - border @ Bb
                dn = (r_n - border @ step) / schur if schur > 0 else 0.0
                step = step - Bb * dn
            v_t, d_t, z_t = _apply(prior, step, v, d, z, n)
            o_t = offset + dn
            H_t, g_t, cost_t = pixel_equations(v_t, d_t, o_t)
            if objective(cost_t, d_t, z_t) < cur:
                v, d, offset, z, H, g, cost = v_t, d_t, o_t, z_t, H_t, g_t, cost_t
                lam = max(lam * 0.3, 1e-9)
                accepted = True
                break
            lam *= 10.0
        bar.update(1)
        if not accepted or (cur - objective(cost, d, z)) < 1e-5 * cur:
            break
    if prior == "default":
        history.append(objective(cost, d, z))
    bar.close()
    timings["fit"] = time.perf_counter() - t0 - timings["prepare"]

    # the normals: the height field's (default), or each pixel's own, on the side of the start
    t1 = time.perf_counter()
    if prior == "default":
        nrm = np.stack([-z[:, 0], -z[:, 1], np.ones(n)], axis=1)
        nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    else:
        u = np.clip(np.hypot(v[:, 0], v[:, 1]), 0.0, 1.0)
        phi = 0.5 * np.arctan2(v[:, 1], v[:, 0])
        flip = np.cos(phi) * sign_ref[:, 0] + np.sin(phi) * sign_ref[:, 1] < 0
        phi = np.where(flip, phi + np.pi, phi)
        nrm = angles_to_normals(np.degrees(np.arcsin(np.sqrt(u))), np.degrees(phi))
    normals = np.zeros(shape + (3,))
    normals[..., 2] = 1.0
    normals[mask] = nrm
    # σ: with the default prior, the linearized posterior (data and priors, by samples);
    # without, each pixel's Fisher information at the result. The index is known in both,
    # its own variance is added below; each is inflated by the pixel's χ² where the data
    # fit worse than the noise (or scaled by the residuals where the noise is not known)
    chi2 = cost / width
    Hp = H[:, :3, :3]
    # (a pixel's χ² per value scatters about 1 by sqrt(2 / width): only a misfit beyond that
    # inflates its σ)
    misfit = chi2 > 1.0 + 3.0 * np.sqrt(2.0 / width)
    scale = (np.where(misfit, chi2, 1.0) if noise_known
             else np.full(n, max(float(np.median(chi2)), 1e-300)))
    ok = np.all(np.isfinite(Hp), axis=(1, 2))
    ok[ok] &= np.linalg.cond(Hp[ok]) < 1e14
    if prior == "default":
        rho = _robust(cost, width)
        A, _, _, _, _, M = _system(prior, H, g, rho, z, d, priors, False)
        dv, dd = _posterior_samples(A, M, H, rho, priors, z, d, SIGMA_SAMPLES)
        Jn = normal_jacobian(v)
        ang2 = np.mean(np.sum(np.einsum("nip,knp->kni", Jn, dv) ** 2, axis=2), axis=0)
        sig_n = np.degrees(np.sqrt(ang2 * scale))
        var_d = np.mean(dd ** 2, axis=0) * scale
    else:
        cov = np.full(Hp.shape, np.nan)
        cov[ok] = np.linalg.inv(Hp[ok])
        cov *= scale[:, None, None]
        sig_n = angle_sigma_deg(normal_jacobian(v), cov[:, :2, :2])
        var_d = cov[:, 2, 2]
    index_sigma = None
    if fit_index:
        # the index's variance (Schur complement of the pixels' blocks) carried into each
        # pixel's thickness through the pixel's own coupling
        h = H[:, :3, 3]
        sol = np.full((n, 3), np.nan)
        sol[ok] = np.linalg.solve(Hp[ok], h[ok][:, :, None])[:, :, 0]
        info_n = float(np.nansum(H[:, 3, 3] - np.einsum("ni,ni->n", h, sol)))
        index_sigma = float(np.sqrt(np.median(scale) / info_n)) if info_n > 0 else float("inf")
        # beyond its statistical error, the index of one number carries the model's own
        # (a dispersive film fitted with a constant index), as in the spectral defaults
        from .spectral_fit import FILM_IOR_SIGMA

        index_sigma = float(np.hypot(index_sigma, FILM_IOR_SIGMA))
        var_d = var_d + (sol[:, 2] * index_sigma) ** 2
    sig_d = np.sqrt(var_d)
    valid = np.zeros(shape, dtype=bool)
    valid[mask] = np.isfinite(chi2) & (chi2 < max_chi2) & np.isfinite(sig_d)
    kept = int(valid.sum())
    if kept == 0:
        from thinfilm.core.errors import NoResultError

        raise NoResultError(f"refine: the model explains none of the estimate's {n} pixels (every fit ends above "
                            f"chi2 {max_chi2:g} per value): the captures are not those of this film and rig, or the "
                            f"start is too far off")
    if kept < 0.5 * n:
        warnings.warn(f"refine: only {kept} of the estimate's {n} pixels fit within chi2 {max_chi2:g} per value; "
                      f"the others are invalid (the start may be far off, or the model lacks what the captures hold: "
                      f"inter-reflections, a rough film, a stack)", ThinfilmWarning, stacklevel=2)
    out_d = np.full(shape, np.nan)
    out_d[mask] = d
    sn = np.full(shape, np.nan)
    sd = np.full(shape, np.nan)
    sn[mask], sd[mask] = sig_n, sig_d
    height = integrate_normals(normals, mask, smoothness=0.05)
    film_ior = estimate.film_ior
    if fit_index:
        film_ior = float(film.effective_index() + offset)
    timings["uncertainty"] = time.perf_counter() - t1
    timings["total"] = time.perf_counter() - t0
    info = dict(estimate.info)
    info["refine"] = {"prior": prior, "capture": capture, "iterations": len(history), "cost_start": history[0],
                      "cost_end": float(history[-1]) if history else None, "fit_index": bool(fit_index),
                      "film_ior_sigma": index_sigma, "noise_model": bool(noise_known),
                      "thickness_smoothness_nm": THICKNESS_SMOOTHNESS_NM if prior == "default" else None,
                      "curl_sigma": CURL_SIGMA if prior == "default" else None,
                      "curvature_sigma": CURVATURE_SIGMA if prior == "default" else None,
                      "unexplained_pixels": int(np.sum(~(chi2 < max_chi2))), "timings_s": timings}
    info["method"] = f"{estimate.info.get('method') or 'estimate'}+refine"
    return Estimate(normals=normals, thickness_nm=out_d, valid=valid, film_ior=film_ior,
                    substrate_ior=estimate.substrate_ior, height=height * estimate.pixel_size,
                    pixel_size=estimate.pixel_size, info=info, normal_sigma_deg=sn, thickness_sigma_nm=sd)


def _system(prior, H, g, rho, z, d, priors, fit_index):
    """The Gauss-Newton system of a refinement step over every pixel's three unknowns
    (``(z_x, z_y, d)`` with the default prior, ``(v1, v2, d)`` without; all first components,
    then all second, then the thicknesses): the sparse matrix, its right-hand side, the column
    of the film index's coupling, the index's own entries and the Jacobian ``T`` (N, 3, 3) of
    the pixels' model unknowns ``(v1, v2, d)`` by theirs. ``rho``: the pixels' robust weights."""
    import scipy.sparse as sp

    n = H.shape[0]
    Hr, gr = H * rho[:, None, None], g * rho[:, None]
    T = np.zeros((n, 3, 3))
    T[:, 2, 2] = 1.0
    if prior == "default":
        _, T[:, :2, :2] = _v_of_gradient(z[:, 0], z[:, 1])
    else:
        T[:, 0, 0] = T[:, 1, 1] = 1.0
    B = np.einsum("nki,nkl,nlj->nij", T, Hr[:, :3, :3], T)
    A = sp.bmat([[sp.diags(B[:, a, c]) for c in range(3)] for a in range(3)]).tocsc()
    grad = np.einsum("nki,nk->ni", T, gr[:, :3])
    rhs = -np.concatenate([grad[:, 0], grad[:, 1], grad[:, 2]])
    if prior == "default":
        Ap, gp = priors.system(z, d)
        A = A + Ap
        rhs = rhs - gp
    border = None
    if fit_index:
        col = np.einsum("nki,nk->ni", T, Hr[:, :3, 3])
        border = np.concatenate([col[:, 0], col[:, 1], col[:, 2]])
    h_nn = float(np.sum(Hr[:, 3, 3])) if fit_index else 0.0
    r_n = -float(np.sum(gr[:, 3])) if fit_index else 0.0
    return A + 1e-12 * sp.identity(3 * n), rhs, border, h_nn, r_n, T


def _factor(A):
    """SuperLU of a symmetric positive definite sparse matrix (symmetric ordering, no pivoting)."""
    import scipy.sparse.linalg as spla

    return spla.splu(A.tocsc(), permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0, options={"SymmetricMode": True})


def _apply(prior, step, v, d, z, n):
    """The trial point of a step: ``(v, d, z)``."""
    d_t = np.maximum(d + step[2 * n:], 0.0)
    if prior == "default":
        z_t = z + np.stack([step[:n], step[n:2 * n]], axis=1)
        v_t, _ = _v_of_gradient(z_t[:, 0], z_t[:, 1])
        return v_t, d_t, z_t
    v_t = v + np.stack([step[:n], step[n:2 * n]], axis=1)
    uu = np.hypot(v_t[:, 0], v_t[:, 1])
    v_t = v_t * np.where(uu > 0.9999, 0.9999 / np.maximum(uu, 1e-300), 1.0)[:, None]
    return v_t, d_t, None


def _posterior_samples(A, T, H, rho, priors, z, d, count: int, seed: int = 0):
    """Draws ``(δv (K, N, 2), δd (K, N))`` of the linearized posterior of the default prior's
    unknowns, covariance ``A⁻¹`` (perturb-and-solve: ``A⁻¹ b`` with ``b`` of covariance ``A``,
    from the pixels' information ``H`` and the priors' rows), with a fixed seed."""
    n = H.shape[0]
    rng = np.random.default_rng(seed)
    Hr = H[:, :3, :3] * rho[:, None, None] + 1e-12 * np.eye(3)
    L = np.linalg.cholesky(Hr)                                          # (N, 3, 3)
    e = np.einsum("nij,knj->kni", L, rng.standard_normal((count, n, 3)))  # Cov = H per pixel
    e = np.einsum("nji,knj->kni", T, e)                                 # in the unknowns
    b = np.concatenate([e[:, :, 0], e[:, :, 1], e[:, :, 2]], axis=1).T  # (3 N, K)
    b += priors.draw(z, d, rng, count)
    delta = _factor(A).solve(np.ascontiguousarray(b))                   # (3 N, K)
    dz = np.stack([delta[:n].T, delta[n:2 * n].T], axis=2)              # (K, N, 2)
    dv = np.einsum("nij,knj->kni", T[:, :2, :2], dz)
    return dv, delta[2 * n:].T


def _robust(cost, width):
    """IRLS weights of the Cauchy loss (:func:`_loss`) at each pixel's cost."""
    c = np.asarray(cost, dtype=np.float64) / max(width, 1)
    return 1.0 / (1.0 + c / OUTLIER_CHI2)


def _loss(cost, width):
    """The Cauchy loss of each pixel's cost ``Σ r²`` over ``width`` values: ``width K log(1 +
    c / K)`` with ``c`` the χ² per value and ``K`` = :data:`OUTLIER_CHI2` (the cost itself well
    below ``K``, growing only logarithmically above)."""
    c = np.asarray(cost, dtype=np.float64) / max(width, 1)
    return width * OUTLIER_CHI2 * np.log1p(c / OUTLIER_CHI2)


