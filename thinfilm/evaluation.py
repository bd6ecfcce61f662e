"""Evaluation: re-render an estimate through the ``thinfilm`` BSDF and score it.

``thinfilm evaluate DATASET ESTIMATE --out DIR`` (``docs/design.md``, *Evaluation output*):

1. The estimated normals, thickness and film index are re-rendered in Mitsuba with the
   dataset's rig (orthographic camera, uniform dome, polarizer angles, bands and passband,
   no noise) as a *normal-mapped plane*: each valid pixel becomes a small flat patch under
   the orthographic camera whose vertices carry that pixel's estimated normal as shading
   normal, with the estimated thickness looked up at the pixel centre
   (:func:`thinfilm.generators.scene.normal_map_scene`, rendered band by band by
   :func:`thinfilm.generators.render.render_stokes_cube`, the code that rendered the
   captures). A pixel-centre ray therefore meets exactly the estimated normal and
   thickness, and the plugin evaluates its Mueller matrix in that shading frame. The dome
   depends on direction only, so for the convex presets the plane sees the same light as
   the true geometry; interreflections of concave shapes are not reproduced (the paper's
   model has none either).
2. The re-rendered Stokes cube becomes the same captures the dataset holds: s-polarized
   spectra ``S0 + sqrt(S1² + S2²)`` and polarized camera RGB
   (:func:`thinfilm.core.model.captures_from_stokes`).
3. Errors per pixel over the object mask (ground-truth mask ∧ estimate ``valid``):
   normal angle, zenith, thickness; ΔE*ab (CIE 1976, paper Eq. 31) and ΔE00 between the
   captured and re-rendered s-polarized appearance, in CIELAB from spectra
   (:mod:`thinfilm.color_difference`), or, when the dataset holds no spectra, from the
   s-polarized camera RGB (Stokes fit of :func:`thinfilm.core.conventions.fit_stokes`)
   through the fitted camera→XYZ matrix; spectral RMSE (paper Eq. 32)
   ``sqrt(Σ_λ (R_o − R_e)² / N)`` per pixel in reflectance units (0.02 = 2 %).

Outputs: ``metrics.json`` (exactly the keys of ``docs/design.md``, *Evaluation output*),
``evaluation.json`` (definitions, coverage, colour path), ``rerendered.exr`` (re-rendered
captures), ``errors.exr`` (error maps) and PNG figures (:mod:`thinfilm.figures`).
"""

from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np

from thinfilm.core.errors import UserError
from thinfilm.core.variants import RENDER_VARIANT

__all__ = [
    "METRIC_KEYS",
    "BOUND_KEYS",
    "CALIBRATION_KEYS",
    "sigma_calibration",
    "bound_metrics",
    "RENDER_VARIANT",
    "summarize",
    "angular_error_deg",
    "geometry_error_maps",
    "s_polarized_rgb",
    "appearance_error_maps",
    "metrics_from_maps",
    "render_normal_map",
    "rerender_estimate",
    "check_estimate",
    "evaluate",
    "cli_main",
]

#: microfacet samples per pixel of the re-rendering of a rough film (at most the captures'):
#: its rendering noise enters ΔE like the captures' noise, and the ground-truth row of a
#: benchmark shows the floor the two set
RERENDER_MAX_SPP = 16

METRIC_KEYS = ("normal_error_deg", "zenith_error_deg", "thickness_error_nm",
               "delta_e_ab", "delta_e_2000", "spectral_rmse")

#: the Cramér-Rao bound beside the errors (:func:`bound_metrics`): the bound's statistics with
#: ``rms``, the errors' RMS on the same pixels, and the efficiencies (bound RMS / error RMS)
BOUND_KEYS = ("crlb_normal_deg", "crlb_thickness_nm", "normal_error_rms_deg", "thickness_error_rms_nm",
              "efficiency_normal", "efficiency_thickness")

#: the calibration of an estimate's own σ (:func:`sigma_calibration`): the share of the scored
#: pixels whose error lies within twice the estimate's ``normal_sigma_deg`` and
#: ``thickness_sigma_nm`` (0.954 for a Gaussian error of that σ; null without σ channels)
CALIBRATION_KEYS = ("normal_within_2sigma", "thickness_within_2sigma")


# -- statistics and per-pixel errors --------------------------------------------------------

