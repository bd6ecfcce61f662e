"""Film thickness (and optionally index) from measured single reflection spectra.

A spectrometer reading of a thin film is modelled as

    I(λ) = B(λ) + G(λ) · R(λ; d, n2, θ) + noise,

with ``R`` the unpolarized reflectance ``(R_s + R_p)/2`` of the film (thickness ``d``, index
``n2(λ)``) on its substrate at the angle of incidence ``θ``, given with its derivatives (by
automatic differentiation) by the project's observation model
(:class:`thinfilm.core.model.Spectrometer`), ``B`` a background (dark current, stray light) and ``G`` the
instrument response (lamp × optics × detector). ``B`` and ``G`` are unknown unless measured:

* a **background** spectrum (a black film, a dark reading) fixes ``B``; without one, ``B`` is a
  straight line in ``1/λ`` (:data:`BACKGROUND_DEGREE`);
* a **reference** spectrum of a white (spectrally flat) reflector fixes the shape of ``G``: then
  ``G = s · (I_ref − B)`` with one free scale ``s`` (the reference's reflectance level need not be
  known; without a background the reference's own offset is the fitted ``B``, so
  ``G = s · I_ref + (a line in 1/λ)``);
* without a reference ``G`` is a positive polynomial in ``1/λ`` whose degree is chosen per
  spectrum (below).

For a given ``d`` (and ``n2``) the model is linear in the coefficients of ``B`` and ``G``, so they
are solved in closed form (variable projection): the profile cost ``c(d) = ‖(1 − P_A(d)) y‖²``,
``A(d)`` the design matrix ``[B basis, G basis · R(d)]``, depends on ``d`` alone.

Identifiability. The thickness is in the fringes; a response flexible enough to draw fringes of
its own could absorb them. A polynomial of degree ``p`` in ``1/λ`` cannot follow much more than
``p / π`` oscillation periods across the range, so for a candidate thickness with ``N``
fringes in the range the response's degree is capped at ``0.75 π N`` (at least
:data:`GAIN_DEGREE_MIN`, at most :data:`GAIN_DEGREE_MAX`): smoother than the film's own
features. Within the cap the degree is chosen by the Bayesian information criterion
``BIC = n ln(RSS/n) + p ln n``, which is also what compares candidates of different degrees. A fit
is *plausible* when its response stays above 5 % of its maximum and its background does not
fall below −5 % of the spectrum's maximum (a response that goes negative flips the fringes: the
half-order-shifted false solutions; a strongly negative background lets a thinner film's
reflectance, scaled up and shifted down, pass for a thicker one).

Algorithm (the user chooses no method and no interference order):

1. **every order at once**: the profile over a thickness grid covering the range, step
   ``λ_min / (8 n2 cos θ2)`` (an eighth of the spacing between neighbouring orders at the
   shortest wavelength), for all spectra sharing a wavelength grid in one batch: the design
   matrices are shared (one QR per grid thickness, the spectra projected together), and each
   grid thickness is polished by one Gauss-Newton step of the variable-projection problem, so
   that a grid point a fraction of a fringe off the truth still ranks it first however high
   the signal-to-noise ratio;
2. the two lowest local minima of the profile and the lowest plausible one are **refined** by
   Levenberg-Marquardt (the project's one solver, :func:`thinfilm.reconstruction.lm.levenberg_marquardt`)
   on the variable-projection residual (Kaufman's Jacobian, all spectra batched) over ``d`` and, with ``fit_film_ior``, an offset ``δ`` added to the film's
   dispersion ``n2(λ) + δ``. The lowest BIC wins, unless it is implausible and a plausible
   candidate comes within 25 of it. With ``fit_film_ior`` the valley of equal optical
   thickness ``n2 d`` (which the fringes fix far better than ``n2`` and ``d`` apart) is then
   walked over ±15 % in ``n2``, and the fit moves to its best point if that is better;
3. **uncertainty**, the sum of two terms:

   * *local*: from the Jacobian of the projected residual ``J̃ = (1 − P_A) ∂(A c)/∂θ`` (the
     linear coefficients profiled out, so their correlation with ``d`` and ``n2`` is
     included): ``Cov(θ) = (J̃ᵀJ̃)⁻¹ J̃ᵀ Σ J̃ (J̃ᵀJ̃)⁻¹`` with ``Σ_ij = s² ρ^|i−j|``, ``s² =
     RSS / (n − p)`` the residual variance (``n`` points, ``p`` parameters) and ``ρ`` the lag-1
     autocorrelation of the residuals (clipped to ``[0, 0.95]``). For white noise (``ρ = 0``)
     this is the textbook ``s² (J̃ᵀJ̃)⁻¹``; a smoothed spectrum or a smooth misfit of the
     response makes the residuals correlated, and the sandwich keeps sigma from shrinking with
     oversampling. It is computed with the capped response and with the response the data
     ask for at the fitted thickness (uncapped, by BIC), and the larger is kept;
   * *global*: the second moment of the thickness about the fit over the grid thicknesses
     (and, with ``fit_film_ior``, of thickness and index over the valley walk), each weighted
     by its evidence ``exp(−ΔBIC/2)`` summed over every response degree, ``ΔBIC`` scaled by
     ``(1 − ρ)/(1 + ρ)`` (the effective share of independent samples). Negligible when the
     thickness is well determined; large when other thicknesses explain the spectrum about as
     well with some smooth response.

Films with less than about one fringe across the range (thinner than ``1 / (2 n2 (1/λ_min −
1/λ_max))``, about 280 nm for a soap film over 400-850 nm) have their thickness in the broad
shape of ``R``, which a free response and background can mimic. The fit does not hide
that: the global term then makes sigma comparable to the thickness. A background and a white
reference pin the response and recover such films to well under 1 %.

The instrument. ``R`` in the model is what the spectrometer reads, not the film's point
reflectance: averaged over a Gaussian spread of the thickness over the light spot (standard
deviation ``s``), seen through a Gaussian instrument line (full width at half maximum ``w``)
and integrated over each pixel's width: the observation model is evaluated on a fine uniform
wavelength grid (resolving the thinnest fringes in range) and a table of thicknesses (0.4 rad
of phase apart at the shortest wavelength, interpolated as cubic Hermite with the model's own
derivatives), averaged over the spread along the table and read through a sparse line-shape
operator. Both lower the fringe contrast, the line width most at short wavelengths for thick
films, and without them a thick film's washed-out fringes are read as another order or a
thinner film. ``s`` and ``w`` are given (``thickness_spread_nm``, ``resolution_nm``) or chosen
by the fit from the grid :data:`SPREADS_NM` × :data:`RESOLUTIONS_NM`: the profile of step 1 is
computed for every setting; a setting is a reading of a thickness only where it leaves a fringe
contrast of at least 0.5 and a spread of at most a tenth of the thickness. At the winner the
thickness is refined at every setting and at half steps around the best one, and the result is
their evidence-weighted mean (BIC differences divided by the reduced chi-square where that
exceeds 1), the weighted spread entering sigma. With ``fit_film_ior`` the instrument is not
fitted (it trades against the index): given values or none.

The runner-up: the best refined candidate a quarter of the spacing between neighbouring orders
or more from the winner, reported with its chi-square and ΔBIC; its evidence-weighted squared
distance enters the variance (where the two fit about equally, sigma spans both).

Examples
--------
>>> import numpy as np
>>> lam = np.linspace(450.0, 800.0, 500)
>>> film = FilmModel(film_ior=1.33, substrate_ior=1.0)         # a soap film in air
>>> raw = 0.02 + (1.0 + lam / 1000.0) * film.reflectance(lam, 1200.0)
>>> fit = fit_spectra(lam, raw, film)[0]
>>> round(fit.thickness_nm, 1)
1200.0
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from thinfilm.bsdf.materials import Constant, Tabulated, as_dispersion
from thinfilm.core.film import Film, Layer
from thinfilm.core.model import Spectrometer

from .lm import levenberg_marquardt

__all__ = [
    "FilmModel",
    "SpectrumFit",
    "fit_spectra",
    "BACKGROUND_DEGREE",
    "GAIN_DEGREE_MIN",
    "GAIN_DEGREE_MAX",
    "DEFAULT_THICKNESS_RANGE_NM",
    "MIN_POINTS",
    "MAX_VALUE",
    "estimated_memory_bytes",
    "instrument_reflectance",
    "SPREADS_NM",
    "RESOLUTIONS_NM",
]

BACKGROUND_DEGREE = 1
"""Degree of the background polynomial in ``1/λ`` when no background spectrum is given."""

GAIN_DEGREE_MIN = 2
"""Degree the response polynomial may always reach (without a reference)."""

GAIN_DEGREE_MAX = 8
"""Highest degree of the response polynomial (without a reference)."""

DEFAULT_THICKNESS_RANGE_NM = (1.0, 10000.0)
"""Thicknesses searched when none are given (capped where the sampling cannot resolve fringes)."""

MIN_POINTS = 10
"""Fewest samples a spectrum may have in the fitted wavelength range."""

SPREADS_NM = (0.0, 25.0, 50.0)
"""Thickness spreads over the light spot (standard deviations, nm) tried when none is given."""

RESOLUTIONS_NM = (0.0, 5.0, 10.0)
"""Instrument line widths (full width at half maximum, nm) tried when none is given; 0 is the
pixel's own width alone."""

