"""Polarized camera RGB of a thin film seen in specular reflection, as the RGB methods see it.

A pixel whose surface normal has zenith θ and azimuth φ (:mod:`thinfilm.core.conventions`)
reflects the uniform, unpolarized dome towards the orthographic camera at incidence θ. Every
value comes from the observation model (:class:`thinfilm.core.model.ObservationModel`, the
optics core in a Dr.Jit kernel) on the rig's bands, with the generator's band integration
(the rig's passband), camera and illuminant: per RGB channel ``S0 = (R_s + R_p)/2`` and
``P = (R_s - R_p)/2`` integrated over the bands with the white-balanced camera weights, the
Stokes vector ``(S0, -P cos 2φ, -P sin 2φ)`` in the image frame, and
``½ (S0 + S1 cos 2α + S2 sin 2α)`` behind a polarizer at α.

The inversion (:mod:`.rgb_invert`) reads the model through a bicubic tabulation in
``(cos θ, thickness)`` (:class:`FilmTable`, :func:`film_table`), whose values are the
model's. Zenith is carried as ``u = sin² θ`` inside the solvers: the polarization signal
grows linearly in ``u`` near normal incidence, which keeps the inversion well conditioned
there.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from thinfilm.core.colorimetry import DEFAULT_CAMERA, DEFAULT_ILLUMINANT
from thinfilm.core.conventions import malus_intensity
from thinfilm.core.film import Film
from thinfilm.core.model import ObservationModel, Parametrization, PixelState, Rig

__all__ = ["FilmCamera", "FilmTable", "film_table", "INCIDENCE"]


def _incidence(x, fixed, layers, dr):
    return PixelState(x[0], fixed.get("c2", 1.0), fixed.get("s2", 0.0), fixed.get("light", 1.0), [x[1]], [])


#: the model's unknowns of a table node: ``(cos θ, thickness_nm)`` in the plane of incidence of
#: the Stokes reference axis (``S1 = P``, ``S2 = 0``). ``cos θ`` is taken as given, without
#: clipping: the table's nodes reach half a step beyond normal incidence, where the optics
#: core's expressions continue analytically (``sin² θ < 0``), so that the spline's end
#: conditions see a smooth function
INCIDENCE = Parametrization("incidence", ("cos_theta", "thickness_nm"), _incidence)


@dataclass
class FilmCamera:
    """A film (:class:`thinfilm.core.film.Film`, possibly dispersive) seen by an RGB camera
    through the bands of a rig.

    Parameters
    ----------
    wavelengths_nm : (B,) band centres.
    film : :class:`~thinfilm.core.film.Film` (a single film; its thickness is the unknown).
    camera, illuminant : names or CSV paths, as in :mod:`thinfilm.core.colorimetry`.
    band_fwhm_nm, passband : the bands' passband (:class:`thinfilm.core.model.Rig`; 0: point
        samples at the centres). :meth:`of_rig` takes them from a dataset's rig.
    backend : Dr.Jit backend of the model, ``"llvm"`` or ``"cuda"``.

    Attributes
    ----------
    rig : the :class:`~thinfilm.core.model.Rig` of the bands, camera and illuminant.
    model : the :class:`~thinfilm.core.model.ObservationModel` (double precision).
    """

    wavelengths_nm: np.ndarray
    film: Film
    camera: str = DEFAULT_CAMERA
    illuminant: str = DEFAULT_ILLUMINANT
    band_fwhm_nm: float = 0.0
    passband: str = "gaussian"
    backend: str = "llvm"
    rig: Rig = field(init=False, repr=False)
    model: ObservationModel = field(init=False, repr=False)

    def __post_init__(self):
        if not self.film.is_single:
            raise ValueError("the RGB forward model handles a single film")
        self.wavelengths_nm = np.asarray(self.wavelengths_nm, dtype=np.float64)
        self.rig = Rig(wavelengths_nm=tuple(self.wavelengths_nm), band_fwhm_nm=float(self.band_fwhm_nm),
                       passband=self.passband, camera=self.camera, illuminant=self.illuminant)
        self.model = ObservationModel(self.rig, self.film, backend=self.backend, precision="double")

    @classmethod
    def of_rig(cls, rig: Rig, film: Film, backend: str = "llvm") -> "FilmCamera":
        """The camera of a rig (:meth:`thinfilm.core.model.Rig.of_dataset`): its bands,
        passband, camera and illuminant."""
        return cls(np.asarray(rig.wavelengths_nm), film, rig.camera, rig.illuminant, rig.band_fwhm_nm,
                   rig.passband, backend)

    # -- spectra ------------------------------------------------------------------------
    def spectra(self, cos_theta, thickness_nm, chunk: int = 1 << 14):
        """Band ``(S0, P)``, each of shape ``broadcast(cos_theta, thickness_nm) + (B,)``, with
        ``S0 = (R_s + R_p)/2`` and ``P = (R_s - R_p)/2`` integrated over each band's passband."""
        c, d = self._nodes(cos_theta, thickness_nm)
        B = self.wavelengths_nm.size
        S0, P = np.empty((c.size, B)), np.empty((c.size, B))
        for i in range(0, c.size, chunk):
            v = self.model.evaluate("stokes", np.stack([c[i:i + chunk], d[i:i + chunk]], axis=1), INCIDENCE)
            S0[i:i + chunk], P[i:i + chunk] = v[:, :B], v[:, B:2 * B]
        shape = np.broadcast_shapes(np.shape(cos_theta), np.shape(thickness_nm))
        return S0.reshape(shape + (B,)), P.reshape(shape + (B,))

    def rgb_s0_p(self, cos_theta, thickness_nm, chunk: int = 1 << 18):
        """Camera-RGB ``(S0, P)``, each ``shape + (3,)`` (the bands integrated out with the
        camera weights): the model's polarizer images at 0° and 90° in the plane of incidence,
        ``S0 = I(0°) + I(90°)``, ``P = I(0°) - I(90°)``."""
        c, d = self._nodes(cos_theta, thickness_nm)
        S0, P = np.empty((c.size, 3)), np.empty((c.size, 3))
        for i in range(0, c.size, chunk):
            v = self.model.evaluate("polarized_rgb", np.stack([c[i:i + chunk], d[i:i + chunk]], axis=1),
                                    INCIDENCE, angles_deg=(0, 90))
            S0[i:i + chunk], P[i:i + chunk] = v[:, :3] + v[:, 3:], v[:, :3] - v[:, 3:]
        shape = np.broadcast_shapes(np.shape(cos_theta), np.shape(thickness_nm))
        return S0.reshape(shape + (3,)), P.reshape(shape + (3,))

    @staticmethod
    def _nodes(cos_theta, thickness_nm):
        c, d = np.broadcast_arrays(np.asarray(cos_theta, dtype=np.float64), np.asarray(thickness_nm, dtype=np.float64))
        return c.ravel(), d.ravel()

    def rgb_stokes(self, zenith_deg, azimuth_deg, thickness_nm):
        """Camera-RGB Stokes ``(S0, S1, S2)`` in the image frame, each ``shape + (3,)``: the
        model's band Stokes cube of the normals ``(zenith, azimuth)`` through the camera
        weights."""
        t, p = np.radians(np.asarray(zenith_deg, dtype=np.float64)), np.radians(np.asarray(azimuth_deg, dtype=np.float64))
        t, p, d = np.broadcast_arrays(t, p, np.asarray(thickness_nm, dtype=np.float64))
        normals = np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], axis=-1).reshape(-1, 3)
        s = self.model.stokes(normals, d.ravel())
        W = self.rig.camera_weights()
        return tuple((s[k] @ W).reshape(t.shape + (3,)) for k in ("S0", "S1", "S2"))

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
    ``(cos θ, thickness)``, built from values of the observation model on a regular grid.

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