def summarize(values, mask=None) -> dict:
    """``{"mean", "median", "p95", "max"}`` of ``values`` over ``mask`` (finite entries only).

    ``p95`` is the 95th percentile with linear interpolation (``numpy.percentile``). With no
    finite value under the mask every entry is ``None``.
    """
    v = np.asarray(values, dtype=np.float64)
    if mask is not None:
        v = v[np.asarray(mask, dtype=bool)]
    v = v[np.isfinite(v)]
    if v.size == 0:
        return {"mean": None, "median": None, "p95": None, "max": None}
    return {"mean": float(v.mean()), "median": float(np.median(v)),
            "p95": float(np.percentile(v, 95.0)), "max": float(v.max())}


def angular_error_deg(normals_a, normals_b) -> np.ndarray:
    """Angle in degrees between two normal fields (..., 3); both are normalized first.

    Uses ``atan2(|a × b|, a · b)``, accurate for small angles too.
    """
    a = np.asarray(normals_a, dtype=np.float64)
    b = np.asarray(normals_b, dtype=np.float64)
    a = a / np.linalg.norm(a, axis=-1, keepdims=True)
    b = b / np.linalg.norm(b, axis=-1, keepdims=True)
    return np.degrees(np.arctan2(np.linalg.norm(np.cross(a, b), axis=-1), np.sum(a * b, axis=-1)))


def geometry_error_maps(ground_truth: dict, estimate) -> dict:
    """Per-pixel ``normal_error_deg``, ``zenith_error_deg`` (``|θ_est − θ_gt|``) and
    ``thickness_error_nm`` (``|d_est − d_gt|``); NaN where the estimate is invalid."""
    from thinfilm.core.conventions import normals_to_angles

    valid = estimate.valid
    normal = np.asarray(estimate.normals, dtype=np.float64)
    with np.errstate(invalid="ignore"):
        zen_est = normals_to_angles(normal / np.linalg.norm(normal, axis=-1, keepdims=True))[0]
        maps = {
            "normal_error_deg": angular_error_deg(estimate.normals, ground_truth["normal"]),
            "zenith_error_deg": np.abs(zen_est - np.asarray(ground_truth["zenith"], dtype=np.float64)),
            "thickness_error_nm": np.abs(np.asarray(estimate.thickness_nm, dtype=np.float64)
                                         - np.asarray(ground_truth["thickness"], dtype=np.float64)),
        }
    return {k: np.where(valid, v, np.nan) for k, v in maps.items()}


def s_polarized_rgb(polarized_rgb: dict, where: str = "polarized_rgb.exr") -> np.ndarray:
    """S-polarized camera RGB ``S0 + sqrt(S1² + S2²)`` per channel (H, W, 3) from polarizer
    images {angle: (H, W, 3)}: the least-squares Stokes fit
    (:func:`thinfilm.core.conventions.stokes_from_polarizer_images`) turned into the
    s-polarized capture (:func:`thinfilm.core.conventions.s_polarized`).

    Raises
    ------
    UserError
        Naming ``where`` when fewer than three distinct polarizer angles are given.
    """
    from thinfilm.core.conventions import s_polarized, stokes_from_polarizer_images

    return s_polarized(*stokes_from_polarizer_images(polarized_rgb, where))


def appearance_error_maps(captured, rendered, wavelengths_nm, illuminant, kind="spectra", camera=None):
    """Per-pixel ΔE*ab, ΔE00 and spectral RMSE between captured and re-rendered appearance.

    Parameters
    ----------
    captured, rendered : ndarray (H, W, B) reflectance spectra, or (H, W, 3) camera RGB
    kind : ``"spectra"`` or ``"camera_rgb"`` (then ``camera`` names the sensitivities; the
        spectral RMSE is NaN, there are no spectra).

    Returns
    -------
    dict with ``delta_e_ab``, ``delta_e_2000``, ``spectral_rmse`` (H, W) and the CIELAB
    images ``lab_captured``, ``lab_rendered`` (H, W, 3).
    """
    from . import color_difference as cd

    captured = np.asarray(captured, dtype=np.float64)
    rendered = np.asarray(rendered, dtype=np.float64)
    if captured.shape != rendered.shape:
        raise ValueError(f"captured {captured.shape} and rendered {rendered.shape} differ in shape")
    if kind == "spectra":
        lab_c = cd.spectra_to_lab(captured, wavelengths_nm, illuminant)
        lab_r = cd.spectra_to_lab(rendered, wavelengths_nm, illuminant)
        rmse = np.sqrt(np.mean((captured - rendered) ** 2, axis=-1))
    elif kind == "camera_rgb":
        lab_c = cd.camera_rgb_to_lab(captured, wavelengths_nm, camera, illuminant)
        lab_r = cd.camera_rgb_to_lab(rendered, wavelengths_nm, camera, illuminant)
        rmse = np.full(captured.shape[:-1], np.nan)
    else:
        raise ValueError(f"kind must be 'spectra' or 'camera_rgb', got {kind!r}")
    return {"delta_e_ab": cd.delta_e_ab(lab_c, lab_r), "delta_e_2000": cd.delta_e_2000(lab_c, lab_r),
            "spectral_rmse": rmse, "lab_captured": lab_c, "lab_rendered": lab_r}