_CANDIDATES = 4  # lowest local minima of the profile refined per spectrum ...
_CANDIDATES_POSITIVE = 1  # ... and lowest among grid thicknesses with a plausible response
_PRE_ITERATIONS = 3  # Levenberg-Marquardt iterations every start gets before the best are kept
_COARSE = 64  # wavelengths at which the response's positivity is checked
_MAX_FINE = 200_000  # most samples of the fine wavelength grid
_FWHM = 2.0 * np.sqrt(2.0 * np.log(2.0))  # full width at half maximum of a unit Gaussian
_MIN_CONTRAST = 0.5  # fringe contrast an instrument setting must leave (see _Problem.allowed)
_MAX_RELATIVE_SPREAD = 0.1  # largest thickness spread, relative to the thickness
_SPREAD_NODES = 9  # Gauss-Hermite nodes over the thickness spread (with a fitted index)
_CAP_FACTOR = 0.75  # response degree <= this × π × fringes (see gain_columns)
_GAIN_FLOOR = 0.05  # a fitted response must stay above 5 % of its maximum ...
_GAIN_FLOOR_GRID = -0.25  # ... on the coarse grid, where it may dip a little below zero
_PLAUSIBLE_MARGIN = 25.0  # BIC a plausible fit may lose to an implausible one and still win
_BACKGROUND_FLOOR = 0.05  # a fitted background may not fall below -5 % of the spectrum's maximum


# ---------------------------------------------------------------------------
# Film model
# ---------------------------------------------------------------------------


@dataclass(frozen=True)
class FilmModel:
    """The known optics of the measurement: film dispersion, substrate, angle.

    Parameters
    ----------
    film_ior :
        Film index: anything :func:`thinfilm.bsdf.materials.as_dispersion` accepts (a number, a
        material name, a ``Cauchy`` model ...); its extinction is used when it has one.
    substrate_ior :
        Substrate index, same forms (``1.0`` for a free-standing film in air).
    substrate_k : float, optional
        Substrate extinction ``k3 >= 0``; default: the substrate model's own (0 for a number).
    angle_deg : float
        Angle of incidence in the exterior medium, degrees (unpolarized light).
    ext_ior : float
        Exterior index ``n1`` (1 for air).
    """

    film_ior: object
    substrate_ior: object
    substrate_k: float | None = None
    angle_deg: float = 0.0
    ext_ior: float = 1.0
    _spectrometers: dict = field(default_factory=dict, init=False, repr=False, compare=False)

    def __post_init__(self):
        object.__setattr__(self, "film_ior", as_dispersion(self.film_ior))
        object.__setattr__(self, "substrate_ior", as_dispersion(self.substrate_ior))
        if not (np.isfinite(self.angle_deg) and 0.0 <= self.angle_deg < 90.0):
            raise ValueError(f"angle_deg must be in [0, 90), got {self.angle_deg}")

    def film(self) -> Film:
        """The film as the observation model takes it (:class:`thinfilm.core.film.Film`), with
        ``substrate_k`` replacing the substrate's own extinction where given."""
        sub = self.substrate_ior
        if self.substrate_k is not None:
            k = float(self.substrate_k)
            if isinstance(sub, Constant):
                sub = Constant(sub.n, k)
            elif isinstance(sub, Tabulated):
                sub = replace(sub, k_values=(k,) * len(sub.n_values))
            else:
                raise ValueError("substrate_k needs a numeric or tabulated substrate index")
        return Film((Layer(self.film_ior),), sub, float(self.ext_ior))

    def indices(self, wavelengths_nm):
        """``(n2, k2, n3, k3)`` at the given wavelengths (NumPy arrays)."""
        lam = np.asarray(wavelengths_nm, dtype=np.float64)
        n2 = np.asarray(self.film_ior(lam), dtype=np.float64)
        k2 = np.asarray(self.film_ior.extinction(lam), dtype=np.float64)
        n3 = np.asarray(self.substrate_ior(lam), dtype=np.float64)
        if self.substrate_k is None:
            k3 = np.asarray(self.substrate_ior.extinction(lam), dtype=np.float64)
        else:
            k3 = np.full_like(lam, float(self.substrate_k))
        return n2, k2, n3, k3

    def reflectance(self, wavelengths_nm, thickness_nm, film_ior_offset=0.0):
        """Unpolarized reflectance ``(R_s + R_p)/2`` (:class:`thinfilm.core.model.Spectrometer`);
        arguments broadcast (NumPy).

        ``film_ior_offset`` is added to the film's real index at every wavelength.
        """
        lam, d, off = np.broadcast_arrays(*(np.asarray(v, dtype=np.float64)
                                            for v in (wavelengths_nm, thickness_nm, film_ior_offset)))
        grid, at = np.unique(lam, return_inverse=True)
        pairs, row = np.unique(np.stack([d.ravel(), off.ravel()], axis=1), axis=0, return_inverse=True)
        R = self.spectrometer(grid).reflectance(pairs[:, 0], pairs[:, 1])
        return R[row.ravel(), at.ravel()].reshape(lam.shape)

    def __getstate__(self):  # the kept models hold Dr.Jit arrays: not pickled
        return {**self.__dict__, "_spectrometers": {}}

    def spectrometer(self, wavelengths_nm) -> Spectrometer:
        """The observation model of this measurement at the given wavelengths (kept for reuse)."""
        lam = np.asarray(wavelengths_nm, dtype=np.float64).ravel()
        key = lam.tobytes()
        if key not in self._spectrometers:
            if len(self._spectrometers) >= 8:
                self._spectrometers.clear()
            self._spectrometers[key] = Spectrometer(self.film(), lam, self.angle_deg)
        return self._spectrometers[key]

    def phase_index(self, wavelengths_nm, film_ior_offset=0.0):
        """``n2 cos θ2 = sqrt(n2² − n1² sin² θ1)``: the round-trip phase is ``4π d · this / λ``."""
        n2 = self.indices(wavelengths_nm)[0] + film_ior_offset
        s = self.ext_ior * np.sin(np.radians(self.angle_deg))
        return np.sqrt(np.maximum(n2 * n2 - s * s, 1e-6))

    def fringes(self, wavelengths_nm, thickness_nm, film_ior_offset=0.0):
        """Interference fringes (periods of ``R``) between the ends of the wavelength range."""
        lam = np.asarray(wavelengths_nm, dtype=np.float64)[[0, -1]]
        q = self.phase_index(lam, film_ior_offset)
        return 2.0 * np.asarray(thickness_nm) * abs(q[0] / lam[0] - q[1] / lam[1])


# ---------------------------------------------------------------------------
# Results
# ---------------------------------------------------------------------------


@dataclass
class SpectrumFit:
    """The fit of one spectrum.

    Attributes
    ----------
    thickness_nm, thickness_sigma_nm : float
        Film thickness and its standard uncertainty (see the module docstring).
    film_ior : float
        Film index at ``film_ior_wavelength_nm`` (fitted with ``fit_film_ior``, else the given).
    film_ior_sigma : float or None
        Its standard uncertainty; ``None`` when the index was not fitted.
    film_ior_wavelength_nm : float
        Wavelength at which ``film_ior`` is reported (the middle of the fitted range).
    rms_residual : float
        Root-mean-square residual, in the units of the spectrum.
    chi2 : float
        Reduced chi-square against the spectrum's own point-to-point noise (from its second
        differences); well above 1 means a misfit the model cannot explain (or smoothed data).
    fringes : float
        Interference fringes across the fitted range at the fitted thickness.
    gain_degree : int or None
        Degree of the fitted response polynomial (``None`` with a reference).
    at_bound : bool
        The thickness sits on an end of the searched range (widen ``thickness_range_nm``).
    n_points : int
        Samples fitted.
    fitted : ndarray
        The fitted model spectrum, same samples as the input.
    thickness_spread_nm, resolution_nm : float
        The instrument setting of the fit: the thickness spread over the light spot (standard
        deviation) and the line width (full width at half maximum; 0: the pixel's own width).
    runner_up_thickness_nm, runner_up_chi2, runner_up_delta_bic : float
        The best other reading (another interference order or regime, a quarter of an order
        or more away): its thickness, its reduced chi-square (as ``chi2``) and how much worse
        its BIC is (NaN where no other candidate survived). A ``runner_up_delta_bic`` of a few
        units means the two fit about equally; the sigma then covers both.
    """

    thickness_nm: float
    thickness_sigma_nm: float
    film_ior: float
    film_ior_sigma: float | None
    film_ior_wavelength_nm: float
    rms_residual: float
    chi2: float
    fringes: float
    gain_degree: int | None
    at_bound: bool
    n_points: int
    fitted: np.ndarray
    thickness_spread_nm: float = 0.0
    resolution_nm: float = 0.0
    runner_up_thickness_nm: float = float("nan")
    runner_up_chi2: float = float("nan")
    runner_up_delta_bic: float = float("nan")


# ---------------------------------------------------------------------------
# The shared part of a wavelength grid: bases, pixel sub-samples, forward model
# ---------------------------------------------------------------------------


def _legendre_basis(lam, degree):
    """Legendre polynomials in ``1/λ`` mapped to [-1, 1] over the range, shape (n, degree+1)."""
    x = 1.0 / lam
    t = 2.0 * (x - x.min()) / (x.max() - x.min()) - 1.0
    return np.polynomial.legendre.legvander(t, degree)


def _pixels(lam, m):
    """Sub-sample wavelengths (n, m), each pixel's width split into ``m`` parts, and the widths."""
    edges = np.empty(lam.size + 1)
    edges[1:-1] = 0.5 * (lam[1:] + lam[:-1])
    edges[0] = lam[0] - 0.5 * (lam[1] - lam[0])
    edges[-1] = lam[-1] + 0.5 * (lam[-1] - lam[-2])
    width = np.diff(edges)
    u = (np.arange(m) + 0.5) / m - 0.5
    return lam[:, None] + width[:, None] * u[None, :], width


