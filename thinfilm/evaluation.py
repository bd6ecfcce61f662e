"""Evaluation: re-render an estimate through the ``thinfilm`` BSDF and score it.

``thinfilm evaluate DATASET ESTIMATE --out DIR`` (``DESIGN.md``, issue 6):

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
   (:func:`thinfilm.generators.render.captures_from_stokes`).
3. Errors per pixel over the object mask (ground-truth mask ∧ estimate ``valid``):
   normal angle, zenith, thickness; ΔE*ab (CIE 1976, paper Eq. 31) and ΔE00 between the
   captured and re-rendered s-polarized appearance, in CIELAB from spectra
   (:mod:`thinfilm.color_difference`), or, when the dataset holds no spectra, from the
   s-polarized camera RGB (Stokes fit of :mod:`thinfilm.reconstruction.polarization`)
   through the fitted camera→XYZ matrix; spectral RMSE (paper Eq. 32)
   ``sqrt(Σ_λ (R_o − R_e)² / N)`` per pixel in reflectance units (0.02 = 2 %).

Outputs: ``metrics.json`` (exactly the keys of ``DESIGN.md``), ``evaluation.json``
(definitions, coverage, colour path), ``rerendered.exr`` (re-rendered captures),
``errors.exr`` (error maps) and PNG figures (:mod:`thinfilm.figures`).
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from thinfilm.generators.generate import VARIANT as RENDER_VARIANT

from .errors import UserError

__all__ = [
    "METRIC_KEYS",
    "RENDER_VARIANT",
    "summarize",
    "angular_error_deg",
    "geometry_error_maps",
    "s_polarized_rgb",
    "appearance_error_maps",
    "film_ior_value",
    "metrics_from_maps",
    "render_normal_map",
    "rerender_estimate",
    "check_estimate",
    "evaluate",
    "cli_main",
]

METRIC_KEYS = ("normal_error_deg", "zenith_error_deg", "thickness_error_nm",
               "delta_e_ab", "delta_e_2000", "spectral_rmse")


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


def geometry_error_maps(ground_truth: dict, estimate: dict) -> dict:
    """Per-pixel ``normal_error_deg``, ``zenith_error_deg`` (|θ_est − θ_gt|) and
    ``thickness_error_nm`` (|d_est − d_gt|); NaN where the estimate is invalid."""
    from thinfilm.reconstruction.estimate import normals_to_angles

    valid = estimate["valid"]
    normal = np.asarray(estimate["normal"], dtype=np.float64)
    with np.errstate(invalid="ignore"):
        zen_est = normals_to_angles(normal / np.linalg.norm(normal, axis=-1, keepdims=True))[0]
        maps = {
            "normal_error_deg": angular_error_deg(estimate["normal"], ground_truth["normal"]),
            "zenith_error_deg": np.abs(zen_est - np.asarray(ground_truth["zenith"], dtype=np.float64)),
            "thickness_error_nm": np.abs(np.asarray(estimate["thickness"], dtype=np.float64)
                                         - np.asarray(ground_truth["thickness"], dtype=np.float64)),
        }
    return {k: np.where(valid, v, np.nan) for k, v in maps.items()}


def s_polarized_rgb(polarized_rgb: dict, where: str = "polarized_rgb.exr") -> np.ndarray:
    """S-polarized camera RGB ``S0 + sqrt(S1² + S2²)`` per channel (H, W, 3) from polarizer
    images {angle: (H, W, 3)}: the least-squares Stokes fit
    (:func:`thinfilm.reconstruction.polarization.stokes_from_dataset`) turned into the
    s-polarized capture as :func:`thinfilm.generators.render.spectral_s_from_stokes` defines it.

    Raises
    ------
    UserError
        Naming ``where`` when fewer than three distinct polarizer angles are given.
    """
    from thinfilm.generators.render import spectral_s_from_stokes
    from thinfilm.reconstruction.polarization import stokes_from_dataset

    return spectral_s_from_stokes(dict(zip(("S0", "S1", "S2"), stokes_from_dataset(polarized_rgb, where))))


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


def film_ior_value(film_ior, wavelengths_nm, where="film_ior") -> float:
    """A film index as one number: a number as is; a named material or dispersion
    (``thinfilm.bsdf.materials.as_dispersion``) averaged over ``wavelengths_nm``."""
    if isinstance(film_ior, bool):
        raise UserError(f"{where}: expected a refractive index, got {film_ior!r}")
    if isinstance(film_ior, (int, float)):
        return float(film_ior)
    from thinfilm.bsdf.materials import as_dispersion

    try:
        disp = as_dispersion(film_ior)
    except (ValueError, TypeError, KeyError) as e:
        raise UserError(f"{where}: expected a refractive index or material name, got {film_ior!r} ({e})") from None
    return float(np.mean(np.asarray(disp(np.asarray(wavelengths_nm, dtype=np.float64)), dtype=np.float64)))


def metrics_from_maps(maps: dict, mask, film_ior_error) -> dict:
    """``metrics.json`` content: each of :data:`METRIC_KEYS` summarized over ``mask``, plus
    ``film_ior_error``."""
    out = {k: summarize(maps[k], mask) if k in maps else summarize([]) for k in METRIC_KEYS}
    out["film_ior_error"] = None if film_ior_error is None else float(film_ior_error)
    return out


# -- re-rendering -----------------------------------------------------------------------------

def render_normal_map(normals, thickness_nm, valid, wavelengths_nm, film_ior, substrate_ior,
                      substrate_k=0.0, dome_hole_deg=0.0, band_fwhm_nm=0.0, passband="gaussian",
                      progress=False) -> dict:
    """Band-integrated Stokes cube of a per-pixel normal and thickness field (any H × W),
    rendered through the ``thinfilm`` plugin under the generator's orthographic camera and
    dome: the generator's :func:`thinfilm.generators.scene.normal_map_scene` and
    :func:`thinfilm.generators.render.render_stokes_cube` (the code that rendered the
    captures). Needs a vectorized mono polarized variant set by the caller.

    Returns
    -------
    dict ``"S0"``, ``"S1"``, ``"S2"`` → (H, W, B) float64 in reflectance units, Stokes in
    the ``DESIGN.md`` frame (``S1 = I(0°) − I(90°)``, 0° = image +x); zero off ``valid``.
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
    film = film_ior if isinstance(film_ior, str) else float(film_ior)
    scene = normal_map_scene(safe_normals, thickness, valid, film, float(substrate_ior), float(substrate_k),
                             rig={"dome_hole_deg": float(dome_hole_deg)})
    out = render_stokes_cube(scene, wl, float(band_fwhm_nm), passband, progress=progress)
    out.pop("mask", None)
    for s in ("S0", "S1", "S2"):
        out[s] = np.where(valid[..., None], out[s], 0.0)
    return out