def film_table(model: FilmCamera, thickness_range_nm, zenith_max_deg: float = 89.5,
               phase_step_rad: float = 0.35) -> FilmTable:
    """Tabulate ``model`` (the observation model's camera RGB) as a :class:`FilmTable`.

    The grid is fine enough that the film's round-trip phase ``4π n2 cos θ2 d / λ`` changes
    by at most ``phase_step_rad`` between neighbouring nodes, at the shortest wavelength the
    bands integrate and the largest film index, both along the thickness and along ``cos θ``
    (where the phase changes fastest at the thickest film). With the default step the spline
    reproduces the model to about 10⁻⁵ of the reflectance (errors scale as the step to the
    fourth).

    The ``cos θ`` nodes are placed half a step either side of normal incidence (never on
    it), since ``Q = P / sin² θ`` is computed from the model's ``P`` at each node; the grid
    reaches a step beyond the domain at both ends (:data:`INCIDENCE`).
    """
    lo, hi = (float(v) for v in thickness_range_nm)
    lam = model.model.sub_nm                                  # the wavelengths the bands integrate
    lam_min = float(np.min(lam))
    n2_max = float(np.max(model.film.layers[0].n_k(lam)[0]))
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
    S0, P = model.rgb_s0_p(c_nodes[:, None], d_nodes[None, :])      # (Nc, Nd, 3)
    u = 1.0 - c_nodes ** 2
    data = np.concatenate([S0, P / u[:, None, None]], axis=-1)     # (Nc, Nd, 6)
    coef = _not_a_knot_coefficients(_not_a_knot_coefficients(data, 0), 1)
    return FilmTable(float(c_nodes[0]), h_c, n_c, lo, h_d, n_d, np.ascontiguousarray(coef), (c_min, 1.0), (lo, hi))