def metrics_from_maps(maps: dict, mask, film_ior_error, bound: dict | None = None) -> dict:
    """``metrics.json`` content: each of :data:`METRIC_KEYS` summarized over ``mask``, plus
    ``film_ior_error``, plus the :data:`BOUND_KEYS` of ``bound`` (:func:`bound_metrics`; all
    None without one)."""
    out = {k: summarize(maps[k], mask) if k in maps else summarize([]) for k in METRIC_KEYS}
    out["film_ior_error"] = None if film_ior_error is None else float(film_ior_error)
    for k in BOUND_KEYS:
        out[k] = (bound or {}).get(k, summarize([]) | {"rms": None} if k.startswith("crlb") else None)
    return out


def _rms(v):
    v = np.asarray(v, dtype=np.float64)
    v = v[np.isfinite(v)]
    return float(np.sqrt(np.mean(v * v))) if v.size else None


def sigma_calibration(estimate, maps: dict, mask) -> dict:
    """:data:`CALIBRATION_KEYS` of an estimate: the share of the pixels of ``mask`` whose
    normal and thickness errors (``maps``) lie within twice the estimate's σ (a pixel with a
    NaN σ counts as outside); None where the estimate reports no σ."""
    out = dict.fromkeys(CALIBRATION_KEYS)
    if estimate.normal_sigma_deg is None or estimate.thickness_sigma_nm is None:
        return out
    for key, err, sig in (("normal_within_2sigma", maps.get("normal_error_deg"), estimate.normal_sigma_deg),
                          ("thickness_within_2sigma", maps.get("thickness_error_nm"), estimate.thickness_sigma_nm)):
        if err is None:
            continue
        sel = mask & np.isfinite(err)
        if sel.any():
            s = np.nan_to_num(np.asarray(sig, dtype=np.float64)[sel], nan=-np.inf)
            out[key] = float(np.mean(err[sel] <= 2.0 * s))
    return out


def bound_capture(estimate, dataset) -> str:
    """The capture an estimate was made from, for its bound
    (:func:`thinfilm.core.bound.estimate_capture`)."""
    from thinfilm.core.bound import estimate_capture

    return estimate_capture(estimate, dataset)