def _line_operator(lam, width, lam_fine, fwhm):
    """The reading of each pixel from the fine grid (sparse, (n, n_fine)): the pixel's box
    (its width) convolved with a Gaussian line of full width ``fwhm`` at half maximum,
    integrated exactly (differences of the normal CDF); each row sums to 1. A line narrower
    than the fine step is the box alone."""
    from scipy.sparse import csr_matrix
    from scipy.special import ndtr

    h = lam_fine[1] - lam_fine[0]
    sigma = max(fwhm / _FWHM, 0.25 * h)
    reach = int(np.ceil((0.5 * np.max(width) + 4.0 * sigma) / h)) + 1
    centre = np.rint((lam - lam_fine[0]) / h).astype(int)
    cols = centre[:, None] + np.arange(-reach, reach + 1)[None, :]
    inside = (cols >= 0) & (cols < lam_fine.size)
    cols = np.clip(cols, 0, lam_fine.size - 1)
    x = lam_fine[cols] - lam[:, None]
    half = 0.5 * width[:, None]
    w = (ndtr((x + half) / sigma) - ndtr((x - half) / sigma)) * inside
    w /= w.sum(axis=1, keepdims=True)
    rows = np.repeat(np.arange(lam.size), cols.shape[1])
    return csr_matrix((w.ravel(), (rows, cols.ravel())), shape=(lam.size, lam_fine.size))


def _qr(A):
    """Thin QR of stacked matrices A (..., n, p), as CholeskyQR2 on unit-norm columns.

    LAPACK's QR runs one small matrix at a time and, with a threaded BLAS, spends most of its
    time synchronising threads; two Cholesky passes over the Gram matrices are batched matrix
    products and orthogonalise to machine precision for the condition numbers met here. A tiny
    ridge keeps nearly dependent columns (a film that barely changes R) from failing.
    """
    p = A.shape[-1]
    scale = np.sqrt(np.einsum("...np,...np->...p", A, A))
    scale = np.where(scale > 0.0, scale, 1.0)
    Q = A / scale[..., None, :]
    R = np.broadcast_to(np.eye(p), A.shape[:-2] + (p, p))
    eye = 1e-14 * np.eye(p)
    for _ in range(2):
        L = np.linalg.cholesky(np.swapaxes(Q, -1, -2) @ Q + eye)
        U = np.swapaxes(L, -1, -2)
        Q = Q @ np.linalg.inv(U)
        R = U @ R
    return Q, R * scale[..., None, :]


class _Problem:
    """Everything shared by the spectra of one wavelength grid."""

    def __init__(self, lam, model, background, reference, d_range, fit_film_ior,
                 background_degree=BACKGROUND_DEGREE, spreads=SPREADS_NM, resolutions=RESOLUTIONS_NM):
        self.lam = lam
        self.n = lam.size
        self.model = model
        self.k = 2 if fit_film_ior else 1
        self.d_lo, self.d_hi = d_range
        self.q_max = float(model.phase_index(lam).max())

        # the instrument: every (thickness spread, line width) setting tried
        self.spreads = tuple(float(v) for v in spreads)
        self.resolutions = tuple(float(v) for v in resolutions)
        self.blurs = [(sv, wv) for sv in self.spreads for wv in self.resolutions]
        self.k_blur = int(len(self.spreads) > 1) + int(len(self.resolutions) > 1)
        # a fine uniform grid resolving the thinnest fringes in range and every pixel
        _, width = _pixels(lam, 1)
        period = lam * lam / (2.0 * model.phase_index(lam) * self.d_hi)
        h = float(min(np.min(width), np.min(period) / 12.0))
        h = max(h, np.ptp(lam) / _MAX_FINE)
        pad = 0.5 * max(width[0], width[-1]) + 4.0 * max(self.resolutions) / _FWHM + 2.0 * h
        self.lam_fine = np.arange(lam[0] - pad, lam[-1] + pad + 0.5 * h, h)
        self.lam_fine = self.lam_fine[self.lam_fine > 0.5 * lam[0]]
        self.fine_step = h
        self.spectrometer = model.spectrometer(self.lam_fine)
        self._pixel_width = width
        self._lines = {wv: _line_operator(lam, width, self.lam_fine, wv) for wv in self.resolutions}
        self._tables = {}
        self.lam_ref = 0.5 * (lam[0] + lam[-1])
        self.n_ref = float(model.indices(np.array([self.lam_ref]))[0][0])
        # thickness table (films without a fitted index): R and dR/dd on a uniform grid, a
        # 0.4 radian of phase apart at the shortest wavelength, interpolated (cubic Hermite)
        self.t_step = 0.4 * lam[0] / (4.0 * np.pi * self.q_max)
        s_max = max(self.spreads)
        t0 = max(self.d_lo - 4.5 * s_max - 2.0 * self.t_step, 0.0)
        count = int(np.ceil((self.d_hi + 4.5 * s_max + 2.0 * self.t_step - t0) / self.t_step)) + 1
        self.t_d = t0 + self.t_step * np.arange(count)

        # linear bases: background columns first, then the response's
        phi = None if background is not None else _legendre_basis(lam, background_degree)
        if reference is not None:
            ref = reference - (background if background is not None else 0.0)
            gain = ref[:, None] / np.sqrt(np.mean(ref * ref))
            if phi is not None:
                gain = np.concatenate([gain, phi], axis=1)
            self.nested = False
        else:
            gain = _legendre_basis(lam, GAIN_DEGREE_MAX)
            self.nested = True
        self.phi = phi
        self.gain = gain
        self.p_b = 0 if phi is None else phi.shape[1]
        coarse = np.unique(np.linspace(0, self.n - 1, min(_COARSE, self.n)).round().astype(int))
        self.gain_coarse = gain[coarse]
        self.phi_coarse = None if phi is None else phi[coarse]
        # the plausibility check looks at the response relative to the reference's shape
        self.gain_shape_coarse = gain[coarse, :1] if reference is not None else np.ones((coarse.size, 1))
        # products of basis columns, for Gram matrices A^T A without forming A
        self.gain_gain = (gain[:, :, None] * gain[:, None, :])  # (n, G, G)
        if phi is not None:
            self.phi_phi = phi.T @ phi
            self.phi_gain = phi[:, :, None] * gain[:, None, :]  # (n, p_b, G)

    def contrast(self, d, blur):
        """The fringe contrast left by instrument setting ``blur`` at thicknesses ``d``, at the
        middle of the range: ``exp(−σ_φ²/2)`` for the spread of the round-trip phase
        ``σ_φ = 4π q / λ · sqrt(s² + (d σ_λ / λ)²)`` (``s`` the thickness spread, ``σ_λ`` the
        line's standard deviation)."""
        spread, width = np.asarray(self.blurs, dtype=np.float64)[np.asarray(blur)].T
        lam = self.lam_ref
        q = float(self.model.phase_index(np.array([lam]))[0])
        sig = np.sqrt(spread ** 2 + (np.asarray(d) * width / _FWHM / lam) ** 2)
        return np.exp(-0.5 * (4.0 * np.pi * q * sig / lam) ** 2)

    def allowed(self, d, blur):
        """Whether instrument setting ``blur`` is a reading of thicknesses ``d``: it leaves a
        fringe contrast of at least :data:`_MIN_CONTRAST` (:meth:`contrast`), and its spread
        is at most :data:`_MAX_RELATIVE_SPREAD` of the thickness (a wider spread is a wedge,
        not a film of that thickness, and trades against the thickness of a thin film)."""
        spread = np.asarray(self.blurs, dtype=np.float64)[np.asarray(blur), 0]
        d = np.asarray(d, dtype=np.float64)
        return (self.contrast(d, blur) >= _MIN_CONTRAST) & (spread <= _MAX_RELATIVE_SPREAD * d)

    def gain_columns(self, d):
        """Response columns allowed at thicknesses ``d``: all of them with a reference, else
        ``degree + 1`` with the degree capped at ``0.75 π N`` for ``N`` fringes."""
        d = np.asarray(d, dtype=np.float64)
        if not self.nested:
            return np.full(d.shape, self.gain.shape[1], dtype=int)
        cap = np.floor(_CAP_FACTOR * np.pi * self.model.fringes(self.lam, d))
        return np.clip(cap, GAIN_DEGREE_MIN, GAIN_DEGREE_MAX).astype(int) + 1

    def column_options(self):
        """The numbers of response columns a fit may use."""
        if not self.nested:
            return [self.gain.shape[1]]
        return list(range(1, GAIN_DEGREE_MAX + 2))

    def bic(self, rss, g, scale2):
        """BIC of fits with ``g`` response columns (+ the background's and the nonlinear ones)."""
        p = self.p_b + g + self.k + self.k_blur
        return self.n * np.log(np.maximum(rss, 1e-14 * scale2) / self.n) + p * np.log(self.n)

    def setting_index(self, setting):
        """The index in :attr:`blurs` of instrument setting ``(spread, fwhm)``, added if new
        (its table is made when first used)."""
        setting = (float(setting[0]), float(setting[1]))
        if setting not in self.blurs:
            self.blurs.append(setting)
        return self.blurs.index(setting)

    def _fine_table(self):
        if "fine" not in self._tables:
            R = np.empty((self.t_d.size, self.lam_fine.size))
            dR = np.empty_like(R)
            for start in range(0, self.t_d.size, 256):
                sl = slice(start, start + 256)
                R[sl], jac = self.spectrometer.reflectance(self.t_d[sl], derivatives=True)
                dR[sl] = jac[:, :, 0]
            self._tables["fine"] = (R, dR)
        return self._tables["fine"]

    def table(self, blur):
        """The thickness table of instrument setting ``blur``: (R, dR/dd), each (T, n), at
        thicknesses :attr:`t_d`: the fine table averaged over the thickness spread (a Gaussian
        over the table's rows), then seen through the line shape and the pixel."""
        if blur not in self._tables:
            from scipy.ndimage import convolve1d

            R, dR = self._fine_table()
            spread, width = self.blurs[blur]
            if ("line", width) not in self._tables:
                if width not in self._lines:
                    self._lines[width] = _line_operator(self.lam, self._pixel_width, self.lam_fine, width)
                line = self._lines[width]
                self._tables["line", width] = (np.asarray(line @ R.T).T.copy(), np.asarray(line @ dR.T).T.copy())
            R, dR = self._tables["line", width]
            if spread > 0.0:
                reach = int(np.ceil(4.0 * spread / self.t_step))
                off = np.arange(-reach, reach + 1)
                w = np.exp(-0.5 * (off * self.t_step / spread) ** 2)
                w /= w.sum()
                R = convolve1d(R, w, axis=0, mode="nearest")
                dR = convolve1d(dR, w, axis=0, mode="nearest")
            self._tables[blur] = (R, dR)
        return self._tables[blur]

    def reflectance(self, d, delta=None, derivatives=False, blur=0):
        """R as the instrument sees it (K, n) for thicknesses ``d`` (K,), index offsets
        ``delta`` (K,), instrument setting ``blur`` (an index into :attr:`blurs`); with
        ``derivatives`` also its derivatives (K, n, 1 or 2) by ``d`` (and ``delta``).

        Without index offsets from the thickness table (:meth:`table`, cubic Hermite in
        ``d``); with them the observation model is evaluated at the thickness spread's
        Gauss-Hermite nodes and seen through the line shape."""
        d = np.asarray(d, dtype=np.float64).ravel()
        if delta is None:
            T, dT = self.table(blur)
            t = np.clip((d - self.t_d[0]) / self.t_step, 0.0, self.t_d.size - 1.0)
            i = np.minimum(np.floor(t).astype(int), self.t_d.size - 2)
            u = (t - i)[:, None]
            h = self.t_step
            a, b, da, db = T[i], T[i + 1], h * dT[i], h * dT[i + 1]
            u2, u3 = u * u, u * u * u
            R = (2 * u3 - 3 * u2 + 1) * a + (u3 - 2 * u2 + u) * da + (3 * u2 - 2 * u3) * b + (u3 - u2) * db
            if not derivatives:
                return R
            D = ((6 * u2 - 6 * u) * a + (3 * u2 - 4 * u + 1) * da + (6 * u - 6 * u2) * b + (3 * u2 - 2 * u) * db) / h
            return R, D[:, :, None]
        spread, width = self.blurs[blur]
        if width not in self._lines:
            self._lines[width] = _line_operator(self.lam, self._pixel_width, self.lam_fine, width)
        line = self._lines[width]
        nodes, weights = (np.polynomial.hermite_e.hermegauss(_SPREAD_NODES) if spread > 0.0
                          else (np.zeros(1), np.ones(1)))
        weights = weights / weights.sum()
        delta = np.broadcast_to(np.asarray(delta, dtype=np.float64).ravel(), d.shape)
        R = 0.0
        dR = 0.0
        for x, w in zip(nodes, weights):
            out = self.spectrometer.reflectance(np.maximum(d + spread * x, 0.0), delta, derivatives)
            if derivatives:
                R = R + w * out[0]
                dR = dR + w * out[1]
            else:
                R = R + w * out
        K = d.size
        R = np.asarray(line @ R.T).T
        if not derivatives:
            return R
        q = dR.shape[-1]
        dR = np.asarray(line @ np.moveaxis(dR, 1, 0).reshape(self.lam_fine.size, K * q))
        return R, np.moveaxis(dR.reshape(self.n, K, q), 1, 0)

    def design(self, R, g=None, derivative=False):
        """Design matrices (K, n, p_b + g) for reflectances R (K, n), ``g`` response columns
        (default all); with ``derivative`` R is a derivative and the background columns are 0."""
        gain = self.gain if g is None else self.gain[:, :g]
        cols = gain[None, :, :] * R[:, :, None]
        if self.phi is None:
            return cols
        phi = np.zeros_like(self.phi) if derivative else self.phi
        return np.concatenate([np.broadcast_to(phi, (R.shape[0],) + phi.shape), cols], axis=2)

    # -- linear algebra of A = [phi, gain * R] for per-problem R (N, n), without forming A --

    def gram(self, R, g):
        """``A^T A`` (N, p, p) for reflectances R (N, n) and ``g`` response columns."""
        N, pb = R.shape[0], self.p_b
        gg = (R * R) @ self.gain_gain[:, :g, :g].reshape(self.n, g * g)
        gg = gg.reshape(N, g, g)
        if pb == 0:
            return gg
        bg = (R @ self.phi_gain[:, :, :g].reshape(self.n, pb * g)).reshape(N, pb, g)
        top = np.concatenate([np.broadcast_to(self.phi_phi, (N, pb, pb)), bg], axis=2)
        bottom = np.concatenate([np.swapaxes(bg, 1, 2), gg], axis=2)
        return np.concatenate([top, bottom], axis=1)

    @staticmethod
    def _left(V, basis):
        """``basis^T V`` per problem: V (N, n, j), basis (n, p) → (N, p, j), one matrix product."""
        N, n, j = V.shape
        out = np.swapaxes(V, 1, 2).reshape(N * j, n) @ basis
        return np.swapaxes(out.reshape(N, j, -1), 1, 2)

    @staticmethod
    def _right(C, basis):
        """``basis C`` per problem: C (N, p, j), basis (n, p) → (N, n, j)."""
        N, p, j = C.shape
        out = np.swapaxes(C, 1, 2).reshape(N * j, p) @ basis.T
        return np.swapaxes(out.reshape(N, j, -1), 1, 2)

    def at(self, R, g, V):
        """``A^T V`` (N, p, j) for V (N, n, j)."""
        out = self._left(R[:, :, None] * V, self.gain[:, :g])
        if self.p_b == 0:
            return out
        return np.concatenate([self._left(V, self.phi), out], axis=1)

    def a(self, R, g, C):
        """``A C`` (N, n, j) for C (N, p, j)."""
        out = R[:, :, None] * self._right(C[:, self.p_b:], self.gain[:, :g])
        if self.p_b == 0:
            return out
        return out + self._right(C[:, :self.p_b], self.phi)

    def plausible(self, coef, y_max, floor=_GAIN_FLOOR):
        """Whether a fit is physically plausible, checked at a few wavelengths: the response
        (relative to the white reference's shape, when there is one) stays above ``floor`` times
        its maximum, and the fitted background (when there is one) nowhere falls below −:data:`_BACKGROUND_FLOOR` times the spectrum's maximum.
        coef (..., p, S), y_max (S,).

        A real response is positive and does not vanish inside the range, a background adds
        light. Fits that break this are the false ones: a response negative throughout flips
        the fringes (the half-order-shifted solutions); a quadratic response with a double
        root draws a fringe minimum of its own; a strongly negative background lets a thinner
        film's reflectance, scaled up and shifted down, pass for a thicker one. On the coarse
        grid a thickness slightly off the truth can need a response dipping a little below
        zero, hence a lower floor there."""
        g = coef.shape[-2] - self.p_b
        G = self.gain_coarse[:, :g] @ coef[..., self.p_b:, :] / self.gain_shape_coarse
        ok = np.min(G, axis=-2) > floor * np.max(G, axis=-2)
        if self.p_b:
            B = self.phi_coarse @ coef[..., :self.p_b, :]
            ok &= np.min(B, axis=-2) > -_BACKGROUND_FLOOR * y_max
        return ok


