"""Shape and film thickness from polarized RGB images with a known film index (paper Sec. 4).

``thinfilm reconstruct rgb DATASET --out DIR [--film-ior N2] [--substrate-ior N3]
[--thickness-range MIN MAX] [--method NAME] [--mask FILE]``

Two methods, chosen by name through :data:`METHODS` (the colour-science habit of one
function per published method and a small registry):

``"kobayashi2023"`` (alias ``"paper"``) — :func:`reconstruct_kobayashi2023`, the paper's
method as published:

* zenith from the degree of polarization (Eq. 10) of the grey (RGB-mean) Stokes vector,
  inverted on the DOP curve of the paper's Eqs. 11–16 — the two interfaces summed
  *incoherently*, ``I_s = R_s(t) + T_s(t) R_s(b) T_s(b)`` (and the same for p), with the
  Fresnel terms taken from :func:`thinfilm.bsdf.optics.interface_amplitudes`; the two
  solutions either side of the Brewster angle told apart by the s-polarized intensity
  ``I_max`` (= (S0 + |S1, S2|) / 2 · 2) against its value at the Brewster angle (Sec. 4.2);
* azimuth from the angle of polarization, the s-direction being φ + 90° (Sec. 4.1, 4.3),
  the 180° ambiguity resolved outwards at the occluding boundary and propagated inwards
  (Sec. 4.3, :func:`~thinfilm.reconstruction.masks.resolve_azimuth`);
* thickness by least squares between the observed RGB (S0, the unpolarized appearance) and
  a table of simulated RGB over (zenith, thickness) within the thickness range, at the
  estimated zenith (Sec. 4.4; the table uses the coherent Airy model of the paper's Eq. 2
  through :mod:`thinfilm.bsdf.optics` and the dataset's camera and illuminant).

``"coherent"`` (the default) — :func:`reconstruct_coherent`:

* inverts the coherent thin-film model (:class:`~.rgb_model.FilmCamera`) per pixel, zenith,
  azimuth (mod 180°) and thickness jointly from all K × 3 polarizer × RGB values
  (:mod:`.rgb_invert`: a k-d tree search over (zenith, thickness) then Levenberg–Marquardt,
  both on a bicubic spline of the model tabulated once from the optics core,
  :class:`~.rgb_model.FilmTable`);
* makes the normal field consistent with one surface: the 180° ambiguity is seeded at the
  occluding boundary as above, then the normals are integrated to a height map on the mask
  (confidence-weighted Poisson with a small curvature penalty, :mod:`.surface`), and every
  pixel is re-fitted with a Gaussian prior towards the surface's normal (which fixes the
  sign of the azimuth, and the zenith where polarization is weak, near normal incidence)
  and towards the local median thickness (which fixes pixels that fell into a neighbouring
  thickness basin);
* exports the final height field as ``surface.ply``.

Both write the estimate folder of ``DESIGN.md``. Nothing here reads ground truth: the
object mask comes from the captures (:func:`~.masks.mask_from_intensity`) or ``--mask``.
"""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass, field

import numpy as np

from thinfilm.errors import UserError

from .masks import mask_from_intensity, read_mask_file, resolve_azimuth
from .polarization import aolp_deg, check_polarizer_angles, dolp, fit_stokes
from .rgb_model import FilmCamera

__all__ = [
    "METHODS",
    "DEFAULT_METHOD",
    "PAPER_METHOD",
    "DEFAULT_THICKNESS_RANGE_NM",
    "RGBCapture",
    "RGBResult",
    "reconstruct",
    "reconstruct_kobayashi2023",
    "reconstruct_coherent",
    "incoherent_polarization_curve",
    "normals_from_angles",
    "cli_main",
]

#: Thickness range searched when none is given (the span of the paper's Fig. 5).
DEFAULT_THICKNESS_RANGE_NM = (100.0, 1000.0)


@dataclass
class RGBCapture:
    """Polarized RGB captures and what is known about the rig.

    Attributes
    ----------
    images : dict angle (deg) → (H, W, 3) linear camera RGB.
    model : the forward model (film and substrate indices, camera, illuminant, bands).
    mask : (H, W) bool, the pixels to reconstruct.
    thickness_range_nm : (min, max).
    pixel_size : size of one pixel in scene units (scales ``surface.ply``).
    """

    images: dict
    model: FilmCamera
    mask: np.ndarray
    thickness_range_nm: tuple = DEFAULT_THICKNESS_RANGE_NM
    pixel_size: float = 1.0

    @property
    def angles_deg(self) -> list:
        return sorted(self.images)

    def stack(self) -> np.ndarray:
        """(H, W, K, 3) images in the order of :attr:`angles_deg`."""
        return np.stack([np.asarray(self.images[a], dtype=np.float64) for a in self.angles_deg], axis=2)