def rerender_estimate(meta: dict, estimate: dict, film_ior, substrate_ior, progress=False) -> dict:
    """Re-render an estimate with the dataset's rig (``meta.json``: bands, passband, dome,
    polarizer angles, camera, illuminant; no noise): returns the Stokes cube and the
    noise-free captures ``spectral_s`` (H, W, B) and ``polarized_rgb`` {angle: (H, W, 3)}
    (:func:`thinfilm.generators.render.captures_from_stokes`)."""
    from thinfilm.generators.render import captures_from_stokes

    from .colorimetry import DEFAULT_CAMERA, DEFAULT_ILLUMINANT

    wl = np.asarray(meta["wavelengths_nm"], dtype=np.float64)
    stokes = render_normal_map(
        estimate["normal"], estimate["thickness"], estimate["valid"], wl, film_ior, substrate_ior,
        float(meta.get("substrate_k", 0.0) or 0.0), dome_hole_deg=float(meta.get("dome_hole_deg", 0.0) or 0.0),
        band_fwhm_nm=float(meta.get("band_fwhm_nm", 0.0) or 0.0), passband=meta.get("passband", "gaussian"),
        progress=progress)
    rig = {"camera": meta.get("camera", DEFAULT_CAMERA), "illuminant": meta.get("illuminant", DEFAULT_ILLUMINANT),
           "polarizer_angles_deg": meta.get("polarizer_angles_deg", [0, 45, 90, 135])}
    polarized_rgb, spectral_s = captures_from_stokes(stokes, wl, rig)
    return {"stokes": stokes, "spectral_s": spectral_s, "polarized_rgb": polarized_rgb}