# ---------------------------------------------------------------------------
# Step 1: the profile over a thickness grid, all spectra of a wavelength grid at once
# ---------------------------------------------------------------------------


def _grid(problem):
    step = problem.lam[0] / (8.0 * problem.q_max)
    count = int(np.ceil((problem.d_hi - problem.d_lo) / step)) + 1
    return np.linspace(problem.d_lo, problem.d_hi, max(count, 16))


def _profile(problem, Y, grid):
    """:func:`_profile_one` for every instrument setting: ``(bic, d, plausible, bic_any,
    blur)``, the first three and ``blur`` (K, S) at each grid thickness of the setting with the
    lowest ``bic`` there, ``blur`` that setting's index, and ``bic_any`` (B K, S) of every
    setting (B settings, grid thicknesses repeated per setting)."""
    parts = [_profile_one(problem, Y, grid, b) for b in range(len(problem.blurs))]
    bic = np.stack([p[0] for p in parts])
    blur = np.argmin(bic, axis=0)
    pick = [np.take_along_axis(np.stack([p[i] for p in parts]), blur[None], axis=0)[0] for i in range(3)]
    return pick[0], pick[1], pick[2], np.concatenate([p[3] for p in parts]), blur


def _profile_one(problem, Y, grid, blur=0, chunk=16):
    """Profile of every grid thickness for every spectrum (instrument setting ``blur``), each thickness polished by one
    Gauss-Newton step of the variable-projection problem (so that a grid point a fraction of
    a fringe off the truth still ranks near the top, however high the signal-to-noise ratio).

    Returns ``(bic, d, plausible, bic_any)``, each (K, S): the BIC predicted after the step (the
    step limited to one grid spacing) with the response columns allowed there
    (:meth:`_Problem.gain_columns`), the stepped thickness, whether the response is plausible,
    and the exact BIC at the grid thickness with the best response of any degree (for the
    uncertainty, :func:`_posterior_spread`).
    """
    Yt = Y.T
    S = Y.shape[0]
    y2 = np.einsum("sn,sn->s", Y, Y)
    y_max = np.max(np.abs(Y), axis=1)
    K = grid.size
    h = grid[1] - grid[0]
    bic_out = np.empty((K, S))
    any_out = np.empty((K, S))
    d_out = np.empty((K, S))
    pos_out = np.empty((K, S), dtype=bool)
    options = problem.column_options()
    for start in range(0, K, chunk):
        d = grid[start:start + chunk]
        g = problem.gain_columns(d)
        R, dR = problem.reflectance(d, derivatives=True, blur=blur)
        A = problem.design(R)
        dA = problem.design(dR[:, :, 0], derivative=True)
        P = A.shape[2]
        Q, Rr = _qr(A)
        proj = np.swapaxes(Q, 1, 2) @ Yt  # (k, P, S)
        # every response degree at once: the columns are nested
        explained = np.cumsum(proj * proj, axis=1)
        any_out[start:start + d.size] = np.min(
            [problem.bic(y2[None, :] - explained[:, problem.p_b + gv - 1], gv, y2[None, :]) for gv in options],
            axis=0)
        # the capped response: leading columns only
        used = np.arange(P)[None, :] < (problem.p_b + g)[:, None]  # (k, P)
        Q = Q * used[:, None, :]
        proj = proj * used[:, :, None]
        Rr = np.where(used[:, :, None] & used[:, None, :], Rr, np.eye(P)[None])
        cost = y2[None, :] - np.einsum("kps,kps->ks", proj, proj)
        coef = np.linalg.solve(Rr, proj)
        # J = dA c (∂(A c)/∂d at fixed c), projected: all through (k, P, ·) products
        dAt = np.swapaxes(dA, 1, 2)
        QtJ = (np.swapaxes(Q, 1, 2) @ dA) @ coef
        JJ = np.einsum("kps,kps->ks", coef, (dAt @ dA) @ coef)
        JtJ = JJ - np.einsum("kps,kps->ks", QtJ, QtJ)
        Jtr = np.einsum("kps,kps->ks", coef, dAt @ Yt) - np.einsum("kps,kps->ks", QtJ, proj)
        curved = JtJ > 1e-9 * JJ  # else J lies (numerically) in the span of A: no step
        step = np.where(curved, np.clip(Jtr / np.where(curved, JtJ, 1.0), -h, h), 0.0)
        pred = np.maximum(cost - 2.0 * step * Jtr + step * step * JtJ, 0.0)
        sl = slice(start, start + d.size)
        # a setting that washes the fringes out is not a reading of this thickness
        washed = ~problem.allowed(d, blur)[:, None]
        any_out[sl] = np.where(washed, np.inf, any_out[sl])
        pred = np.where(washed, np.inf, pred)
        bic_out[sl] = problem.bic(pred, g[:, None], y2[None, :])
        d_out[sl] = np.clip(d[:, None] + step, problem.d_lo, problem.d_hi)
        pos_out[sl] = problem.plausible(coef, y_max, _GAIN_FLOOR_GRID)
    return bic_out, d_out, pos_out, any_out