@dataclass
class RGBResult:
    """Estimate: ``normals`` (H, W, 3), ``thickness_nm`` (H, W), ``valid`` (H, W) bool,
    ``height`` (H, W) or None (scene units), ``info`` (extra keys for ``estimate.json``)."""

    normals: np.ndarray
    thickness_nm: np.ndarray
    valid: np.ndarray
    height: np.ndarray | None = None
    info: dict = field(default_factory=dict)


def normals_from_angles(zenith_deg, azimuth_deg):
    """Unit normals (..., 3) from zenith and azimuth in degrees (camera frame of DESIGN.md)."""
    t = np.radians(zenith_deg)
    p = np.radians(azimuth_deg)
    return np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], axis=-1)


# ------------------------------------------------------------------------------------------
# The paper's method
# ------------------------------------------------------------------------------------------

def incoherent_polarization_curve(film_ior: float, substrate_ior: float, zenith_deg):
    """The paper's Eqs. 11–16: s and p intensities of the film with its two interfaces summed
    incoherently, ``I_s = R_s(t) + T_s(t) R_s(b) T_s(b)``, and the DOP ``(I_s - I_p)/(I_s + I_p)``.

    ``t`` is the air–film interface at the zenith angle, ``b`` the film–substrate interface at
    the refracted angle θ2 (Snell); ``T = 1 - R`` for these lossless interfaces, which equals
    the paper's Eqs. 15–16. The Fresnel amplitudes come from the optics core.

    Returns
    -------
    I_s, I_p, dop : arrays shaped like ``zenith_deg``.
    """
    from thinfilm.bsdf.optics import interface_amplitudes

    c1 = np.cos(np.radians(np.asarray(zenith_deg, dtype=np.float64)))
    rs_t, rp_t = interface_amplitudes(c1, 1.0, film_ior)
    sin2 = (1.0 - c1 ** 2) / film_ior ** 2
    c2 = np.sqrt(np.clip(1.0 - sin2, 0.0, 1.0))
    rs_b, rp_b = interface_amplitudes(c2, film_ior, substrate_ior)
    Rs_t, Rp_t = np.abs(rs_t) ** 2, np.abs(rp_t) ** 2
    Rs_b, Rp_b = np.abs(rs_b) ** 2, np.abs(rp_b) ** 2
    I_s = Rs_t + (1.0 - Rs_t) * Rs_b * (1.0 - Rs_b)
    I_p = Rp_t + (1.0 - Rp_t) * Rp_b * (1.0 - Rp_b)
    with np.errstate(invalid="ignore", divide="ignore"):
        dop = np.where(I_s + I_p > 0, (I_s - I_p) / (I_s + I_p), 0.0)
    return I_s, I_p, dop


def _scalar_index(model: FilmCamera, which: str) -> float:
    """A single index for the paper's (non-dispersive) formulas: the value at 550 nm."""
    from thinfilm.bsdf.materials import as_dispersion

    return float(as_dispersion(getattr(model, which))(550.0))


def zenith_from_dop(dop_obs, I_s_obs, film_ior, substrate_ior, zenith_max_deg: float = 89.9):
    """The paper's Sec. 4.2: zenith from the DOP, branch by the s-intensity at Brewster.

    Returns
    -------
    zenith_deg : array like ``dop_obs``.
    brewster_deg : float
    """
    grid = np.linspace(0.0, zenith_max_deg, 4000)
    I_s, _, dop = incoherent_polarization_curve(film_ior, substrate_ior, grid)
    kb = int(np.argmax(dop))
    brewster = grid[kb]
    low = np.interp(dop_obs, dop[:kb + 1], grid[:kb + 1])               # rising branch
    high = np.interp(dop_obs, dop[kb:][::-1], grid[kb:][::-1])          # falling branch
    larger = I_s_obs > I_s[kb]
    return np.where(larger, high, low), brewster