def bound_metrics(dataset, estimate, maps: dict, mask) -> tuple[dict, dict]:
    """The per-pixel Cramér-Rao bound (:func:`thinfilm.core.bound.pixel_bound`) of the capture
    the estimate used, from the ground truth and the dataset's noise model, beside the errors.

    Statistics over the scored pixels (``mask``) whose true zenith lies in
    :data:`thinfilm.core.bound.ZENITH_RANGE_DEG` (where a per-pixel bound is meaningful):
    ``crlb_normal_deg``, ``crlb_thickness_nm`` (``{mean, median, p95, max, rms}``), the
    errors' RMS on the same pixels and ``efficiency_* = bound RMS / error RMS`` (1 for an
    efficient unbiased estimator; above 1 only with priors or bias). Returns ``(metrics,
    info)``; metrics empty where the dataset has no ground truth or no camera noise, or holds a
    stack (one thickness map)."""
    from thinfilm.core.bound import ZENITH_RANGE_DEG, pixel_bound
    from thinfilm.core.model import Rig

    noise = dataset.meta.get("noise") or {}
    gt = dataset.ground_truth
    film = dataset.film()
    if not gt or noise.get("model") != "camera" or not film.is_single:
        why = ("no ground truth" if not gt else "no camera noise" if noise.get("model") != "camera"
               else "a stack (one thickness map)")
        return {}, {"computed": False, "reason": why}
    capture = bound_capture(estimate, dataset)
    obj = gt["mask"]
    b = pixel_bound(Rig.of_dataset(dataset), film, gt["normal"][obj], gt["thickness"][obj], noise, capture)
    crlb_n = np.full(obj.shape, np.nan)
    crlb_d = np.full(obj.shape, np.nan)
    crlb_n[obj], crlb_d[obj] = b["normal_deg"], b["thickness_nm"][:, 0]
    zen = np.degrees(np.arccos(np.clip(gt["normal"][..., 2], -1.0, 1.0)))
    sel = mask & (zen >= ZENITH_RANGE_DEG[0]) & (zen <= ZENITH_RANGE_DEG[1])
    out = {}
    for key, crlb, err in (("normal", crlb_n, maps.get("normal_error_deg")),
                           ("thickness", crlb_d, maps.get("thickness_error_nm"))):
        unit = "deg" if key == "normal" else "nm"
        stats = summarize(crlb, sel)
        stats["rms"] = _rms(crlb[sel])
        out[f"crlb_{key}_{unit}"] = stats
        e_rms = None if err is None else _rms(err[sel & np.isfinite(crlb)])
        out[f"{key}_error_rms_{unit}"] = e_rms
        out[f"efficiency_{key}"] = (stats["rms"] / e_rms if e_rms and stats["rms"] is not None
                                    and np.isfinite(stats["rms"]) else None)
    maps["crlb_normal_deg"], maps["crlb_thickness_nm"] = crlb_n, crlb_d
    info = {"computed": True, "capture": capture, "pixels": int(sel.sum()), "zenith_range_deg": list(ZENITH_RANGE_DEG),
            "noise": noise, "definition": "per-pixel Cramer-Rao bound with the film index known "
                                          "(thinfilm.core.bound); normal: RMS angle; thickness: standard deviation"}
    return out, info


# -- re-rendering -----------------------------------------------------------------------------

def render_normal_map(normals, thickness_nm, valid, wavelengths_nm, film, dome_hole_deg=0.0, band_fwhm_nm=0.0,
                      passband="gaussian", progress=False, roughness=0.0, spp=1) -> dict:
    """Band-integrated Stokes cube of a per-pixel normal and thickness field (any H × W),
    rendered through the ``thinfilm`` plugin under the generator's orthographic camera and
    dome: the generator's :func:`thinfilm.generators.scene.normal_map_scene` and
    :func:`thinfilm.generators.render.render_stokes_cube` (the code that rendered the
    captures). ``film`` is a :class:`thinfilm.core.film.Film`; a rough film (``roughness`` > 0)
    is rendered with ``spp`` microfacet samples per pixel-centre ray, as the generator renders
    it. Needs a vectorized mono polarized variant set by the caller.

    Returns
    -------
    dict ``"S0"``, ``"S1"``, ``"S2"`` → (H, W, B) float64 in reflectance units, Stokes in
    the frame of ``docs/design.md``, *Conventions* (``S1 = I(0°) − I(90°)``, 0° = image +x);
    zero off ``valid``.
    """
    from thinfilm.generators.render import render_stokes_cube, require_render_variant
    from thinfilm.generators.scene import normal_map_scene

    require_render_variant()
    valid = np.asarray(valid, dtype=bool)
    h, w = valid.shape
    wl = np.asarray(wavelengths_nm, dtype=np.float64)
    normals = np.asarray(normals, dtype=np.float64)
    valid = valid & np.all(np.isfinite(normals), axis=-1) & (np.nan_to_num(normals[..., 2]) > 0)
    if not valid.any():
        return {s: np.zeros((h, w, wl.size)) for s in ("S0", "S1", "S2")}
    safe_normals = np.where(valid[..., None], np.nan_to_num(normals), [0.0, 0.0, 1.0])
    thickness = np.where(valid, np.asarray(thickness_nm, dtype=np.float64), 0.0)
    thickness = np.clip(np.nan_to_num(thickness), 0.0, None)
    scene = normal_map_scene(safe_normals, thickness, valid, film, dome_hole_deg=float(dome_hole_deg),
                             roughness=float(roughness))
    if roughness > 0:
        from thinfilm.generators.scene import BSDF_SAMPLING_INTEGRATOR

        # one BSDF sample to the dome per path: each pixel is a flat patch that sees only the dome
        out = render_stokes_cube(scene, wl, float(band_fwhm_nm), passband, progress=progress, spp=int(spp),
                                 seed=0, integrator=dict(BSDF_SAMPLING_INTEGRATOR))
    else:
        out = render_stokes_cube(scene, wl, float(band_fwhm_nm), passband, progress=progress)
    out.pop("mask", None)
    for s in ("S0", "S1", "S2"):
        out[s] = np.where(valid[..., None], out[s], 0.0)
    return out