def _local_minima(values, count):
    """Indices (S, count) of the lowest local minima of each column of values (K, S)."""
    K, S = values.shape
    padded = np.vstack([np.full((1, S), np.inf), values, np.full((1, S), np.inf)])
    is_min = (values <= padded[:-2]) & (values <= padded[2:]) & np.isfinite(values)
    ranked = np.where(is_min, values, np.inf)
    order = np.argsort(ranked, axis=0)[:count].T
    found = np.isfinite(np.take_along_axis(ranked, order.T, axis=0).T)
    fallback = np.argmin(values, axis=0)[:, None]  # no finite minimum: the lowest value
    order = np.where(found, order, order[:, :1])
    return np.where(found.any(axis=1, keepdims=True), order, fallback)


def _candidates(profile):
    """Start thicknesses and instrument settings (S, M) each: the lowest local minima of the
    profile, and the lowest among those with a plausible response (a grid point slightly off
    the truth can need a response that dips below zero, and a false solution can be lower
    still)."""
    bic, d, plausible = profile[:3]
    blur = profile[4]
    raw = _local_minima(bic, _CANDIDATES)
    pos = _local_minima(np.where(plausible, bic, np.inf), _CANDIDATES_POSITIVE)
    cols = np.arange(bic.shape[1])[:, None]
    at = np.concatenate([raw, pos], axis=1)
    return d[at, cols], blur[at, cols]


def _groups(*keys):
    """``(values, rows)`` for each distinct combination of the per-row integer ``keys``."""
    stacked = np.stack([np.asarray(k, dtype=int) for k in keys], axis=1)
    values, inverse = np.unique(stacked, axis=0, return_inverse=True)
    inverse = inverse.ravel()
    for j, v in enumerate(values):
        yield tuple(int(x) for x in v), np.flatnonzero(inverse == j)


# ---------------------------------------------------------------------------
# Step 2: Levenberg-Marquardt on the variable-projection residual
# ---------------------------------------------------------------------------


def _normal_solve(G, B):
    """Solve the normal equations ``G X = B`` (N, p, p), (N, p, j) with Jacobi scaling and a
    tiny ridge (nearly dependent columns: a film that barely changes R)."""
    dg = np.sqrt(np.maximum(np.einsum("npp->np", G), 1e-300))
    Gs = G / (dg[:, :, None] * dg[:, None, :]) + 1e-12 * np.eye(G.shape[-1])
    return np.linalg.solve(Gs, B / dg[:, :, None]) / dg[:, :, None]


class _State:
    """Residuals, coefficients and projected Jacobian of N problems with ``g`` response columns
    at parameters theta (N, k): ``theta[:, 0]`` thickness, ``theta[:, 1]`` index offset.

    The linear coefficients come from the normal equations, assembled from the bases without
    forming the (N, n, p) design matrices; residuals are computed explicitly."""

    def __init__(self, problem, Y, theta, g, jacobian=True, blur=0):
        self.problem, self.g = problem, g
        self.theta = theta
        d, delta = self.split(theta)
        if jacobian:
            self.R, self.dR = problem.reflectance(d, delta, derivatives=True, blur=blur)
        else:
            self.R = problem.reflectance(d, delta, blur=blur)
        self.gram = problem.gram(self.R, g)
        self.coef = _normal_solve(self.gram, problem.at(self.R, g, Y[:, :, None]))[:, :, 0]
        self.fitted = problem.a(self.R, g, self.coef[:, :, None])[:, :, 0]
        self.resid = Y - self.fitted
        self.cost = np.einsum("ni,ni->n", self.resid, self.resid)
        self.plausible = problem.plausible(self.coef[:, :, None], np.max(np.abs(Y), axis=1)[:, None])[:, 0]
        if jacobian:
            self.jacobian()

    @staticmethod
    def split(theta):
        return theta[:, 0], (theta[:, 1] if theta.shape[1] > 1 else None)

    def jacobian(self):
        """Fill ``J`` (the Jacobian with the linear parameters profiled out, Kaufman's form
        ``(1 − P_A) ∂(A c)/∂θ``, from the model's derivatives of R), ``J^T J`` and ``J^T r``."""
        problem, g, R = self.problem, self.g, self.R
        gain = self.coef[:, problem.p_b:] @ problem.gain[:, :g].T  # G(λ) per problem
        J = self.dR * gain[:, :, None]  # ∂(A c)/∂θ at fixed c
        J = J - problem.a(R, g, _normal_solve(self.gram, problem.at(R, g, J)))
        self.J = J
        self.JtJ = np.swapaxes(J, 1, 2) @ J
        self.Jtr = np.einsum("nik,ni->nk", J, self.resid)


def _clip(problem, theta):
    theta[:, 0] = np.clip(theta[:, 0], problem.d_lo, problem.d_hi)
    if theta.shape[1] > 1:
        theta[:, 1] = np.clip(theta[:, 1], 1.01 - problem.n_ref, 4.0 - problem.n_ref)
    return theta


def _refine_group(problem, Y, theta, g, iterations=30, freeze_index=False, blur=0):
    """Levenberg-Marquardt (:func:`thinfilm.reconstruction.lm.levenberg_marquardt`) for N
    independent problems with ``g`` response columns; returns ``(theta, cost, plausible)``.

    The solver's normal equations are the variable-projection ones of :class:`_State` (the
    linear coefficients profiled out). With ``freeze_index`` the index offsets stay where they
    are and the steps are in ``d`` alone. A problem stops when an accepted step falls below 1 %
    of its thickness sigma (or 1e-3 nm) and the index step below 1e-6, or when its damping
    grows past 1e4."""
    N, k = theta.shape
    n = Y.shape[1]
    free = 1 if freeze_index else k
    fixed = theta[:, free:].copy()
    dof = max(n - problem.p_b - g - k, 1)

    def full(x, idx):
        return np.concatenate([x, fixed[idx]], axis=1) if free < k else x

    def normal_equations(x, idx):
        st = _State(problem, Y[idx], full(x, idx), g, blur=blur)
        return st.JtJ[:, :free, :free], st.Jtr[:, :free], st.cost, st.plausible

    def project(x):
        if free == k:
            return _clip(problem, x)
        x[:, 0] = np.clip(x[:, 0], problem.d_lo, problem.d_hi)
        return x

    def converged(step, H, cost, accepted):
        sigma = np.sqrt(cost / dof / np.maximum(H[:, 0, 0], 1e-300))
        small = np.abs(step[:, 0]) < np.maximum(1e-3, 0.01 * sigma)
        if free > 1:
            small &= np.abs(step[:, -1]) < 1e-6
        return accepted & small

    # the normal equations are JᵀJ and Jᵀ(y − fit): the descent step is +(H + μD)⁻¹ Jᵀr
    fit = levenberg_marquardt(theta[:, :free], lambda x, idx: _negated(normal_equations(x, idx)), iterations,
                              project=project, lam0=1e-3, lam_down=0.2, lam_up=4.0, lam_max=1e4,
                              floor_rel=0.0, floor_abs=1e-300, converged=converged)
    return full(fit.x, np.arange(N)), fit.cost, fit.aux.astype(bool)


def _negated(terms):
    """Normal equations with the gradient's sign flipped: :class:`_State` keeps ``Jᵀr`` for
    residuals ``r = y − fit``, the solver takes the gradient of the residuals ``fit − y``."""
    H, g, cost, aux = terms
    return H, -g, cost, aux


def _refine(problem, Y, theta, g, blur, freeze_index=False, iterations=30):
    """Refine N problems (rows of Y, theta) with their own response column counts ``g`` (N,)
    and instrument settings ``blur`` (N,); returns (theta, cost, plausible)."""
    theta_out = theta.copy()
    cost = np.empty(theta.shape[0])
    plausible = np.empty(theta.shape[0], dtype=bool)
    for (gv, bv), sel in _groups(g, blur):
        theta_out[sel], cost[sel], plausible[sel] = _refine_group(
            problem, Y[sel], theta[sel].copy(), gv, iterations, freeze_index, bv)
    return theta_out, cost, plausible