def reconstruct_kobayashi2023(capture: RGBCapture, progress: bool = False) -> RGBResult:
    """The paper's polarized-RGB method as published (see the module docstring)."""
    timings = {}
    t0 = time.perf_counter()
    mask = capture.mask
    stack = capture.stack()                      # (H, W, K, 3)
    angles = capture.angles_deg
    S0, S1, S2 = fit_stokes(np.moveaxis(stack, 2, 0), angles)   # (H, W, 3) each
    g0, g1, g2 = S0.mean(axis=-1), S1.mean(axis=-1), S2.mean(axis=-1)
    rho = dolp(g0, g1, g2)
    I_s_obs = g0 + np.hypot(g1, g2)              # 2 I_max: the s-polarized reflectance
    n2 = _scalar_index(capture.model, "film_ior")
    n3 = _scalar_index(capture.model, "substrate_ior")
    zenith, brewster = zenith_from_dop(rho, I_s_obs, n2, n3)
    phi_mod = np.mod(aolp_deg(g1, g2) - 90.0, 180.0)   # s-direction = φ + 90°
    azimuth = resolve_azimuth(phi_mod, zenith, mask)
    timings["shape"] = time.perf_counter() - t0

    # Thickness: least squares against simulated RGB S0 over the range, at the pixel's zenith.
    t1 = time.perf_counter()
    lo, hi = capture.thickness_range_nm
    thick_grid = np.linspace(lo, hi, max(2, int(round(hi - lo)) + 1))   # 1 nm steps
    zen_step = 0.5
    rows = np.round(np.where(mask, zenith, 0.0) / zen_step).astype(int)
    thickness = np.zeros(mask.shape)
    for r in _progress(np.unique(rows[mask]), progress, "thickness table"):
        sel = mask & (rows == r)
        S0_tab, _ = capture.model.rgb_s0_p(np.cos(np.radians(r * zen_step)), thick_grid)   # (D, 3)
        err = np.sum((S0[sel][:, None, :] - S0_tab[None, :, :]) ** 2, axis=-1)
        thickness[sel] = thick_grid[np.argmin(err, axis=1)]
    timings["thickness"] = time.perf_counter() - t1

    normals = normals_from_angles(zenith, np.nan_to_num(azimuth))
    valid = mask & np.isfinite(zenith) & np.isfinite(azimuth)
    info = {"brewster_angle_deg": float(brewster), "timings_s": timings,
            "notes": "paper Sec. 4 as published: incoherent DOP model (Eqs. 11-16), "
                     "boundary azimuth propagation, RGB table thickness search"}
    return RGBResult(normals, thickness, valid, None, info)


# ------------------------------------------------------------------------------------------
# The default: joint coherent inversion + surface consistency
# ------------------------------------------------------------------------------------------

def _normal_information(info, n_xy):
    """Information (precision) on the normal's image-plane part (a, b) from the fit's
    Gauss–Newton matrix in (v1, v2, d), with d marginalized out. ``v = (a² - b², 2ab)``."""
    H = info
    Hvv = H[:, :2, :2]
    Hvd = H[:, :2, 2]
    Hdd = np.maximum(H[:, 2, 2], 1e-300)
    Iv = Hvv - Hvd[:, :, None] * Hvd[:, None, :] / Hdd[:, None, None]
    a, b = n_xy[:, 0], n_xy[:, 1]
    J = 2.0 * np.stack([np.stack([a, -b], -1), np.stack([b, a], -1)], axis=-2)   # dv/d(a, b)
    return np.einsum("nki,nkl,nlj->nij", J, Iv, J)


def _local_median(values, mask, size: int = 5):
    """Median of ``values`` over the mask pixels of each ``size`` × ``size`` window."""
    import warnings

    v = np.where(mask, values, np.nan)
    pad = size // 2
    H, W = v.shape
    vp = np.pad(v, pad, constant_values=np.nan)
    win = np.lib.stride_tricks.sliding_window_view(vp, (size, size))[:H, :W].reshape(H, W, -1)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)   # all-NaN windows outside the mask
        med = np.nanmedian(win, axis=-1)
    return np.where(np.isfinite(med), med, values)


