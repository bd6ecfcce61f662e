"""Forward model of polarized camera RGB for a thin film seen in specular reflection.

A pixel whose surface normal has zenith θ and azimuth φ (camera frame of ``DESIGN.md``)
reflects the uniform, unpolarized dome towards the orthographic camera at incidence θ.
Per band the reflected Stokes vector is the specular one of
:func:`thinfilm.core.conventions.specular_stokes`: ``(S0, -P cos 2φ, -P sin 2φ)`` with
``S0 = (R_s + R_p)/2`` and ``P = (R_s - R_p)/2``. ``R_s``, ``R_p`` come from :mod:`thinfilm.bsdf.optics` (the coherent Airy model, the
project's one copy of the physics) and the camera response from
:func:`thinfilm.core.colorimetry.camera_weights` (the same white-balanced weights the capture
generator uses). Behind a polarizer at α the camera sees
``½ (S0 + S1 cos 2α + S2 sin 2α)`` per RGB channel.

Zenith is carried as ``u = sin² θ`` inside the solvers: the polarization signal grows
linearly in ``u`` near normal incidence, which keeps the inversion well conditioned there.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass, field

import numpy as np

from thinfilm.bsdf import optics
from thinfilm.core.colorimetry import DEFAULT_CAMERA, DEFAULT_ILLUMINANT, camera_weights
from thinfilm.core.conventions import malus_intensity, specular_stokes
from thinfilm.core.film import Film

__all__ = ["FilmCamera", "FilmTable", "film_table"]


@dataclass
class FilmCamera:
    """A film (:class:`thinfilm.core.film.Film`, possibly dispersive) seen by an RGB camera.

    Parameters
    ----------
    wavelengths_nm : (B,) band centres.
    film : :class:`~thinfilm.core.film.Film` (a single film; its thickness is the unknown).
    camera, illuminant : names or CSV paths, as in :mod:`thinfilm.core.colorimetry`.
    """

    wavelengths_nm: np.ndarray
    film: Film
    camera: str = DEFAULT_CAMERA
    illuminant: str = DEFAULT_ILLUMINANT
    weights: np.ndarray = field(init=False, repr=False)

    def __post_init__(self):
        if not self.film.is_single:
            raise ValueError("the RGB forward model handles a single film")
        self.wavelengths_nm = np.asarray(self.wavelengths_nm, dtype=np.float64)
        self.weights = camera_weights(self.wavelengths_nm, self.camera, self.illuminant)  # (B, 3)
        self._n2, self._k2 = self.film.layers[0].n_k(self.wavelengths_nm)
        self._n3, self._k3 = self.film.substrate_n_k(self.wavelengths_nm)

    # -- spectra ------------------------------------------------------------------------
    def spectra(self, cos_theta, thickness_nm, backend: str = "numpy"):
        """Spectral ``(S0, P)``, each of shape ``broadcast(cos_theta, thickness_nm) + (B,)``,
        with ``S0 = (R_s + R_p)/2`` and ``P = (R_s - R_p)/2``.

        ``backend``: ``"numpy"``, or ``"llvm"`` to evaluate the same optics code on Dr.Jit's
        LLVM backend in double precision (one fused, multi-threaded kernel; a few times
        faster on large grids).
        """
        c = np.asarray(cos_theta, dtype=np.float64)[..., None]
        d = np.asarray(thickness_nm, dtype=np.float64)[..., None]
        # Non-absorbing media pass k = 0 as a number (the optics core then skips it).
        k2 = self._k2 if np.any(self._k2) else 0.0
        k3 = self._k3 if np.any(self._k3) else 0.0
        if backend == "llvm":
            from drjit.llvm import Float64

            arrays = np.broadcast_arrays(c, self.wavelengths_nm, d, self._n2, self._n3, k3, k2)
            jit = [Float64(np.ascontiguousarray(a).ravel()) for a in arrays]
            if np.isscalar(k3):
                jit[5] = 0.0
            if np.isscalar(k2):
                jit[6] = 0.0
            Rs, Rp = optics.reflectances(*jit[:6], float(self.film.ext_ior), jit[6])
            Rs, Rp = np.asarray(Rs).reshape(arrays[0].shape), np.asarray(Rp).reshape(arrays[0].shape)
        elif backend == "numpy":
            Rs, Rp = optics.reflectances(c, self.wavelengths_nm, d, self._n2, self._n3, k3,
                                         self.film.ext_ior, k2)
        else:
            raise ValueError(f"backend: expected 'numpy' or 'llvm', got {backend!r}")
        return 0.5 * (Rs + Rp), 0.5 * (Rs - Rp)

    def rgb_s0_p(self, cos_theta, thickness_nm, chunk: int = 65536, backend: str = "numpy"):
        """Camera-RGB ``(S0, P)``, each ``shape + (3,)`` (the band axis integrated out).
        ``backend``: see :meth:`spectra`."""
        c, d = np.broadcast_arrays(np.asarray(cos_theta, dtype=np.float64),
                                   np.asarray(thickness_nm, dtype=np.float64))
        shape = c.shape
        c, d = c.ravel(), d.ravel()
        S0 = np.empty((c.size, 3))
        P = np.empty((c.size, 3))
        for i in range(0, c.size, chunk):
            s0, p = self.spectra(c[i:i + chunk], d[i:i + chunk], backend)
            S0[i:i + chunk] = s0 @ self.weights
            P[i:i + chunk] = p @ self.weights
        return S0.reshape(shape + (3,)), P.reshape(shape + (3,))

    def rgb_stokes(self, zenith_deg, azimuth_deg, thickness_nm):
        """Camera-RGB Stokes ``(S0, S1, S2)`` in the image frame, each ``shape + (3,)``
        (:func:`thinfilm.core.conventions.specular_stokes` of the camera RGB of R_s and R_p)."""
        S0, P = self.rgb_s0_p(np.cos(np.radians(zenith_deg)), thickness_nm)
        return specular_stokes(S0 + P, S0 - P, azimuth_deg)

    def polarized_rgb(self, zenith_deg, azimuth_deg, thickness_nm, angles_deg):
        """Noise-free camera RGB behind the polarizer at each angle: ``{angle: shape + (3,)}``."""
        images = malus_intensity(*self.rgb_stokes(zenith_deg, azimuth_deg, thickness_nm), angles_deg)
        return dict(zip(angles_deg, images))


# ------------------------------------------------------------------------------------------
# A smooth tabulation of the model for fast inversion
# ------------------------------------------------------------------------------------------

def _not_a_knot_coefficients(values: np.ndarray, axis: int) -> np.ndarray:
    """Coefficients of the uniform cubic B-spline interpolating ``values`` at equally spaced
    nodes along ``axis`` (n nodes → n + 2 coefficients), with the not-a-knot end conditions
    (third derivative continuous at the second and the second-to-last node), so the
    interpolation error is O(h⁴) up to the ends of the table.

    The system, ordered [first end condition; value at node 0 … n-1; last end condition],
    is banded (4 below, 4 above the diagonal); the value at node i is
    ``(a[i-1] + 4 a[i] + a[i+1]) / 6`` with ``a`` indexed from -1.
    """
    from scipy.linalg import solve_banded

    v = np.moveaxis(np.asarray(values, dtype=np.float64), axis, 0)
    n = v.shape[0]
    m = n + 2
    ab = np.zeros((9, m))                       # ab[4 + i - j, j] = M[i, j]

    def put(i, j, x):
        ab[4 + i - j, j] = x

    for j, x in enumerate((-1.0, 4.0, -6.0, 4.0, -1.0)):
        put(0, j, x)
        put(m - 1, m - 5 + j, x)
    for i in range(n):
        for j, x in ((i, 1.0 / 6.0), (i + 1, 4.0 / 6.0), (i + 2, 1.0 / 6.0)):
            put(i + 1, j, x)
    rhs = np.zeros((m,) + v.shape[1:])
    rhs[1:-1] = v
    a = solve_banded((4, 4), ab, rhs.reshape(m, -1)).reshape(rhs.shape)
    return np.moveaxis(a, 0, axis)


def _bspline_weights(x, x0: float, h: float, n: int):
    """Index of the first of the four coefficients, the basis weights (N, 4) and their
    derivatives (N, 4) (per unit of x) of the uniform cubic B-spline at ``x``."""
    s = (np.asarray(x, dtype=np.float64) - x0) / h
    i = np.clip(np.floor(s), 0, n - 2).astype(np.intp)
    t = s - i
    t2 = t * t
    t3 = t2 * t
    w = np.stack([(1.0 - t) ** 3, 3.0 * t3 - 6.0 * t2 + 4.0, -3.0 * t3 + 3.0 * t2 + 3.0 * t + 1.0, t3],
                 axis=-1) * (1.0 / 6.0)
    dw = np.stack([-(1.0 - t) ** 2, 3.0 * t2 - 4.0 * t, -3.0 * t2 + 2.0 * t + 1.0, t2], axis=-1) * (0.5 / h)
    return i, w, dw


@dataclass
class FilmTable:
    """The camera-RGB model of a :class:`FilmCamera` as a bicubic spline in
    ``(cos θ, thickness)``, built from values of the optics core on a regular grid.

    Two quantities per RGB channel are tabulated: ``S0`` and ``Q = P / sin² θ``. Both are
    smooth (analytic) functions of ``cos θ`` on the whole domain, normal incidence included
    (``P`` vanishes like ``sin² θ`` there), so the polarized model ``½ (S0 - Q v·a)`` of
    :mod:`.rgb_invert` has well-defined derivatives everywhere. Evaluation (:meth:`s0_q`)
    costs a 4 × 4 gather per point and gives exact derivatives of the spline.

    Use :func:`film_table` to build one.

    Attributes
    ----------
    cos_lo, cos_step : first node and spacing of the ``cos θ`` grid.
    thickness_lo_nm, thickness_step_nm : the same for the thickness grid.
    coef : (Nc + 2, Nd + 2, 6) B-spline coefficients of (S0_R, S0_G, S0_B, Q_R, Q_G, Q_B).
    cos_range, thickness_range_nm : the domain the table was built for (queries are meant to
        stay inside it; outside, the end polynomials are extended).
    """

    cos_lo: float
    cos_step: float
    n_cos: int
    thickness_lo_nm: float
    thickness_step_nm: float
    n_thickness: int
    coef: np.ndarray
    cos_range: tuple
    thickness_range_nm: tuple

    #: largest table (bytes) whose 4 × 4 coefficient blocks are stored contiguously
    BLOCKS_MAX_BYTES = 256 * 2 ** 20

    def __post_init__(self):
        # Every 4 × 4 block of coefficients stored contiguously (16 times the coefficients'
        # memory): one row gather per point instead of sixteen.
        from numpy.lib.stride_tricks import sliding_window_view

        self._blocks = None
        if 16 * self.coef.nbytes <= self.BLOCKS_MAX_BYTES:
            w = sliding_window_view(self.coef, (4, 4), axis=(0, 1))            # (nc-3, nd-3, 6, 4, 4)
            self._blocks = np.ascontiguousarray(w.transpose(0, 1, 3, 4, 2)).reshape(-1, 96)

    def s0_q(self, cos_theta, thickness_nm, derivatives: bool = False):
        """Spline values of ``S0`` and ``Q`` (each (N, 3)) at 1-D arrays of points; with
        ``derivatives``, also ``∂/∂cos θ`` and ``∂/∂d`` (per nm) of both: a tuple
        ``(S0, Q, dS0_dc, dQ_dc, dS0_dd, dQ_dd)``."""
        c = np.asarray(cos_theta, dtype=np.float64).ravel()
        d = np.asarray(thickness_nm, dtype=np.float64).ravel()
        n = c.size
        ic, wc, dwc = _bspline_weights(c, self.cos_lo, self.cos_step, self.n_cos)
        jd, wd, dwd = _bspline_weights(d, self.thickness_lo_nm, self.thickness_step_nm, self.n_thickness)
        if self._blocks is not None:
            G = np.take(self._blocks, ic * (self.n_thickness - 1) + jd, axis=0).reshape(n, 16, 6)
        else:
            nd = self.n_thickness + 2
            k = (ic * nd + jd)[:, None] + (np.arange(4)[:, None] * nd + np.arange(4)[None, :]).ravel()
            G = np.take(self.coef.reshape(-1, 6), k, axis=0)
        W = np.empty((n, 3 if derivatives else 1, 4, 4))
        W[:, 0] = wc[:, :, None] * wd[:, None, :]
        if derivatives:
            W[:, 1] = dwc[:, :, None] * wd[:, None, :]
            W[:, 2] = wc[:, :, None] * dwd[:, None, :]
        f = np.matmul(W.reshape(n, -1, 16), G)                              # (n, 1 or 3, 6)
        if not derivatives:
            return f[:, 0, :3], f[:, 0, 3:]
        return f[:, 0, :3], f[:, 0, 3:], f[:, 1, :3], f[:, 1, 3:], f[:, 2, :3], f[:, 2, 3:]


#: grid size from which :func:`film_table` evaluates the optics core on Dr.Jit's LLVM backend
#: even when Dr.Jit is not loaded yet
LLVM_MIN_NODES = 40000


def _llvm_available() -> bool:
    try:
        import drjit as dr

        return bool(dr.has_backend(dr.JitBackend.LLVM))
    except Exception:  # no Dr.Jit, or no LLVM library on this machine
        return False


def film_table(model: FilmCamera, thickness_range_nm, zenith_max_deg: float = 89.5,
               phase_step_rad: float = 0.35, backend: str = "auto") -> FilmTable:
    """Tabulate ``model`` (through the optics core) as a :class:`FilmTable`.

    The grid is fine enough that the film's round-trip phase ``4π n2 cos θ2 d / λ`` changes
    by at most ``phase_step_rad`` between neighbouring nodes, at the shortest wavelength and
    the largest film index, both along the thickness and along ``cos θ`` (where the phase
    changes fastest at the thickest film). With the default step the spline reproduces the
    optics core to about 10⁻⁵ of the reflectance (errors scale as the step to the fourth).

    ``backend``: how the optics core is evaluated on the grid, ``"numpy"``, ``"llvm"``
    (Dr.Jit, double precision) or ``"auto"``: LLVM when Dr.Jit has it and either Dr.Jit is
    already loaded or the grid has more than :data:`LLVM_MIN_NODES` nodes.

    The ``cos θ`` nodes are placed half a step either side of normal incidence (never on
    it), since ``Q = P / sin² θ`` is computed from the optics core's ``P`` at each node; the
    grid reaches a step beyond the domain at both ends.
    """
    lo, hi = (float(v) for v in thickness_range_nm)
    lam_min = float(np.min(model.wavelengths_nm))
    n2_max = float(np.max(model._n2))
    k_max = 4.0 * np.pi * n2_max / lam_min                    # dΔ/dd at most (rad per nm)
    h_d = phase_step_rad / k_max
    n_d = max(4, int(np.ceil((hi - lo) / h_d)) + 1)
    h_d = (hi - lo) / (n_d - 1) if hi > lo else h_d
    # dΔ/dcos θ = (4π d / λ) cos θ / q2 with q2 = sqrt(n2² - sin² θ) > cos θ: at most 4π d / λ.
    kc = 4.0 * np.pi * max(abs(hi), abs(lo), 1.0) / lam_min
    h_c = min(phase_step_rad / kc, 0.01)
    c_min = float(np.cos(np.radians(zenith_max_deg)))
    # nodes 1 + h/2 - k h, down to below c_min
    n_c = max(4, int(np.ceil((1.0 + 0.5 * h_c - c_min) / h_c)) + 2)
    c_nodes = 1.0 + 0.5 * h_c - h_c * np.arange(n_c)[::-1]
    d_nodes = lo + h_d * np.arange(n_d)
    if backend == "auto":
        # Dr.Jit's import and LLVM start-up (~0.3 s) pay off on large grids, or at once when
        # the process already has Dr.Jit loaded (e.g. next to Mitsuba).
        loaded = "drjit" in sys.modules
        backend = "llvm" if (loaded or n_c * n_d > LLVM_MIN_NODES) and _llvm_available() else "numpy"
    S0, P = model.rgb_s0_p(c_nodes[:, None], d_nodes[None, :], chunk=16384, backend=backend)   # (Nc, Nd, 3)
    u = 1.0 - c_nodes ** 2
    data = np.concatenate([S0, P / u[:, None, None]], axis=-1)     # (Nc, Nd, 6)
    coef = _not_a_knot_coefficients(_not_a_knot_coefficients(data, 0), 1)
    return FilmTable(float(c_nodes[0]), h_c, n_c, lo, h_d, n_d, np.ascontiguousarray(coef), (c_min, 1.0), (lo, hi))
