"""Forward model of s-polarized film spectra for the spectral reconstruction, with derivatives.

Every reflectance here comes from :mod:`thinfilm.bsdf.optics` (the project's single source of
thin-film physics). For speed the optics is traced with Dr.Jit's LLVM backend when it is
available (one fused kernel over pixels × bands, forward-mode AD for the Jacobians); otherwise
the same functions run on NumPy arrays, in chunks, with derivatives by central differences.

Parameters throughout: ``theta_rad`` incident (= zenith, orthographic camera) angle,
``thickness_nm``, ``film_ior`` n2, ``substrate_ior`` n3, exterior index 1.
"""

from __future__ import annotations

import functools

import numpy as np

from thinfilm.bsdf import optics

__all__ = [
    "airy_coefficients",
    "airy_coefficients_exact",
    "rs_spectra",
    "grid_sse",
    "peak_reflectance",
    "angle_from_peak",
    "drjit_available",
    "use_drjit",
]

_CHUNK = 1 << 22  # elements (pixels × bands) per kernel


@functools.lru_cache(maxsize=1)
def drjit_available() -> bool:
    """True when Dr.Jit's LLVM backend runs here (it needs a working libLLVM)."""
    try:
        import drjit as dr
        from drjit.llvm.ad import Float64

        x = Float64([0.5, 0.25])
        y = optics.reflectances(x, Float64(500.0), Float64(100.0), 1.37, 1.6)[0]
        dr.eval(y)
        return bool(np.all(np.isfinite(y.numpy())))
    except Exception:  # pragma: no cover - depends on the machine
        return False


#: below this many lanes (pixels × bands × outputs) a NumPy evaluation beats a Dr.Jit
#: kernel (whose thread pool takes milliseconds to wake up)
DRJIT_MIN_LANES = 1 << 18


def use_drjit(lanes: int, minimum: int = DRJIT_MIN_LANES) -> bool:
    """Whether an evaluation of ``lanes`` values runs on Dr.Jit's LLVM backend."""
    return lanes >= minimum and drjit_available()


def _measured(R_s, R_p, sigma2, sqrt):
    """Expected ``S0 + sqrt(S1² + S2²)`` of a rotating-polarizer capture.

    ``S0 = (R_s + R_p)/2``; ``|(S1, S2)|`` has the Rice distribution of the true linear part
    ``b = (R_s - R_p)/2`` with Gaussian noise of variance ``sigma2`` per component, whose mean
    ``sqrt(b² + (π/2) σ²)`` approximates within 0.09 σ (exact at ``b = 0`` and for ``b >> σ``).
    Without noise this is ``R_s``.
    """
    b = 0.5 * (R_s - R_p)
    return 0.5 * (R_s + R_p) + sqrt(b * b + (0.5 * np.pi) * sigma2)


def _np_rs(theta, d, n2, n3, wl, sig2=None, with_p=False):
    R_s, R_p = optics.reflectances(np.cos(theta)[:, None], wl[None, :], d[:, None], n2[:, None], n3)
    if with_p:
        return np.concatenate([R_s, R_p], axis=1)
    if sig2 is None:
        return R_s
    return _measured(R_s, R_p, sig2[:, None], np.sqrt)