def reconstruct_coherent(capture: RGBCapture, progress: bool = False, rounds: int = 1,
                         normal_prior_sigma: float = 0.01, thickness_prior_sigma_nm: float = 15.0,
                         smoothness: float = 2.0) -> RGBResult:
    """Joint per-pixel inversion of the coherent model, then surface consistency.

    Parameters
    ----------
    capture : RGBCapture
    rounds : integrate → re-fit rounds.
    normal_prior_sigma : σ of the prior on each normal's image-plane part around the
        integrated surface's normal (unitless; 0.01 ≈ 0.6° near normal incidence). Where the
        polarization data are confident (zenith beyond ~20°) they outweigh it.
    thickness_prior_sigma_nm : σ of the prior on thickness around its 5 × 5 local median.
    smoothness : curvature penalty of the height integration (relative to the mean weight).
    """
    from .rgb_invert import PixelPrior, build_table, invert_pixels, refine_pixels
    from .surface import height_to_normals, integrate_normals

    timings = {}
    mask = capture.mask
    angles = capture.angles_deg
    K = len(angles)
    I_obs = capture.stack()[mask]                       # (N, K, 3)
    N = I_obs.shape[0]
    model = capture.model
    rng_nm = capture.thickness_range_nm

    bar = _progress_bar(progress, 2 + rounds, "coherent")
    t = time.perf_counter()
    table = build_table(model, rng_nm)
    timings["table"] = time.perf_counter() - t
    t = time.perf_counter()
    fit = invert_pixels(model, I_obs, angles, rng_nm, table=table)
    timings["per_pixel"] = time.perf_counter() - t
    bar.update(2)

    t = time.perf_counter()
    # Noise level of the data, from the residuals (robust; dof = 3K - 3).
    sigma = float(np.sqrt(np.median(fit.cost) / max(3 * K - 3, 1)))
    sigma = max(sigma, 1e-12)
    zen = np.full(mask.shape, np.nan)
    az = np.full(mask.shape, np.nan)
    thick = np.full(mask.shape, np.nan)
    zen[mask], az[mask], thick[mask] = fit.zenith_deg, fit.azimuth_deg, fit.thickness_nm
    n_xy = np.sin(np.radians(fit.zenith_deg))[:, None] * np.stack(
        [np.cos(np.radians(fit.azimuth_deg)), np.sin(np.radians(fit.azimuth_deg))], axis=-1)
    info_n = _normal_information(fit.info, n_xy) / sigma ** 2
    w_n = np.full(mask.shape, 0.0)
    w_n[mask] = 0.5 * np.trace(info_n, axis1=1, axis2=2)
    az = resolve_azimuth(az, zen, mask)
    timings["azimuth"] = time.perf_counter() - t

    t = time.perf_counter()
    height = None
    cost = fit.cost
    for _ in range(rounds):
        normals = normals_from_angles(zen, np.nan_to_num(az))
        nz = np.clip(normals[..., 2], 0.0, 1.0)
        weights = np.where(mask, w_n * nz ** 4, 0.0)
        height = integrate_normals(normals, mask, weights, smoothness=smoothness)
        n_surf = height_to_normals(height, mask)
        d_med = _local_median(thick, mask)
        prior = PixelPrior(
            normal_xy=n_surf[mask][:, :2],
            normal_weight=np.full(N, sigma / normal_prior_sigma),
            thickness_nm=d_med[mask],
            thickness_weight=np.full(N, sigma / thickness_prior_sigma_nm))
        # Start from the current estimate, on the surface's side; thickness outliers restart
        # from the local median.
        d0 = thick[mask]
        far = np.abs(d0 - d_med[mask]) > 3 * thickness_prior_sigma_nm
        d0 = np.where(far, d_med[mask], d0)
        refit = refine_pixels(table, I_obs, angles, zen[mask], d0, az[mask], prior=prior)
        phi = np.radians(refit.azimuth_deg)
        dot = n_surf[mask][:, 0] * np.cos(phi) + n_surf[mask][:, 1] * np.sin(phi)
        az_new = np.mod(refit.azimuth_deg + np.where(dot < 0, 180.0, 0.0), 360.0)
        zen[mask], az[mask], thick[mask] = refit.zenith_deg, az_new, refit.thickness_nm
        cost = refit.data_cost
        bar.update(1)
    bar.close()
    # The exported surface: every final normal is now good (data plus surface prior), so they
    # are weighted alike except towards the silhouette (slopes clipped), with a light
    # curvature penalty — the heavy one above only serves to carry the surface across regions
    # where polarization says little.
    normals = normals_from_angles(zen, np.nan_to_num(az))
    nz = np.clip(normals[..., 2], 0.0, 1.0)
    height = integrate_normals(normals, mask, np.where(mask, nz ** 2, 0.0), smoothness=0.05)
    timings["surface"] = time.perf_counter() - t

    # Pixels whose final fit to the data (priors left out) is far worse than the noise are
    # reported as invalid.
    chi2 = cost / (sigma ** 2 * max(3 * K - 3, 1))
    ok = np.isfinite(chi2) & (chi2 < 50.0)
    valid = np.zeros(mask.shape, dtype=bool)
    valid[mask] = ok
    info = {"timings_s": timings, "noise_sigma": sigma,
            "notes": "coherent Airy model inverted jointly per pixel (zenith, azimuth, thickness), "
                     "then integrated to one surface and re-fitted with surface and thickness priors"}
    return RGBResult(normals, np.where(mask, thick, 0.0), valid, height * capture.pixel_size, info)