# -- the evaluate command -------------------------------------------------------------------

def check_estimate(estimate: dict, info: dict, shape, estimate_path) -> None:
    """Stop with one line when the estimate does not fit the dataset: image size,
    or a missing / non-numeric ``film_ior`` or ``substrate_ior`` in ``estimate.json``."""
    exr = Path(estimate_path) / "estimate.exr"
    js = Path(estimate_path) / "estimate.json"
    got = tuple(estimate["valid"].shape)
    if got != tuple(shape):
        raise UserError(f"{exr}: image is {got[1]}x{got[0]} pixels but the dataset is "
                        f"{shape[1]}x{shape[0]}; the estimate does not belong to this dataset")
    for key in ("film_ior",):
        if key not in info:
            raise UserError(f"{js}: missing field '{key}'")
    sub = info.get("substrate_ior")
    if sub is not None and (isinstance(sub, bool) or not isinstance(sub, (int, float)) or not sub > 0):
        raise UserError(f"{js}: field 'substrate_ior' must be a positive number, got {sub!r}")
    fi = info["film_ior"]
    if isinstance(fi, (int, float)) and not isinstance(fi, bool) and not fi > 0:
        raise UserError(f"{js}: field 'film_ior' must be positive, got {fi!r}")
    valid = estimate["valid"]
    for name, arr in (("normal", estimate["normal"]), ("thickness", estimate["thickness"])):
        bad = valid & ~np.all(np.isfinite(arr.reshape(*valid.shape, -1)), axis=-1)
        if bad.any():
            raise UserError(f"{exr}: channel '{name}' is NaN or infinite at {int(bad.sum())} pixels "
                            f"marked valid")
    nz = np.linalg.norm(estimate["normal"], axis=-1)
    if valid.any() and np.any(nz[valid] < 1e-6):
        raise UserError(f"{exr}: channels 'normal.X/Y/Z' are zero at pixels marked valid")


def _read_estimate(path):
    from thinfilm.reconstruction.estimate import read_estimate

    return read_estimate(path)