def rs_spectra(theta_rad, thickness_nm, film_ior, substrate_ior, wavelengths_nm, jac=(),
               stokes_noise=None, with_p=False):
    """s reflectance spectra of N pixels and, optionally, their partial derivatives.

    With ``with_p`` every row holds the s spectrum followed by the p spectrum (2 B values;
    ``stokes_noise`` is then not used: both come from the linear Stokes parameters, which
    carry no such bias).

    Parameters
    ----------
    theta_rad, thickness_nm : (N,) array_like
        Incident angle (radians) and film thickness (nm) per pixel.
    film_ior : float or (N,) array_like
        Film index n2 (one for all, or per pixel).
    substrate_ior : float
        Substrate index n3.
    wavelengths_nm : (B,) array_like
    jac : tuple of str
        Any of ``"theta"``, ``"thickness"``, ``"film_ior"``: derivatives to return.
    stokes_noise : (N,) array_like, optional
        Noise (standard deviation) of the measured S1 and S2 per pixel. When given, the model is
        the expectation of the measured ``S0 + sqrt(S1² + S2²)`` (see :func:`_measured`), which
        near normal incidence, where the light is barely polarized, sits above ``R_s``.

    Returns
    -------
    R : (N, B) ndarray, followed by one (N, B) derivative per name in ``jac``.
    """
    theta = np.ascontiguousarray(theta_rad, dtype=np.float64).ravel()
    d = np.ascontiguousarray(thickness_nm, dtype=np.float64).ravel()
    n2 = np.broadcast_to(np.asarray(film_ior, dtype=np.float64), theta.shape).ravel()
    wl = np.ascontiguousarray(wavelengths_nm, dtype=np.float64).ravel()
    n, b = theta.size, wl.size
    sig2 = None if stokes_noise is None else np.broadcast_to(
        np.asarray(stokes_noise, dtype=np.float64) ** 2, theta.shape).ravel()
    if with_p:
        sig2 = None
    cols = 2 * b if with_p else b
    outs = [np.empty((n, cols)) for _ in range(1 + len(jac))]
    rows = max(1, _CHUNK // max(cols, 1))
    use_dr = use_drjit(n * cols * (1 + len(jac)))
    for s in range(0, n, rows):
        e = min(n, s + rows)
        parts = (_dr_chunk if use_dr else _np_chunk)(theta[s:e], d[s:e], n2[s:e], float(substrate_ior), wl, jac,
                                                     None if sig2 is None else sig2[s:e], with_p)
        for o, p in zip(outs, parts):
            o[s:e] = p
    return outs[0] if not jac else tuple(outs)


def _np_chunk(theta, d, n2, n3, wl, jac, sig2=None, with_p=False):
    out = [_np_rs(theta, d, n2, n3, wl, sig2, with_p)]
    steps = {"theta": 1e-6, "thickness": 1e-4, "film_ior": 1e-6}
    for name in jac:
        h = steps[name]
        args = {"theta": theta, "thickness": d, "film_ior": n2}
        hi = dict(args, **{name: args[name] + h})
        lo = dict(args, **{name: args[name] - h})
        out.append((_np_rs(hi["theta"], hi["thickness"], hi["film_ior"], n3, wl, sig2, with_p)
                    - _np_rs(lo["theta"], lo["thickness"], lo["film_ior"], n3, wl, sig2, with_p)) / (2 * h))
    return out


def _dr_chunk(theta, d, n2, n3, wl, jac, sig2=None, with_p=False):
    import drjit as dr
    from drjit.llvm.ad import Float64

    n, b = theta.size, wl.size
    T = dr.repeat(Float64(theta), b)
    D = dr.repeat(Float64(d), b)
    N2 = dr.repeat(Float64(n2), b)
    W = dr.tile(Float64(wl), n)
    var = {"theta": T, "thickness": D, "film_ior": N2}
    for name in jac:
        dr.enable_grad(var[name])
    R_s, R_p = optics.reflectances(dr.cos(T), W, D, N2, n3)
    outs = [R_s, R_p] if with_p else [R_s if sig2 is None else _measured(R_s, R_p, dr.repeat(Float64(sig2), b), dr.sqrt)]
    grads = []
    for name in jac:
        # symbolic forward passes (keeping the graph's edges for the next one); nothing is
        # evaluated until the end, so the value and every derivative come from one kernel
        dr.forward_from(var[name], flags=dr.ADFlag.ClearVertices)
        grads.append([dr.grad(R) for R in outs])
        for R in outs:
            dr.clear_grad(R)
    outs = [dr.detach(R) for R in outs]
    dr.eval(*outs, *[g for gs in grads for g in gs])

    def arr(parts):
        return np.concatenate([x.numpy().reshape(n, b) for x in parts], axis=1)

    return [arr(outs)] + [arr(gs) for gs in grads]


def grid_sse(observed, theta_rad, thickness_nm, film_ior, substrate_ior, wavelengths_nm):
    """Sum over bands of squared residuals for K candidate (n2, d) pairs per pixel.

    Parameters
    ----------
    observed : (N, B) measured s spectra, or (N, 2 B) s then p spectra.
    theta_rad : (N,) incident angles.
    thickness_nm, film_ior : (N, K) candidates (NaN thickness: candidate skipped, SSE = inf).

    Returns
    -------
    (N, K) ndarray of ``Σ_λ (R_o(λ) - R_m(λ))²`` (Eq. 30 with the sum outside the square).
    """
    obs = np.asarray(observed, dtype=np.float64)
    theta = np.asarray(theta_rad, dtype=np.float64)
    d = np.asarray(thickness_nm, dtype=np.float64)
    n2 = np.asarray(film_ior, dtype=np.float64)
    wl = np.asarray(wavelengths_nm, dtype=np.float64)
    n, k = d.shape
    b = wl.size
    bad = ~np.isfinite(d)
    d = np.where(bad, 0.0, d)
    # the reflectances through their Airy coefficients (exact; one cosine per band): per
    # pixel when every candidate of a row has the same film index, else per candidate
    u = np.sin(theta) ** 2
    if n and np.all(n2 == n2[:, :1]):
        C = airy_coefficients(u, n2[:, 0] if np.ptp(n2) > 0 else float(n2.flat[0]), substrate_ior)
        C = {key: np.broadcast_to(v[:, None], (n, k)) for key, v in C.items()}
    else:
        C = airy_coefficients(np.repeat(u, k), n2.ravel(), substrate_ior)
        C = {key: v.reshape(n, k) for key, v in C.items()}
    out = np.empty((n, k))
    rows = max(1, _CHUNK // (b * k))
    kernel = _dr_grid if use_drjit(n * k * b) else _np_grid
    for s in range(0, n, rows):
        e = min(n, s + rows)
        out[s:e] = kernel(obs[s:e], d[s:e], {key: v[s:e] for key, v in C.items()}, wl)
    out[bad] = np.inf
    return out


def _grid_lanes(O_s, O_p, C, D, K, cos):
    """Squared residuals of one band for candidates with Airy coefficients ``C``."""
    c = cos(K * D * C["q2"])
    r = O_s - (C["a_s"] + C["e_s"] * c) / (1.0 + C["e_s"] * c)
    r2 = r * r
    if O_p is not None:
        rp = O_p - (C["a_p"] + C["e_p"] * c) / (1.0 + C["e_p"] * c)
        r2 = r2 + rp * rp
    return r2


def _np_grid(obs, d, C, wl):
    b = wl.size
    O_p = obs[:, None, b:] if obs.shape[1] == 2 * b else None
    Cb = {key: v[..., None] for key, v in C.items()}
    return np.sum(_grid_lanes(obs[:, None, :b], O_p, Cb, d[..., None], 4.0 * np.pi / wl, np.cos), axis=-1)


def _dr_grid(obs, d, C, wl):
    import drjit as dr
    from drjit.llvm import Float64, UInt32

    n, k = d.shape
    b = wl.size
    total = n * k * b
    idx = dr.arange(UInt32, total)
    pix = idx // (k * b)
    cand = idx // b
    band = idx - cand * b
    Cl = {key: dr.gather(Float64, Float64(np.ascontiguousarray(v, dtype=np.float64).ravel()), cand)
          for key, v in C.items()}
    D = dr.gather(Float64, Float64(np.ascontiguousarray(d).ravel()), cand)
    K = dr.gather(Float64, Float64(4.0 * np.pi / wl), band)
    cols = obs.shape[1]
    flat = Float64(np.ascontiguousarray(obs, dtype=np.float64).ravel())
    O_s = dr.gather(Float64, flat, pix * cols + band)
    O_p = dr.gather(Float64, flat, pix * cols + b + band) if cols == 2 * b else None
    r2 = _grid_lanes(O_s, O_p, Cl, D, K, dr.cos)
    dr.eval(r2)
    return dr.block_sum(r2, b).numpy().reshape(n, k)


def airy_coefficients(u, film_ior, substrate_ior, derivatives=False, reference_nm=500.0):
    """Per pixel, the two coefficients of each polarization's reflectance as a function of
    the film's round-trip phase Δ, and the film's normal wavenumber factor.

    For a non-absorbing film on a dielectric substrate (real Fresnel amplitudes r12, r23, no
    total reflection) the Airy sum gives ``R = (a + e cos Δ) / (1 + e cos Δ)`` with
    ``Δ = 4π q2 d / λ`` and ``q2 = sqrt(n2² - sin² θ)``: ``a`` is the reflectance at a
    quarter wave (Δ = π/2) and ``e = (R(0) - a) / (1 - R(0))``, ``R(0)`` the bare
    substrate's. Both are taken from the optics core at one wavelength (the angle dependence
    sits in them, the wavelength dependence in Δ), so a whole spectrum costs one cosine per
    band (:func:`airy_spectra`).

    Parameters
    ----------
    u : (N,) ``sin² θ``.
    film_ior, substrate_ior : float or (N,).
    derivatives : bool
        Also return the derivatives of every coefficient with respect to ``u`` (central
        differences).

    Returns
    -------
    dict of (N,) arrays ``a_s``, ``e_s``, ``a_p``, ``e_p``, ``q2`` (and ``*_u`` with
    ``derivatives``).
    """
    u = np.clip(np.asarray(u, dtype=np.float64), 0.0, 1.0)
    if np.ndim(film_ior) == 0 and u.size > _AIRY_TABLE_MIN:
        return _airy_table(float(film_ior), float(substrate_ior), float(reference_nm))(u, derivatives)
    n2 = np.broadcast_to(np.asarray(film_ior, dtype=np.float64), u.shape)
    return airy_coefficients_exact(u, n2, substrate_ior, derivatives, reference_nm, np)


def airy_coefficients_exact(u, film_ior, substrate_ior, derivatives=False, reference_nm=500.0, ops=np):
    """:func:`airy_coefficients` evaluated through the optics core, on any backend: ``ops`` is
    ``numpy`` for NumPy arrays, or ``drjit`` for Dr.Jit arrays (traced into the caller's
    kernel; ``u`` in [0, 1])."""

    def at(uu):
        c = ops.sqrt(1.0 - uu)
        q2 = ops.sqrt(film_ior * film_ior - uu)
        R0s, R0p = optics.reflectances(c, reference_nm, 0.0, film_ior, substrate_ior)
        Qs, Qp = optics.reflectances(c, reference_nm, reference_nm / (8.0 * q2), film_ior, substrate_ior)
        return {"a_s": Qs, "e_s": (R0s - Qs) / (1.0 - R0s), "a_p": Qp, "e_p": (R0p - Qp) / (1.0 - R0p), "q2": q2}

    out = at(u)
    if derivatives:
        h = 1e-6
        hi, lo = ops.minimum(u + h, 1.0 - 1e-12), ops.maximum(u - h, 0.0)
        up, dn = at(hi), at(lo)
        for k in list(out):
            out[k + "_u"] = (up[k] - dn[k]) / (hi - lo)
    return out


_AIRY_TABLE_MIN = 256
_AIRY_KEYS = ("a_s", "e_s", "a_p", "e_p", "q2")


@functools.lru_cache(maxsize=8)
def _airy_table(film_ior, substrate_ior, reference_nm):
    """:func:`airy_coefficients` of one film tabulated in ``u`` (nodes uniform in θ up to
    89.9°, 12000 of them), looked up by linear interpolation (values and derivatives: within
    about 1e-8 and 1e-3 of the optics core's)."""
    theta = np.linspace(0.0, np.radians(89.9), 12000)
    nodes = np.sin(theta) ** 2
    exact = airy_coefficients(nodes, np.full(nodes.shape, film_ior), substrate_ior, derivatives=True,
                              reference_nm=reference_nm)
    values = {k: exact[k] for k in _AIRY_KEYS}
    slopes = {k: exact[k + "_u"] for k in _AIRY_KEYS}

    def evaluate(u, derivatives):
        uu = np.minimum(u, nodes[-1])
        out = {k: np.interp(uu, nodes, v) for k, v in values.items()}
        if derivatives:
            out.update({k + "_u": np.interp(uu, nodes, v) for k, v in slopes.items()})
        return out

    return evaluate


def peak_reflectance(theta_rad, substrate_ior):
    """s reflectance at a constructive-interference peak (paper Eq. 21), from the optics core.

    At the peak ``e^{iΔ} = 1``; the Airy sum then no longer depends on the film, so this is the
    film reflectance evaluated at a thickness whose round-trip phase is ``Δ = 2π·0``.
    """
    theta = np.asarray(theta_rad, dtype=np.float64)
    return optics.reflectances(np.cos(theta), 550.0, 0.0, substrate_ior, substrate_ior)[0]


@functools.lru_cache(maxsize=8)
def _peak_table(substrate_ior):
    theta = np.radians(np.linspace(0.0, 89.99, 9000))
    return theta, peak_reflectance(theta, substrate_ior)


def angle_from_peak(peak_value, substrate_ior):
    """Invert Eq. 21 (monotone in θ): incident angle in radians from the peak reflectance.

    Values below the normal-incidence peak give 0; above the grazing value, 89.99°. NaN stays NaN.
    """
    theta, table = _peak_table(float(substrate_ior))
    v = np.asarray(peak_value, dtype=np.float64)
    out = np.interp(v, table, theta)
    return np.where(np.isnan(v), np.nan, out)