# ---------------------------------------------------------------------------
# Step 3: uncertainty
# ---------------------------------------------------------------------------


def _covariance(state, n_params):
    """Sandwich covariance (N, k, k) with an AR(1) model of the residuals (module docstring)."""
    r = state.resid
    N, n = r.shape
    s2 = state.cost / max(n - n_params, 1)
    rho = np.clip(np.einsum("ni,ni->n", r[:, 1:], r[:, :-1])
                  / np.maximum(state.cost, 1e-300), 0.0, 0.95)
    J = state.J
    JtJ = np.swapaxes(J, 1, 2) @ J
    # J^T Σ J = s² Σ_l ρ^|l| Σ_i J_i J_{i+l}^T: lagged cross-products by FFT
    size = 2 * n
    F = np.fft.rfft(J, size, axis=1)  # (N, f, k)
    lagged = np.fft.irfft(np.conj(F)[:, :, :, None] * F[:, :, None, :], size, axis=1)  # (N, lag, k, k)
    lags = np.minimum(np.arange(size), size - np.arange(size))
    weights = rho[:, None] ** lags[None, :]
    weights[:, n] = 0.0  # lag ±n does not exist
    meat = s2[:, None, None] * np.einsum("nl,nlab->nab", weights, lagged)
    bread = np.linalg.pinv(JtJ)
    return bread @ meat @ bread, rho


def _covariances(problem, Y, theta, g, blur):
    """Covariance (N, k, k), fitted spectra, residual cost and residual lag-1 autocorrelation at
    fixed theta, ``g`` (N,) response columns per problem."""
    N = theta.shape[0]
    cov = np.empty((N, problem.k, problem.k))
    fitted = np.empty(Y.shape)
    cost = np.empty(N)
    rho = np.empty(N)
    for (gv, bv), sel in _groups(g, blur):
        st = _State(problem, Y[sel], theta[sel].copy(), gv, blur=bv)
        cov[sel], rho[sel] = _covariance(st, problem.p_b + gv + problem.k + problem.k_blur)
        fitted[sel], cost[sel] = st.fitted, st.cost
    return cov, fitted, cost, rho


def _posterior_spread(grid, bic_grid, theta, bic_fit, rho):
    """Second moment (S,) of the thickness about the fit, over the thickness grid and the fit,
    each weighted by its evidence ``exp(−BIC/2)``: at each grid thickness the best response of
    any degree (the cap protects the estimate, not the uncertainty), ``bic_grid`` (K, S) from
    :func:`_profile` (at the given film index).

    The BIC differences are scaled by ``(1 − ρ)/(1 + ρ)``, the effective share of independent
    samples for residuals with lag-1 autocorrelation ``ρ``. Near zero for a well-determined
    thickness (every grid point is far less likely than the fit); large when thicknesses far
    from the fit explain the spectrum about as well with some smooth response, as for a film
    without a full fringe whose response is not pinned down.
    """
    shrink = (1.0 - rho) / (1.0 + rho)
    logw = np.minimum(-0.5 * (bic_grid - bic_fit[None, :]) * shrink[None, :], 50.0)
    w = np.exp(logw)
    dev2 = (grid[:, None] - theta[None, :, 0]) ** 2
    return (w * dev2).sum(axis=0) / (1.0 + w.sum(axis=0))


def _bic_at(problem, Y, theta, g, scale2, blur):
    """BIC (N,) of fits at fixed theta with ``g`` (N,) response columns, settings ``blur``."""
    cost = np.empty(theta.shape[0])
    for (gv, bv), sel in _groups(g, blur):
        cost[sel] = _State(problem, Y[sel], theta[sel].copy(), gv, jacobian=False, blur=bv).cost
    return problem.bic(cost, g, scale2)


def _index_valley(problem, Y, theta, g, rho, scale2, blur, count=25, span=0.15):
    """Film index and thickness along the valley of equal optical thickness.

    The fringes fix the optical thickness ``n2 d`` far better than ``n2`` and ``d`` apart (the
    index shows only in the fringes' amplitude and shape), so a fit started at a wrong index
    can stop anywhere along ``n2 d = const``. This walks the valley: ``count`` film indices
    within ``± span`` of the fitted one, each with the thickness that keeps the optical
    thickness and refined with the index held. Returns ``(theta, var)``: the parameters moved
    to the valley's best point where that beats the fit (then refined in both), and the
    evidence-weighted second moments of thickness and index about them (BIC differences
    scaled by ``(1 − ρ)/(1 + ρ)`` as in :func:`_posterior_spread`)."""
    S = theta.shape[0]
    lam_ref = np.array([problem.lam_ref])
    n_fit = problem.n_ref + theta[:, 1]
    u = np.linspace(-span, span, count)
    n_new = np.clip(n_fit[:, None] * (1.0 + u[None, :]), 1.01, 4.0)  # (S, J)
    delta = n_new - problem.n_ref
    q_fit = np.array([problem.model.phase_index(lam_ref, dv)[0] for dv in theta[:, 1]])
    q_new = np.vectorize(lambda dv: problem.model.phase_index(lam_ref, dv)[0])(delta)
    d_new = theta[:, :1] * q_fit[:, None] / q_new
    th = np.stack([d_new.reshape(-1), delta.reshape(-1)], axis=1)
    th = _clip(problem, th)
    gg = np.repeat(g, count)
    Yv = np.repeat(Y, count, axis=0)
    bb = np.repeat(blur, count)
    th, cost, _ = _refine(problem, Yv, th, gg, bb, freeze_index=True)
    bic_v = problem.bic(cost, gg, np.repeat(scale2, count)).reshape(S, count)
    th = th.reshape(S, count, 2)
    bic_fit = _bic_at(problem, Y, theta, g, scale2, blur)
    best = np.argmin(bic_v, axis=1)
    moved = bic_v[np.arange(S), best] < bic_fit - 1e-9
    theta = theta.copy()
    if np.any(moved):
        rows = np.flatnonzero(moved)
        start = th[rows, best[rows]]
        theta[rows] = _refine(problem, Y[rows], start, g[rows], blur[rows])[0]
        bic_fit[rows] = _bic_at(problem, Y[rows], theta[rows], g[rows], scale2[rows], blur[rows])
    shrink = (1.0 - rho) / (1.0 + rho)
    logw = np.minimum(-0.5 * (bic_v - bic_fit[:, None]) * shrink[:, None], 50.0)
    w = np.exp(logw)
    norm = 1.0 + w.sum(axis=1)
    var = np.stack([(w * (th[:, :, 0] - theta[:, :1]) ** 2).sum(axis=1) / norm,
                    (w * (th[:, :, 1] - theta[:, 1:]) ** 2).sum(axis=1) / norm], axis=1)
    return theta, var


def _best_gain_columns(problem, Y, theta, lo, hi, blur):
    """Per problem, the number of response columns within ``[lo, hi]`` (arrays or numbers)
    with the lowest BIC at fixed theta and instrument settings ``blur``."""
    delta = theta[:, 1] if theta.shape[1] > 1 else None
    R = np.empty(Y.shape)
    for (bv,), sel in _groups(blur):
        R[sel] = problem.reflectance(theta[sel, 0], None if delta is None else delta[sel], blur=bv)
    Q, _ = _qr(problem.design(R))
    proj = np.einsum("nip,ni->np", Q, Y)
    y2 = np.einsum("ni,ni->n", Y, Y)
    explained = np.cumsum(proj * proj, axis=1)
    options = np.array(problem.column_options())
    bic = np.stack([problem.bic(y2 - explained[:, problem.p_b + gv - 1], gv, y2) for gv in options], axis=1)
    lo = np.broadcast_to(lo, theta.shape[:1])[:, None]
    hi = np.broadcast_to(hi, theta.shape[:1])[:, None]
    bic[(options[None, :] < lo) | (options[None, :] > hi)] = np.inf
    return options[np.argmin(bic, axis=1)]


def _over_settings(problem, Y, theta, g, blur, scale2):
    """The thickness averaged over the instrument settings (Bayesian model averaging).

    The settings are a grid; the instrument lies between its points, and the thickness moves
    a little with the setting. Each spectrum's thickness is refined at every setting from the
    fit, and then at the settings half a grid step from its best one along each axis (the
    grid refined where it matters); each is weighted by its evidence ``exp(−ΔBIC/2)``,
    ``ΔBIC`` divided by the fit's reduced chi-square against its own point-to-point noise
    where that exceeds 1 (a setting that misses the instrument leaves a misfit, which widens
    the weights instead of singling one point out). Returns the weighted mean thickness and
    the weighted variance about it."""
    S, B = theta.shape[0], len(problem.blurs)
    rows = np.repeat(np.arange(S), B)
    bb = np.tile(np.arange(B), S)
    ok = problem.allowed(np.repeat(theta[:, 0], B), bb)
    rows, bb = rows[ok], bb[ok]
    th, cost, _ = _refine(problem, Y[rows], theta[rows].copy(), g[rows], bb, iterations=4)
    bic = problem.bic(cost, g[rows], scale2[rows])

    # half steps around each spectrum's best setting
    best_b = np.zeros(S, dtype=int)
    lowest = np.full(S, np.inf)
    for r, bv, value in zip(rows, bb, bic):
        if value < lowest[r]:
            lowest[r], best_b[r] = value, bv
    extra_rows, extra_b = [], []
    for axis, values in ((0, problem.spreads), (1, problem.resolutions)):
        if len(values) < 2:
            continue
        half = 0.5 * float(np.min(np.diff(sorted(values))))
        for r in range(S):
            here = list(problem.blurs[best_b[r]])
            for sign in (-1.0, 1.0):
                v = here[axis] + sign * half
                if min(values) <= v <= max(values):
                    setting = tuple(here[:axis] + [v] + here[axis + 1:])
                    extra_rows.append(r)
                    extra_b.append(problem.setting_index(setting))
    if extra_rows:
        er, eb = np.asarray(extra_rows), np.asarray(extra_b)
        keep = problem.allowed(theta[er, 0], eb)
        er, eb = er[keep], eb[keep]
        th2, cost2, _ = _refine(problem, Y[er], theta[er].copy(), g[er], eb, iterations=4)
        rows = np.concatenate([rows, er])
        th = np.concatenate([th, th2])
        cost = np.concatenate([cost, cost2])
        bic = np.concatenate([bic, problem.bic(cost2, g[er], scale2[er])])

    n = problem.n
    noise2 = np.maximum(_noise_sigma(Y) ** 2, 1e-300)
    best = np.full(S, np.inf)
    np.minimum.at(best, rows, bic)
    cmin = np.full(S, np.inf)
    np.minimum.at(cmin, rows, cost)
    chi2 = cmin / max(n - problem.p_b - int(np.max(g)) - 1, 1) / noise2
    temper = np.maximum(chi2, 1.0)
    w = np.exp(-0.5 * (bic - best[rows]) / temper[rows])
    wsum = np.bincount(rows, w, S)
    mean = np.bincount(rows, w * th[:, 0], S) / wsum
    var = np.bincount(rows, w * (th[:, 0] - mean[rows]) ** 2, S) / wsum
    theta = theta.copy()
    theta[:, 0] = np.clip(mean, problem.d_lo, problem.d_hi)
    return theta, var