def evaluate(dataset_path, estimate_path, out=None, progress=False, figures=True) -> dict:
    """Re-render an estimate, compute the metrics, and (with ``out``) write the evaluation
    folder atomically. Needs a mono polarized Mitsuba variant set by the caller
    (:data:`RENDER_VARIANT`).

    Returns
    -------
    dict with ``metrics`` (the ``metrics.json`` content), ``info`` (the ``evaluation.json``
    content), ``maps`` (per-pixel error images), ``mask``, ``rendered``, ``captured`` and
    the ``dataset`` and ``estimate``.
    """
    from .colorimetry import DEFAULT_CAMERA, DEFAULT_ILLUMINANT
    from .dataset import read_dataset

    t0 = time.perf_counter()
    ds = read_dataset(dataset_path, need=())
    if ds.spectral_s is None and not ds.polarized_rgb:
        raise UserError(f"{ds.path}: dataset holds neither spectral_s.exr nor polarized_rgb.exr, "
                        f"nothing to compare the re-rendering with")
    estimate, info = _read_estimate(estimate_path)
    check_estimate(estimate, info, ds.shape, estimate_path)
    meta = ds.meta
    wl = ds.wavelengths_nm
    if wl.size < 2:
        raise UserError(f"{ds.path / 'meta.json'}: 'wavelengths_nm' needs at least 2 bands to re-render")
    camera = meta.get("camera", DEFAULT_CAMERA)
    illuminant = meta.get("illuminant", DEFAULT_ILLUMINANT)
    js = Path(estimate_path) / "estimate.json"
    film_est = info["film_ior"]
    film_est_value = film_ior_value(film_est, wl, f"{js}: field 'film_ior'")
    substrate = info.get("substrate_ior")
    if substrate is None:
        substrate = meta.get("substrate_ior", 1.6)

    have_gt = bool(ds.ground_truth)
    valid = estimate["valid"]
    mask = (ds.ground_truth["mask"] & valid) if have_gt else valid.copy()

    t_render = time.perf_counter()
    rendered = rerender_estimate(meta, estimate, film_est, substrate, progress=progress)
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
        film_err = abs(film_est_value - film_ior_value(film_true, wl, f"{ds.path / 'meta.json'}: field 'film_ior'"))
    metrics = metrics_from_maps(maps, mask, film_err)

    n_mask = int(ds.ground_truth["mask"].sum()) if have_gt else int(valid.sum())
    info_out = {
        "dataset": str(Path(dataset_path)),
        "estimate": str(Path(estimate_path)),
        "method": info.get("method"),
        "film_ior_estimated": film_est if isinstance(film_est, str) else float(film_est),
        "film_ior_true": film_true,
        "substrate_ior_used": float(substrate),
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
        "timings_s": {"rerender": round(t_render, 3)},
    }
    result = {"metrics": metrics, "info": info_out, "maps": maps, "mask": mask, "rendered": rendered,
              "captured": captured, "rerendered_appearance": rerendered, "colour_kind": kind,
              "lab_captured": app["lab_captured"], "lab_rendered": app["lab_rendered"],
              "dataset": ds, "estimate": estimate}
    info_out["timings_s"]["metrics_total"] = round(time.perf_counter() - t0, 3)
    if out is not None:
        write_evaluation(out, result, figures=figures)
    return result


def write_evaluation(out, result: dict, figures=True) -> Path:
    """Write ``metrics.json``, ``evaluation.json``, ``rerendered.exr``, ``errors.exr`` and
    figures into ``out`` atomically."""
    from thinfilm.generators.generate import band_channels, polarized_rgb_channels

    from .dataset import atomic_output_dir, write_exr, write_json

    with atomic_output_dir(out) as tmp:
        write_json(tmp / "metrics.json", result["metrics"])
        write_json(tmp / "evaluation.json", result["info"])
        rendered = result["rendered"]
        write_exr(tmp / "rerendered.exr", {**polarized_rgb_channels(rendered["polarized_rgb"]),
                                           **band_channels(rendered["spectral_s"], "spectral_s.")})
        write_exr(tmp / "errors.exr", {**{k: np.nan_to_num(v, nan=0.0) for k, v in result["maps"].items()},
                                       "mask": result["mask"].astype(np.float32)})
        if figures:
            from . import figures as fig

            fig.write_evaluation_figures(tmp, result)
    return Path(out)


def cli_main(args) -> int:
    """``thinfilm evaluate DATASET ESTIMATE --out DIR``."""
    import sys

    from thinfilm.generators.generate import set_variant

    set_variant()
    result = evaluate(args.dataset, args.estimate, args.out, progress=sys.stderr.isatty())
    m = result["metrics"]

    def fmt(key, unit=""):
        v = m[key]["mean"]
        return "n/a" if v is None else f"{v:.3g}{unit}"

    print(f"normal error {fmt('normal_error_deg', ' deg')}, thickness error {fmt('thickness_error_nm', ' nm')}, "
          f"mean dE*ab {fmt('delta_e_ab')}, dE00 {fmt('delta_e_2000')}, spectral RMSE {fmt('spectral_rmse')}, "
          f"film index error {m['film_ior_error'] if m['film_ior_error'] is None else round(m['film_ior_error'], 4)}"
          f" -> {Path(args.out) / 'metrics.json'}")
    return 0