def rerender_estimate(meta: dict, estimate, film, progress=False) -> dict:
    """Re-render an :class:`~thinfilm.core.io.Estimate` of a film with the dataset's rig
    (``meta.json``: bands, passband, dome, polarizer angles, camera, illuminant, the film's
    roughness, at most :data:`RERENDER_MAX_SPP` samples per pixel; no noise):
    returns the Stokes cube and the noise-free captures ``spectral_s`` (H, W, B) and
    ``polarized_rgb`` {angle: (H, W, 3)} (:func:`thinfilm.core.model.captures_from_stokes`)."""
    from thinfilm.core.colorimetry import DEFAULT_CAMERA, DEFAULT_ILLUMINANT
    from thinfilm.core.model import captures_from_stokes

    wl = np.asarray(meta["wavelengths_nm"], dtype=np.float64)
    stokes = render_normal_map(
        estimate.normals, estimate.thickness_nm, estimate.valid, wl, film,
        dome_hole_deg=float(meta.get("dome_hole_deg", 0.0) or 0.0),
        band_fwhm_nm=float(meta.get("band_fwhm_nm", 0.0) or 0.0), passband=meta.get("passband", "gaussian"),
        progress=progress, roughness=float(meta.get("film_roughness", 0.0) or 0.0),
        spp=min(int(meta.get("spp", 1) or 1), RERENDER_MAX_SPP))
    polarized_rgb, spectral_s = captures_from_stokes(
        stokes, wl, meta.get("polarizer_angles_deg", [0, 45, 90, 135]), meta.get("camera", DEFAULT_CAMERA),
        meta.get("illuminant", DEFAULT_ILLUMINANT))
    return {"stokes": stokes, "spectral_s": spectral_s, "polarized_rgb": polarized_rgb}


# -- the evaluate command -------------------------------------------------------------------

#: how far from 1 the length of an estimated normal may be (float32 files hold ~1e-7)
UNIT_TOLERANCE = 1e-3
#: the largest film thickness an estimate may hold (nm)
MAX_THICKNESS_NM = 1e5