def _noise_sigma(Y):
    """Point-to-point noise of each spectrum from its second differences (robust MAD)."""
    e = Y[:, :-2] - 2.0 * Y[:, 1:-1] + Y[:, 2:]
    mad = np.median(np.abs(e - np.median(e, axis=1, keepdims=True)), axis=1)
    return 1.4826 * mad / np.sqrt(6.0)


# ---------------------------------------------------------------------------
# Public entry point
# ---------------------------------------------------------------------------


def _choose(bic, plausible):
    """Index (S,) of the chosen candidate per row of ``bic`` (S, M): the lowest BIC, unless it
    is implausible and a plausible candidate comes within :data:`_PLAUSIBLE_MARGIN` of it.

    A false solution with an implausible response or background fits about as well as the
    truth (it is the truth's fringes moved or redrawn); an implausible fit far better than
    every plausible one means the plausible ones are wrong, not the other way round."""
    lowest = np.argmin(bic, axis=1)
    masked = np.where(plausible, bic, np.inf)
    alt = np.argmin(masked, axis=1)
    rows = np.arange(bic.shape[0])
    use_alt = ~plausible[rows, lowest] & (masked[rows, alt] <= bic[rows, lowest] + _PLAUSIBLE_MARGIN)
    return np.where(use_alt, alt, lowest)


def _thickness_range(lam, model, thickness_range_nm):
    if thickness_range_nm is not None:
        lo, hi = float(thickness_range_nm[0]), float(thickness_range_nm[1])
        if not (np.isfinite(lo) and np.isfinite(hi) and 0.0 <= lo < hi):
            raise ValueError("thickness_range_nm must be (min, max) with 0 <= min < max")
        return max(lo, 0.1), hi
    step = np.max(np.diff(lam))
    d_nyquist = float(np.min(lam * lam / (4.0 * model.phase_index(lam) * step)))
    return DEFAULT_THICKNESS_RANGE_NM[0], min(DEFAULT_THICKNESS_RANGE_NM[1], d_nyquist)