# ------------------------------------------------------------------------------------------
# Registry, input handling, CLI
# ------------------------------------------------------------------------------------------

PAPER_METHOD = "kobayashi2023"
DEFAULT_METHOD = "coherent"
#: name → function(capture, progress) -> RGBResult
METHODS = {
    "kobayashi2023": reconstruct_kobayashi2023,
    "coherent": reconstruct_coherent,
}
_ALIASES = {"paper": "kobayashi2023", "default": "coherent"}


def reconstruct(capture: RGBCapture, method: str = DEFAULT_METHOD, progress: bool = False) -> RGBResult:
    """Run a method of :data:`METHODS` by name (``"paper"`` and ``"default"`` are aliases)."""
    name = _ALIASES.get(method, method)
    if name not in METHODS:
        raise UserError(f"--method: unknown method {method!r}, expected one of "
                        f"{', '.join(sorted(list(METHODS) + list(_ALIASES)))}")
    result = METHODS[name](capture, progress=progress)
    result.info["method"] = name
    return result


def _progress(iterable, enabled, desc):
    if not enabled:
        return iterable
    from tqdm import tqdm

    return tqdm(iterable, desc=desc, file=sys.stderr, disable=not sys.stderr.isatty(), leave=False)


class _NoBar:
    def update(self, n=1):
        pass

    def close(self):
        pass


def _progress_bar(enabled, total, desc):
    """A tqdm bar on stderr (only on a terminal), or a do-nothing stand-in."""
    if not enabled or not sys.stderr.isatty():
        return _NoBar()
    from tqdm import tqdm

    return tqdm(total=total, desc=desc, file=sys.stderr, leave=False)


def _given_or_meta_index(given, meta, key, option, meta_path):
    """(dispersion, where) for an index from the command line, else from ``meta.json``."""
    if given is not None:
        return _index_from(given, option), option
    if key not in meta:
        raise UserError(f"{meta_path}: no '{key}'; pass the index with {option}")
    where = f"{meta_path}: {key}"
    return _index_from(meta[key], where), where


def _index_from(value, where):
    """A dispersion model from a CLI number or a meta.json value; UserError when not > 1."""
    from thinfilm.bsdf.materials import as_dispersion

    try:
        disp = as_dispersion(value)
    except (ValueError, TypeError) as e:
        raise UserError(f"{where}: {e}") from None
    return disp