def check_estimate(estimate, shape, estimate_path) -> None:
    """Stop with one line when an :class:`~thinfilm.core.io.Estimate` does not fit the
    dataset or is not a plausible estimate: image size, a missing or invalid ``film_ior``
    or ``substrate_ior`` in ``estimate.json``, no valid pixel, and at valid pixels NaN,
    zero or non-unit normals (``|‖n‖ - 1| >`` :data:`UNIT_TOLERANCE`), normals facing away
    from the camera (n_z <= 0), negative thickness."""
    exr = Path(estimate_path) / "estimate.exr"
    js = Path(estimate_path) / "estimate.json"
    got = tuple(estimate.valid.shape)
    if got != tuple(shape):
        raise UserError(f"{exr}: image is {got[1]}x{got[0]} pixels but the dataset is "
                        f"{shape[1]}x{shape[0]}; the estimate does not belong to this dataset")
    if estimate.film_ior is None:
        raise UserError(f"{js}: missing field 'film_ior'")
    sub = estimate.substrate_ior
    if sub is not None and (isinstance(sub, bool) or not isinstance(sub, (int, float))
                            or not (math.isfinite(sub) and sub > 0)):
        raise UserError(f"{js}: field 'substrate_ior' must be a positive number, got {sub!r}")
    fi = estimate.film_ior
    if isinstance(fi, (int, float)) and not isinstance(fi, bool) and not (math.isfinite(fi) and fi > 0):
        raise UserError(f"{js}: field 'film_ior' must be positive, got {fi!r}")
    valid = estimate.valid
    for name, arr in (("normal", estimate.normals), ("thickness", estimate.thickness_nm)):
        bad = valid & ~np.all(np.isfinite(np.asarray(arr).reshape(*valid.shape, -1)), axis=-1)
        if bad.any():
            raise UserError(f"{exr}: channel '{name}' is NaN or infinite at {int(bad.sum())} pixels "
                            f"marked valid")
    if not valid.any():
        raise UserError(f"{exr}: channel 'valid' marks no pixel; there is nothing to evaluate")
    normals = np.asarray(estimate.normals, dtype=np.float64)[valid]
    length = np.linalg.norm(normals, axis=-1)
    if np.any(length < 1e-6):
        raise UserError(f"{exr}: channels 'normal.X/Y/Z' are zero at pixels marked valid")
    off = np.abs(length - 1.0) > UNIT_TOLERANCE
    if off.any():
        worst = float(length[np.argmax(np.abs(length - 1.0))])
        raise UserError(f"{exr}: channels 'normal.X/Y/Z' are not unit vectors at {int(off.sum())} pixels "
                        f"marked valid (length {worst:.4g}); expected |n| = 1")
    away = normals[:, 2] <= 0
    if away.any():
        raise UserError(f"{exr}: channel 'normal.Z' is <= 0 at {int(away.sum())} pixels marked valid; "
                        f"visible normals face the camera (n_z > 0)")
    thickness = np.asarray(estimate.thickness_nm, dtype=np.float64)[valid]
    if np.any(thickness < 0):
        raise UserError(f"{exr}: channel 'thickness' is negative at {int((thickness < 0).sum())} pixels "
                        f"marked valid (min {thickness.min():g} nm); expected a thickness in nm >= 0")
    if np.any(thickness > MAX_THICKNESS_NM):
        raise UserError(f"{exr}: channel 'thickness' exceeds {MAX_THICKNESS_NM:g} nm at pixels marked "
                        f"valid (max {thickness.max():g}); expected a thickness in nm")


def estimated_film(dataset, estimate, estimate_path):
    """The film an estimate is re-rendered with: the dataset's (its substrate, exterior, k),
    with the estimate's film index and, where it gives one, substrate index."""
    from thinfilm.core.film import Film, as_index

    js = Path(estimate_path) / "estimate.json"
    index = as_index(estimate.film_ior, f"{js}: field 'film_ior'")
    try:
        film = dataset.film()
    except UserError:
        sub = estimate.substrate_ior if estimate.substrate_ior is not None else dataset.meta.get("substrate_ior")
        if sub is None:
            raise UserError(f"{js}: no 'substrate_ior', and the dataset's meta.json has none") from None
        film = Film.single(index, None, sub, where=str(js))
        _check_indices(film, js, estimate, dataset.path / "meta.json")
        return film
    film = film.with_index(index)
    if estimate.substrate_ior is not None and abs(estimate.substrate_ior - film.effective_substrate_index()) > 1e-12:
        film = film.with_substrate(estimate.substrate_ior)
    _check_indices(film, js, estimate, dataset.path / "meta.json")
    return film


#: refractive indices (real part) the re-rendering accepts, as the scene specs do
INDEX_RANGE = (0.01, 100.0)


def _check_indices(film, estimate_json, estimate, meta_json) -> None:
    lo, hi = INDEX_RANGE
    n2, n3 = film.effective_index(), film.effective_substrate_index()
    if not lo <= n2 <= hi:
        raise UserError(f"{estimate_json}: field 'film_ior' must be a refractive index from {lo:g} to {hi:g}, "
                        f"got {n2:g}")
    if not lo <= n3 <= hi:
        where = (f"{estimate_json}: field 'substrate_ior'" if estimate.substrate_ior is not None
                 else f"{meta_json}: the substrate index")
        raise UserError(f"{where} must be a refractive index from {lo:g} to {hi:g}, got {n3:g}")