def _fit_problem(problem, Yfit):
    """Steps 1-3 of the module docstring for the spectra ``Yfit`` (S, n) of one problem.

    Returns a dict of per-spectrum arrays: ``theta`` (S, k), ``var`` (S, k) variances,
    ``cost``, ``fitted``, ``g`` response columns, ``p_lin`` linear parameters, ``blur`` the
    instrument setting, and the runner-up reading (``runner_up`` thickness, ``runner_up_cost``,
    ``runner_up_dbic``; NaN where every other candidate is the same reading)."""
    S, k = Yfit.shape[0], problem.k
    scale2 = np.einsum("sn,sn->s", Yfit, Yfit)

    # 1. every order and every instrument setting: the profile over the thickness grid
    grid = _grid(problem)
    profile = _profile(problem, Yfit, grid)
    d0, b0 = _candidates(profile)
    M = d0.shape[1]

    # 2. refine every candidate with the response allowed there; keep the best (a plausible
    #    fit first, then the lowest BIC); then the response's degree by BIC within the cap
    # (a start found twice for a spectrum is refined once; every start gets a few iterations,
    # the best two per spectrum, and the best plausible one, are then refined to the end)
    dup = np.zeros((S, M), dtype=bool)
    for j in range(1, M):
        dup[:, j] = np.any(np.isclose(d0[:, :j], d0[:, j:j + 1], rtol=0.0, atol=1e-9)
                           & (b0[:, :j] == b0[:, j:j + 1]), axis=1)
    rows = np.flatnonzero(~dup.reshape(-1))
    theta0 = np.zeros((rows.size, k))
    theta0[:, 0] = d0.reshape(-1)[rows]
    blur_flat = b0.reshape(-1)[rows]
    g_flat = problem.gain_columns(theta0[:, 0])
    spectrum = rows // M
    theta_r, cost_r, plausible_r = _refine(problem, Yfit[spectrum], theta0, g_flat, blur_flat,
                                           iterations=_PRE_ITERATIONS)
    bic = np.full(S * M, np.inf)
    bic[rows] = problem.bic(cost_r, g_flat, scale2[spectrum])
    plausible = np.zeros(S * M, dtype=bool)
    plausible[rows] = plausible_r
    bic, plausible = bic.reshape(S, M), plausible.reshape(S, M)
    order = np.argsort(bic, axis=1)
    keep = np.zeros((S, M), dtype=bool)
    np.put_along_axis(keep, order[:, :3], True, axis=1)
    np.put_along_axis(keep, np.argmin(np.where(plausible, bic, np.inf), axis=1)[:, None], True, axis=1)
    keep &= np.isfinite(bic)
    final = np.flatnonzero(keep.reshape(-1))
    at = np.searchsorted(rows, final)
    theta_f, cost_f, plausible_f = _refine(problem, Yfit[final // M], theta_r[at], g_flat[at], blur_flat[at])
    bic = np.full(S * M, np.inf)
    bic[final] = problem.bic(cost_f, g_flat[at], scale2[final // M])
    plausible = np.zeros(S * M, dtype=bool)
    plausible[final] = plausible_f
    best = _choose(bic.reshape(S, M), plausible.reshape(S, M)) + np.arange(S) * M
    where = np.searchsorted(final, best)  # the winners among the refined ones
    theta, g_best, Yb, plausible = theta_f[where], g_flat[at][where], Yfit, plausible_f[where]
    blur = blur_flat[at][where]
    bic_best = bic[best]

    # the runner-up: the best refined candidate that is another reading (a quarter of the
    # spacing between neighbouring orders away, or more)
    apart = 0.25 * problem.lam[0] / (2.0 * problem.q_max)
    d_all = np.full(S * M, np.nan)
    d_all[final] = theta_f[:, 0]
    cost_all = np.full(S * M, np.nan)
    cost_all[final] = cost_f
    other = np.where(np.abs(d_all.reshape(S, M) - theta[:, :1]) > apart, bic.reshape(S, M), np.inf)
    second = np.argmin(other, axis=1)
    has = np.isfinite(other[np.arange(S), second])
    pick = second + np.arange(S) * M
    runner_up = np.where(has, d_all[pick], np.nan)
    runner_up_cost = np.where(has, cost_all[pick], np.nan)
    runner_up_dbic = np.where(has, bic[pick] - bic_best, np.nan)

    if problem.nested:
        g_low = _best_gain_columns(problem, Yb, theta, 1, problem.gain_columns(theta[:, 0]), blur)
        redo = np.flatnonzero(g_low != g_best)
        if redo.size:
            th2, cost2, pos2 = _refine(problem, Yb[redo], theta[redo], g_low[redo], blur[redo])
            keep = pos2 | ~plausible[redo]
            theta[redo[keep]], g_best[redo[keep]] = th2[keep], g_low[redo[keep]]

    # 3. uncertainty at the winners: the larger of the local (Jacobian) variances with the
    #    capped response and with the response the data ask for (uncapped), plus the spread of
    #    the thickness's evidence over the grid (all responses, all instrument settings) and
    #    over the runner-up
    g_free = g_best
    if problem.nested:
        g_free = _best_gain_columns(problem, Yb, theta, g_best, GAIN_DEGREE_MAX + 1, blur)
    var_valley = 0.0
    if k > 1:
        rho = _covariances(problem, Yb, theta, g_best, blur)[3]
        theta, var_valley = _index_valley(problem, Yb, theta, g_best, rho, scale2, blur)
    var_blur = 0.0
    if k == 1 and len(problem.blurs) > 1:
        theta, var_blur = _over_settings(problem, Yb, theta, g_best, blur, scale2)
    cov, fitted, cost, _ = _covariances(problem, Yb, theta, g_best, blur)
    cov_free, _, cost_free, rho_free = _covariances(problem, Yb, theta, g_free, blur)
    var = np.maximum(np.einsum("skk->sk", cov), np.einsum("skk->sk", cov_free)) + var_valley
    var[:, 0] += var_blur
    bic_free = problem.bic(cost_free, g_free, scale2)
    grid_all = np.tile(grid, profile[3].shape[0] // grid.size)
    spread = _posterior_spread(grid_all, profile[3], theta, bic_free, rho_free)
    shrink = (1.0 - rho_free) / (1.0 + rho_free)
    w = np.where(has, np.exp(np.minimum(-0.5 * np.nan_to_num(runner_up_dbic, nan=np.inf) * shrink, 50.0)), 0.0)
    ambiguity = w / (1.0 + w) * np.nan_to_num(runner_up - theta[:, 0]) ** 2
    var[:, 0] += np.maximum(spread, ambiguity)
    return {"problem": problem, "theta": theta, "var": var, "cost": cost, "fitted": fitted,
            "g": g_best, "p_lin": problem.p_b + g_best, "blur": blur, "runner_up": runner_up,
            "runner_up_cost": runner_up_cost, "runner_up_dbic": runner_up_dbic}


#: the largest magnitude of a spectrum value (any units): beyond it squares overflow
MAX_VALUE = 1e100


def estimated_memory_bytes(wavelengths_nm, model, thickness_range_nm=None, spectra=1) -> int:
    """About how many bytes :func:`fit_spectra` needs at its peak for ``spectra`` spectra on
    the strictly increasing ``wavelengths_nm``: the thickness tables (on the fine wavelength
    grid, and at the samples for every instrument setting), a chunk of the thickness grid's
    design matrices, and the per-spectrum profiles. Computed from the sizes alone, before
    anything is allocated."""
    lam = np.asarray(wavelengths_nm, dtype=np.float64)
    n = lam.size
    lo, hi = _thickness_range(lam, model, thickness_range_nm)
    q = model.phase_index(lam)
    _, width = _pixels(lam, 1)
    h = max(min(float(np.min(width)), float(np.min(lam * lam / (2.0 * q * hi))) / 12.0), np.ptp(lam) / _MAX_FINE)
    fine = np.ptp(lam) / h + 8.0 * max(RESOLUTIONS_NM) / _FWHM / h
    q_max = float(q.max())
    T = (hi - lo + 9.0 * max(SPREADS_NM)) / (0.4 * lam[0] / (4.0 * np.pi * q_max)) + 4
    B = (2 * len(SPREADS_NM) - 1) * (2 * len(RESOLUTIONS_NM) - 1)  # the grid and its half steps
    K = max(int(np.ceil((hi - lo) / (lam[0] / (8.0 * q_max)))) + 1, 16)
    G = GAIN_DEGREE_MAX + 1
    P = G + BACKGROUND_DEGREE + 1
    words = (4 * T * fine + 2 * B * T * n + 16 * n * P * 12 + n * G * (G + P)
             + 8 * B * K * int(spectra) + 16 * n * int(spectra))
    return int(8 * 1.2 * words + 64e6)


def instrument_reflectance(wavelengths_nm, model, thickness_nm, thickness_spread_nm=0.0, resolution_nm=0.0):
    """The reflectance the fit's model of the instrument reads at the strictly increasing
    ``wavelengths_nm`` for films of thicknesses ``thickness_nm`` (K,): averaged over a
    Gaussian thickness spread (standard deviation, nm), seen through a Gaussian line (full
    width at half maximum, nm) and integrated over each pixel's width. Returns (K, n).

    Examples
    --------
    >>> lam = np.linspace(450.0, 800.0, 200)
    >>> film = FilmModel(1.33, 1.0)
    >>> sharp, soft = (instrument_reflectance(lam, film, [3000.0], s)[0] for s in (0.0, 50.0))
    >>> bool(np.ptp(soft) < 0.7 * np.ptp(sharp))
    True
    """
    lam = np.asarray(wavelengths_nm, dtype=np.float64)
    d = np.atleast_1d(np.asarray(thickness_nm, dtype=np.float64))
    hi = max(float(d.max()) * 1.1, 100.0)
    problem = _Problem(lam, model, None, None, (max(float(d.min()) * 0.9, 0.1), hi), False,
                       BACKGROUND_DEGREE, (float(thickness_spread_nm),), (float(resolution_nm),))
    return problem.reflectance(d)


def fit_spectra(wavelengths_nm, spectra, model, *, background=None, reference=None,
                thickness_range_nm=None, fit_film_ior=False, thickness_spread_nm=None,
                resolution_nm=None):
    """Fit the film thickness (and index) of spectra sampled on one wavelength grid.

    Parameters
    ----------
    wavelengths_nm : (n,) array_like
        Strictly increasing wavelengths, nm; at least :data:`MIN_POINTS`.
    spectra : (n,) or (S, n) array_like
        Measured intensities (any units; raw counts are fine).
    model : FilmModel
        The known optics (film dispersion, substrate, angle).
    background, reference : (n,) array_like, optional
        A background spectrum (no film reflection: a black film, a dark reading) and a white
        reference spectrum, on the same wavelengths.
    thickness_range_nm : (float, float), optional
        Thicknesses searched; default :data:`DEFAULT_THICKNESS_RANGE_NM`, the upper end capped
        where fringes at the shortest wavelength would be less than two samples apart.
    fit_film_ior : bool
        Also fit an offset to the film index (the given index is the start).
    thickness_spread_nm : float, optional
        The thickness spread over the light spot (a standard deviation, nm) when known; by
        default the fit chooses among :data:`SPREADS_NM`.
    resolution_nm : float, optional
        The instrument's line width (full width at half maximum, nm) when known; by default
        the fit chooses among :data:`RESOLUTIONS_NM`. With ``fit_film_ior`` neither is fitted
        (default 0: the loss of fringe contrast trades against the index).

    Returns
    -------
    list of SpectrumFit
        One per spectrum, in order.
    """
    lam = np.asarray(wavelengths_nm, dtype=np.float64)
    Y = np.atleast_2d(np.asarray(spectra, dtype=np.float64))
    if lam.ndim != 1 or Y.ndim != 2 or Y.shape[1] != lam.size:
        raise ValueError("wavelengths_nm must be 1-D and match the last axis of spectra")
    if lam.size < MIN_POINTS:
        raise ValueError(f"a spectrum needs at least {MIN_POINTS} samples, got {lam.size}")
    if not np.all(np.diff(lam) > 0):
        raise ValueError("wavelengths_nm must be strictly increasing")
    if not np.all(np.isfinite(Y)):
        raise ValueError("spectra contain NaN or infinite values")
    if np.max(np.abs(Y)) > MAX_VALUE:
        raise ValueError(f"spectra hold values beyond {MAX_VALUE:g} in magnitude")
    bg = None if background is None else np.asarray(background, dtype=np.float64)
    ref = None if reference is None else np.asarray(reference, dtype=np.float64)
    for name, arr in (("background", bg), ("reference", ref)):
        if arr is not None and (arr.shape != lam.shape or not np.all(np.isfinite(arr))):
            raise ValueError(f"{name} must be finite and sampled on the spectra's wavelengths")
    d_range = _thickness_range(lam, model, thickness_range_nm)

    for name, arr in (("background", bg), ("reference", ref)):
        if arr is not None and np.max(np.abs(arr)) > MAX_VALUE:
            raise ValueError(f"{name} holds values beyond {MAX_VALUE:g} in magnitude")
    Yfit = Y - bg[None, :] if bg is not None else Y
    flat = np.flatnonzero(np.ptp(Yfit, axis=1) <= 1e-12 * np.max(np.abs(Yfit), axis=1))
    if flat.size:
        raise ValueError(f"spectrum {int(flat[0])} does not vary: a spectrum without variation holds no "
                         f"thickness information")
    S, n = Y.shape[0], lam.size
    # with a fitted index the instrument is taken as given (default: neither spread nor a
    # line wider than a pixel): its washing out of the fringes trades against the index
    spreads = ((0.0,) if fit_film_ior else SPREADS_NM) if thickness_spread_nm is None else (float(thickness_spread_nm),)
    resolutions = (((0.0,) if fit_film_ior else RESOLUTIONS_NM) if resolution_nm is None
                   else (float(resolution_nm),))
    for name, values in (("thickness_spread_nm", spreads), ("resolution_nm", resolutions)):
        if not all(np.isfinite(v) and 0.0 <= v <= 1000.0 for v in values):
            raise ValueError(f"{name} must be from 0 to 1000 nm")
    problem = _Problem(lam, model, bg, ref, d_range, fit_film_ior,
                       None if bg is not None else BACKGROUND_DEGREE, spreads, resolutions)
    out = _fit_problem(problem, Yfit)
    theta, var, cost, fitted, g_best, p_lin = (out[key] for key in ("theta", "var", "cost", "fitted", "g", "p_lin"))
    k = problem.k
    sigma_noise = _noise_sigma(Yfit)
    results = []
    for i in range(S):
        d = float(theta[i, 0])
        delta = float(theta[i, 1]) if k > 1 else 0.0
        dof = max(n - int(p_lin[i]) - k, 1)
        results.append(SpectrumFit(
            thickness_nm=d,
            thickness_sigma_nm=float(np.sqrt(var[i, 0])),
            film_ior=problem.n_ref + delta,
            film_ior_sigma=float(np.sqrt(var[i, 1])) if k > 1 else None,
            film_ior_wavelength_nm=float(problem.lam_ref),
            rms_residual=float(np.sqrt(cost[i] / n)),
            chi2=float(cost[i] / dof / max(float(sigma_noise[i]) ** 2, 1e-300)),
            fringes=float(model.fringes(lam, d, delta)),
            gain_degree=int(g_best[i]) - 1 if problem.nested else None,
            at_bound=bool(np.isclose(d, problem.d_lo) or np.isclose(d, problem.d_hi)),
            n_points=int(n),
            fitted=fitted[i] + (bg if bg is not None else 0.0),
            thickness_spread_nm=problem.blurs[int(out["blur"][i])][0],
            resolution_nm=problem.blurs[int(out["blur"][i])][1],
            runner_up_thickness_nm=float(out["runner_up"][i]),
            runner_up_chi2=float(out["runner_up_cost"][i] / dof / max(float(sigma_noise[i]) ** 2, 1e-300)),
            runner_up_delta_bic=float(out["runner_up_dbic"][i]),
        ))
    return results