def capture_from_dataset(dataset_path, film_ior=None, substrate_ior=None, thickness_range=None,
                         mask_path=None) -> tuple[RGBCapture, dict]:
    """Read a dataset folder into an :class:`RGBCapture` (no ground truth is used).

    Raises
    ------
    UserError
        Missing or too few polarizer layers, unknown or invalid indices (<= 1), a thickness
        range with MIN >= MAX or MIN < 0, a mask of the wrong shape.
    """
    from thinfilm.colorimetry import DEFAULT_CAMERA, DEFAULT_ILLUMINANT
    from thinfilm.dataset import read_dataset

    ds = read_dataset(dataset_path, need=("polarized_rgb",), optional=())
    meta_path = f"{ds.path / 'meta.json'}"
    exr_path = f"{ds.path / 'polarized_rgb.exr'}"
    if not ds.polarized_rgb:
        raise UserError(f"{exr_path}: no polarizer layers (pol000, pol045, ...) found")
    check_polarizer_angles(ds.polarizer_angles_deg, exr_path)

    if thickness_range is None:
        thickness_range = DEFAULT_THICKNESS_RANGE_NM
    lo, hi = (float(v) for v in thickness_range)
    if not (np.isfinite(lo) and np.isfinite(hi)) or lo >= hi or lo < 0:
        raise UserError(f"--thickness-range: expected 0 <= MIN < MAX in nm, got {lo:g} {hi:g}")

    wl = ds.wavelengths_nm
    if wl.size < 2:
        wl = np.arange(400.0, 721.0, 4.0)
        print(f"thinfilm: warning: {meta_path}: no 'wavelengths_nm', modelling the camera over "
              f"400-720 nm in 4 nm steps", file=sys.stderr)
    meta = ds.meta
    n2, n2_where = _given_or_meta_index(film_ior, meta, "film_ior", "--film-ior", meta_path)
    n3, n3_where = _given_or_meta_index(substrate_ior, meta, "substrate_ior", "--substrate-ior", meta_path)
    for disp, where in ((n2, n2_where), (n3, n3_where)):
        vals = np.asarray(disp(wl), dtype=np.float64)
        if not np.all(np.isfinite(vals)) or np.any(vals <= 1.0):
            raise UserError(f"{where}: refractive index must be > 1, got {float(np.min(vals)):g}")
    substrate_k = float(meta.get("substrate_k", 0.0) or 0.0) if substrate_ior is None else 0.0
    for key, default in (("camera", DEFAULT_CAMERA), ("illuminant", DEFAULT_ILLUMINANT)):
        if key not in meta:  # a real capture's meta.json may lack them: say what is assumed
            print(f"thinfilm: warning: {meta_path}: no '{key}', assuming {default!r}", file=sys.stderr)
    model = FilmCamera(wl, n2, n3, substrate_k, meta.get("camera", DEFAULT_CAMERA),
                       meta.get("illuminant", DEFAULT_ILLUMINANT))

    images = {a: np.asarray(img, dtype=np.float64) for a, img in ds.polarized_rgb.items()}
    shape = next(iter(images.values())).shape[:2]
    if mask_path is not None:
        mask = read_mask_file(mask_path, shape)
    else:
        S0 = fit_stokes(np.stack([images[a] for a in sorted(images)]), sorted(images))[0]
        mask = mask_from_intensity(np.clip(S0.mean(axis=-1), 0.0, None))
    if not mask.any():
        raise UserError(f"{mask_path or exr_path}: the object mask is empty")
    pixel_size = 1.0
    proj = meta.get("projection")
    if isinstance(proj, dict) and isinstance(proj.get("pixel_size"), (int, float)):
        pixel_size = float(proj["pixel_size"])
    info = {"film_ior": meta.get("film_ior") if film_ior is None else float(film_ior),
            "substrate_ior": meta.get("substrate_ior") if substrate_ior is None else float(substrate_ior),
            "thickness_range_nm": [lo, hi]}
    return RGBCapture(images, model, mask, (lo, hi), pixel_size), info


def cli_main(args) -> int:
    """Entry point of ``thinfilm reconstruct rgb``."""
    from .estimate import write_estimate

    method = args.method or DEFAULT_METHOD
    if _ALIASES.get(method, method) not in METHODS:
        raise UserError(f"--method: unknown method {method!r}, expected one of "
                        f"{', '.join(sorted(list(METHODS) + list(_ALIASES)))}")
    t0 = time.perf_counter()
    capture, info = capture_from_dataset(args.dataset, args.film_ior, args.substrate_ior,
                                         args.thickness_range, getattr(args, "mask", None))
    t_read = time.perf_counter() - t0
    result = reconstruct(capture, method, progress=True)
    info.update(result.info)
    info["timings_s"] = {"read": t_read, **result.info.get("timings_s", {}),
                         "total": time.perf_counter() - t0}
    info["coverage"] = float(result.valid.sum() / max(capture.mask.sum(), 1))
    write_estimate(args.out, result.normals, result.thickness_nm, result.valid, info,
                   height=result.height, pixel_size=capture.pixel_size)
    print(f"wrote {args.out} (method {info['method']}, {int(result.valid.sum())} pixels, "
          f"{info['timings_s']['total']:.1f} s)")
    return 0