def _evaluate(dataset_path, estimate_path, progress=False) -> dict:
    from thinfilm.core.colorimetry import DEFAULT_CAMERA, DEFAULT_ILLUMINANT
    from thinfilm.core.io import read_dataset, read_estimate

    t0 = time.perf_counter()
    ds = read_dataset(dataset_path, need=())
    if ds.spectral_s is None and not ds.polarized_rgb:
        raise UserError(f"{ds.path}: dataset holds neither spectral_s.exr nor polarized_rgb.exr, "
                        f"nothing to compare the re-rendering with")
    estimate = read_estimate(estimate_path)
    check_estimate(estimate, ds.shape, estimate_path)
    meta = ds.meta
    wl = ds.wavelengths_nm
    if wl.size < 2:
        raise UserError(f"{ds.path / 'meta.json'}: 'wavelengths_nm' needs at least 2 bands to re-render")
    camera = meta.get("camera", DEFAULT_CAMERA)
    illuminant = meta.get("illuminant", DEFAULT_ILLUMINANT)
    film = estimated_film(ds, estimate, estimate_path)

    have_gt = bool(ds.ground_truth)
    valid = estimate.valid
    mask = (ds.ground_truth["mask"] & valid) if have_gt else valid.copy()
    if not mask.any():
        raise UserError(f"{Path(estimate_path) / 'estimate.exr'}: no pixel marked valid lies on the object "
                        f"of {ds.path / 'ground_truth.exr'} ('mask'); there is nothing to score")

    t_render = time.perf_counter()
    rendered = rerender_estimate(meta, estimate, film, progress=progress)
    t_render = time.perf_counter() - t_render

    maps = {}
    if have_gt:
        maps.update(geometry_error_maps(ds.ground_truth, estimate))
    if ds.spectral_s is not None:
        kind, captured, rerendered = "spectra", ds.spectral_s, rendered["spectral_s"]
        colour_path = (f"s-polarized reflectance spectra (spectral_s) -> XYZ with the CIE 1931 2 degree "
                       f"observer under {illuminant} -> CIELAB relative to the perfect white")
        m_fit = None
    else:
        kind = "camera_rgb"
        captured = s_polarized_rgb(ds.polarized_rgb, str(ds.path / "polarized_rgb.exr"))
        rerendered = s_polarized_rgb({a: rendered["polarized_rgb"][a] for a in ds.polarized_rgb})
        colour_path = (f"s-polarized camera RGB (S0 + |S1, S2| per channel, from polarized_rgb) -> XYZ "
                       f"through a 3x3 matrix fitted to the CIE 1931 2 degree colour-matching functions "
                       f"from the {camera} sensitivities under {illuminant} (white-preserving least "
                       f"squares) -> CIELAB relative to the perfect white")
        from .color_difference import fit_camera_to_xyz

        m_fit = fit_camera_to_xyz(wl, camera, illuminant).tolist()
    app = appearance_error_maps(captured, rerendered, wl, illuminant, kind=kind, camera=camera)
    maps.update({k: app[k] for k in ("delta_e_ab", "delta_e_2000", "spectral_rmse")})
    for k in ("delta_e_ab", "delta_e_2000", "spectral_rmse"):
        maps[k] = np.where(valid, maps[k], np.nan)

    film_true = meta.get("film_ior")
    film_err = None
    if film_true is not None:
        # one number for each index: the effective index of thinfilm.core.film
        film_err = abs(film.effective_index() - ds.film().effective_index())
    t_bound = time.perf_counter()
    bound, bound_info = bound_metrics(ds, estimate, maps, mask)
    t_bound = time.perf_counter() - t_bound
    metrics = metrics_from_maps(maps, mask, film_err, bound)
    metrics.update(sigma_calibration(estimate, maps, mask) if have_gt else dict.fromkeys(CALIBRATION_KEYS))

    n_mask = int(ds.ground_truth["mask"].sum()) if have_gt else int(valid.sum())
    info_out = {
        "dataset": str(Path(dataset_path)),
        "estimate": str(Path(estimate_path)),
        "method": estimate.info.get("method"),
        "film_ior_estimated": estimate.film_ior,
        "film_ior_true": film_true,
        "substrate_ior_used": film.effective_substrate_index(),
        "object_pixels": n_mask,
        "scored_pixels": int(mask.sum()),
        "coverage": (float(mask.sum()) / n_mask) if n_mask else 0.0,
        "colour_path": colour_path,
        "colour_kind": kind,
        "camera_to_xyz_matrix": m_fit,
        "units": {"normal_error_deg": "degrees", "zenith_error_deg": "degrees",
                  "thickness_error_nm": "nm", "delta_e_ab": "CIE 1976 Delta E*ab",
                  "delta_e_2000": "CIEDE2000", "film_ior_error": "absolute index difference",
                  "spectral_rmse": "reflectance units (0.02 = 2 %), sqrt(mean over bands of "
                                   "(captured - rerendered)^2) per pixel, paper Eq. 32"},
        "statistics": "mean, median, 95th percentile (linear interpolation) and max over the object "
                      "mask (ground-truth mask and estimate valid)",
        "rerender": "normal-mapped plane under the orthographic camera, thinfilm BSDF, dataset rig, no noise",
        "timings_s": {"rerender": round(t_render, 3), "bound": round(t_bound, 3)},
        "bound": bound_info,
    }
    result = {"metrics": metrics, "info": info_out, "maps": maps, "mask": mask, "rendered": rendered,
              "captured": captured, "rerendered_appearance": rerendered, "colour_kind": kind,
              "lab_captured": app["lab_captured"], "lab_rendered": app["lab_rendered"],
              "dataset": ds, "estimate": estimate}
    info_out["timings_s"]["metrics_total"] = round(time.perf_counter() - t0, 3)
    return result


def evaluate(dataset_path, estimate_path, out=None, progress=False, figures=True) -> dict:
    """Re-render an estimate, compute the metrics, and (with ``out``) write the evaluation
    folder atomically, holding its lock while the work runs. Needs a mono polarized Mitsuba
    variant set by the caller (:data:`RENDER_VARIANT`).

    ``out`` may not be, contain or lie inside the dataset or the estimate
    (:func:`thinfilm.core.outputs.check_output_dir`).

    Returns
    -------
    dict with ``metrics`` (the ``metrics.json`` content), ``info`` (the ``evaluation.json``
    content), ``maps`` (per-pixel error images), ``mask``, ``rendered``, ``captured`` and
    the ``dataset`` and ``estimate``.
    """
    if out is None:
        return _evaluate(dataset_path, estimate_path, progress=progress)
    from thinfilm.core.outputs import atomic_output_dir

    with atomic_output_dir(out, command="evaluate", inputs=[dataset_path, estimate_path]) as tmp:
        result = _evaluate(dataset_path, estimate_path, progress=progress)
        _write_evaluation_files(tmp, result, figures)
    return result


def _write_evaluation_files(folder, result: dict, figures: bool) -> None:
    from thinfilm.core.io import write_evaluation_files

    rendered = result["rendered"]
    write_evaluation_files(folder, result["metrics"], result["info"], rendered["polarized_rgb"],
                           rendered["spectral_s"], result["maps"], result["mask"])
    if figures:
        from . import figures as fig

        fig.write_evaluation_figures(folder, result)


def write_evaluation(out, result: dict, figures=True, inputs=()) -> Path:
    """Write ``metrics.json``, ``evaluation.json``, ``rerendered.exr``, ``errors.exr`` and
    figures of an :func:`evaluate` result into ``out`` atomically."""
    from thinfilm.core.outputs import atomic_output_dir

    with atomic_output_dir(out, command="evaluate", inputs=inputs) as tmp:
        _write_evaluation_files(tmp, result, figures)
    return Path(out)


def cli_main(args) -> int:
    """``thinfilm evaluate DATASET ESTIMATE --out DIR``."""
    import sys

    from thinfilm.core.variants import use_variant

    from thinfilm.core.outputs import check_output_dir

    check_output_dir(args.out, command="evaluate", inputs=[args.dataset, args.estimate])
    use_variant()
    result = evaluate(args.dataset, args.estimate, args.out, progress=sys.stderr.isatty())
    m = result["metrics"]

    def fmt(key, unit=""):
        v = m[key]["mean"]
        return "n/a" if v is None else f"{v:.3g}{unit}"

    print(f"wrote {Path(args.out) / 'metrics.json'} (normal error {fmt('normal_error_deg', ' deg')}, "
          f"thickness error {fmt('thickness_error_nm', ' nm')}, mean dE*ab {fmt('delta_e_ab')}, "
          f"dE00 {fmt('delta_e_2000')}, spectral RMSE {fmt('spectral_rmse')}, film index error "
          f"{m['film_ior_error'] if m['film_ior_error'] is None else round(m['film_ior_error'], 4)})")
    return 0
