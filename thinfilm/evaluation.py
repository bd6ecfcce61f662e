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
   spectra ``S0 + sqrt(S1² + S2²)`` and polarized camera RGB.
3. Errors per pixel over the object mask (ground-truth mask ∧ estimate ``valid``):
   normal angle, zenith, thickness; ΔE*ab (CIE 1976, paper Eq. 31) and ΔE00 between the
   captured and re-rendered s-polarized appearance, in CIELAB from spectra
   (:mod:`thinfilm.color_difference`), or from camera RGB through the fitted
   camera→XYZ matrix when the dataset holds no spectra; spectral RMSE (paper Eq. 32)
   ``sqrt(Σ_λ (R_o − R_e)² / N)`` per pixel in reflectance units (0.02 = 2 %).

Outputs: ``metrics.json`` (exactly the keys of ``DESIGN.md``), ``evaluation.json``
(definitions, coverage, colour path), ``rerendered.exr`` (re-rendered captures),
``errors.exr`` (error maps) and PNG figures (:mod:`thinfilm.figures`).
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from .errors import UserError

__all__ = [
    "METRIC_KEYS",
    "RENDER_VARIANT",
    "summarize",
    "angular_error_deg",
    "geometry_error_maps",
    "s_polarized_from_stokes",
    "stokes_from_polarized",
    "appearance_error_maps",
    "film_ior_value",
    "metrics_from_maps",
    "normal_map_mesh",
    "render_normal_map",
    "rerender_estimate",
    "check_estimate",
    "evaluate",
    "cli_main",
]

METRIC_KEYS = ("normal_error_deg", "zenith_error_deg", "thickness_error_nm",
               "delta_e_ab", "delta_e_2000", "spectral_rmse")
RENDER_VARIANT = "llvm_ad_mono_polarized"


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
    valid = estimate["valid"]
    with np.errstate(invalid="ignore"):
        zen_est = np.degrees(np.arccos(np.clip(
            estimate["normal"][..., 2] / np.linalg.norm(estimate["normal"], axis=-1), -1.0, 1.0)))
        maps = {
            "normal_error_deg": angular_error_deg(estimate["normal"], ground_truth["normal"]),
            "zenith_error_deg": np.abs(zen_est - np.asarray(ground_truth["zenith"], dtype=np.float64)),
            "thickness_error_nm": np.abs(np.asarray(estimate["thickness"], dtype=np.float64)
                                         - np.asarray(ground_truth["thickness"], dtype=np.float64)),
        }
    return {k: np.where(valid, v, np.nan) for k, v in maps.items()}


def s_polarized_from_stokes(stokes: dict) -> np.ndarray:
    """S-polarized reflectance ``S0 + sqrt(S1² + S2²)`` (the maximum over polarizer angles,
    doubled), as ``spectral_s.exr`` defines it; works per band or per RGB channel."""
    return stokes["S0"] + np.sqrt(stokes["S1"] ** 2 + stokes["S2"] ** 2)


def stokes_from_polarized(images: dict) -> dict:
    """Least-squares ``S0, S1, S2`` from intensities behind a polarizer at ≥ 3 angles.

    ``images``: angle in degrees → array (...). Inverts ``I(α) = ½ (S0 + S1 cos 2α + S2 sin 2α)``.
    """
    angles = sorted(images)
    if len(angles) < 3:
        raise UserError(f"need images at 3 or more polarizer angles to recover Stokes vectors, "
                        f"got {angles}")
    t = np.radians(np.asarray(angles, dtype=np.float64))
    design = 0.5 * np.stack([np.ones_like(t), np.cos(2 * t), np.sin(2 * t)], axis=-1)
    pinv = np.linalg.pinv(design)  # (3, A)
    stack = np.stack([np.asarray(images[a], dtype=np.float64) for a in angles], axis=-1)
    s = stack @ pinv.T
    return {"S0": s[..., 0], "S1": s[..., 1], "S2": s[..., 2]}


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

def _require_variant():
    import mitsuba as mi

    variant = mi.variant()
    if variant is None or not variant.endswith("mono_polarized") or variant.startswith("scalar"):
        raise RuntimeError(f"re-rendering needs a vectorized mono polarized Mitsuba variant "
                           f"(e.g. {RENDER_VARIANT}) set by the caller, not {variant!r}")
    from thinfilm.generators.scene import register_plugins

    register_plugins()
    return mi


def normal_map_mesh(normals, thickness_nm, valid, bsdf):
    """A Mitsuba mesh for images that are not square (the generator's
    ``normal_map_scene`` covers square ones): one quad per valid pixel in the plane z = 0,
    pixel (row i, column j) covering x ∈ [j − W/2, j + 1 − W/2], y ∈ [H/2 − i − 1, H/2 − i];
    its four vertices carry the pixel's normal (shading normal) and the texture coordinate
    of the pixel's centre in an H×W thickness bitmap. ``None`` when no pixel is valid."""
    mi = _require_variant()
    normals = np.asarray(normals, dtype=np.float64)
    h, w = valid.shape
    ys, xs = np.nonzero(valid)
    if ys.size == 0:
        return None
    n = normals[ys, xs]
    n = n / np.linalg.norm(n, axis=-1, keepdims=True)
    x0 = xs - w / 2.0
    y0 = h / 2.0 - ys
    corners = ((0.0, 0.0), (1.0, 0.0), (1.0, -1.0), (0.0, -1.0))
    verts = np.stack([np.stack([x0 + cx, y0 + cy, np.zeros(xs.shape)], axis=-1) for cx, cy in corners],
                     axis=1).reshape(-1, 3)
    vnormals = np.repeat(n[:, None, :], 4, axis=1).reshape(-1, 3)
    uv = np.stack([(xs + 0.5) / w, (ys + 0.5) / h], axis=-1)
    vuv = np.repeat(uv[:, None, :], 4, axis=1).reshape(-1, 2)
    base = (np.arange(xs.size) * 4)[:, None]
    faces = np.concatenate([base + [0, 3, 2], base + [0, 2, 1]], axis=0)  # counter-clockwise from +z
    props = mi.Properties()
    props["bsdf"] = bsdf
    mesh = mi.Mesh("estimate_plane", verts.shape[0], faces.shape[0], props=props,
                   has_vertex_normals=True, has_vertex_texcoords=True)
    params = mi.traverse(mesh)
    params["vertex_positions"] = mi.Float(verts.astype(np.float32).ravel())
    params["vertex_normals"] = mi.Float(vnormals.astype(np.float32).ravel())
    params["vertex_texcoords"] = mi.Float(vuv.astype(np.float32).ravel())
    params["faces"] = mi.UInt32(faces.astype(np.uint32).ravel())
    params.update()
    return mesh


def _rectangular_scene(normals, thickness, valid, film_ior, substrate_ior, substrate_k, dome_hole_deg):
    """Scene of :func:`normal_map_mesh` under an orthographic camera fitting the image, with
    the generator's dome and integrator settings; ``None`` when no pixel is valid."""
    mi = _require_variant()
    from thinfilm.generators.scene import dome_dict

    h, w = valid.shape
    bsdf = mi.load_dict({
        "type": "thinfilm", "substrate_ior": float(substrate_ior), "substrate_k": float(substrate_k),
        "film_ior": film_ior if isinstance(film_ior, str) else float(film_ior),
        "thickness": {"type": "bitmap", "bitmap": mi.Bitmap(thickness.astype(np.float32)[..., None]),
                      "raw": True, "filter_type": "nearest", "wrap_mode": "clamp"}})
    mesh = normal_map_mesh(normals, thickness, valid, bsdf)
    if mesh is None:
        return None
    half = max(w, h) / 2.0
    return {
        "type": "scene",
        "integrator": {"type": "stokes", "nested": {"type": "path", "max_depth": 3, "hide_emitters": True}},
        "sensor": {
            "type": "orthographic",
            "to_world": mi.ScalarTransform4f().look_at(origin=[0, 0, 10.0], target=[0, 0, 0], up=[0, 1, 0])
            @ mi.ScalarTransform4f().scale([half, half, 1.0]),
            "film": {"type": "hdrfilm", "width": w, "height": h, "rfilter": {"type": "box"},
                     "pixel_format": "luminance", "sample_border": False},
            "sampler": {"type": "stratified", "sample_count": 1, "jitter": False},
        },
        "dome": dome_dict(float(dome_hole_deg)),
        "estimate": mesh,
    }


def _render_bands(scene_dict, wavelengths_nm, band_fwhm_nm, passband, progress):
    """Band-integrated Stokes cube of any scene (square or not), with the generator's
    passband quadrature (:func:`thinfilm.generators.render.passband_quadrature`)."""
    mi = _require_variant()
    from tqdm import tqdm

    from thinfilm.generators.render import passband_quadrature

    scene = mi.load_dict(scene_dict)
    params = mi.traverse(scene)
    keys = [k for k in params.keys() if k == "wavelength" or k.endswith(".wavelength")]
    sub_nm, weights = passband_quadrature(wavelengths_nm, float(band_fwhm_nm), passband)
    w, h = (int(v) for v in scene.sensors()[0].film().size())
    cube = np.zeros((3, h, w, weights.shape[0]))
    channels = None
    for k, lam in enumerate(tqdm(sub_nm, desc="re-rendering", unit="λ", leave=False,
                                 disable=None if progress else True)):
        for key in keys:
            params[key] = float(lam)
        params.update()
        img = np.asarray(mi.render(scene, spp=1, seed=0), dtype=np.float64)
        if channels is None:  # the film holds Y, then S0..S3 as R, G, B (equal in mono)
            st = scene.sensors()[0].film().bitmap().struct_()
            names = [st[i].name for i in range(len(st))]
            channels = [names.index(f"S{i}.R") for i in range(3)]
        for b in np.nonzero(weights[:, k])[0]:
            cube[..., b] += weights[b, k] * np.moveaxis(img[..., channels], -1, 0)
    return {s: cube[i] for i, s in enumerate(("S0", "S1", "S2"))}


def render_normal_map(normals, thickness_nm, valid, wavelengths_nm, film_ior, substrate_ior,
                      substrate_k=0.0, dome_hole_deg=0.0, band_fwhm_nm=0.0, passband="gaussian",
                      progress=False) -> dict:
    """Band-integrated Stokes cube of a per-pixel normal and thickness field, rendered through
    the ``thinfilm`` plugin under the generator's orthographic camera and dome.

    Square images use the generator's :func:`thinfilm.generators.scene.normal_map_scene` and
    :func:`thinfilm.generators.render.render_stokes_cube` (the code that rendered the
    captures); other shapes a quad-per-pixel plane (:func:`normal_map_mesh`) with the same
    passband quadrature. Needs a mono polarized variant set by the caller.

    Returns
    -------
    dict ``"S0"``, ``"S1"``, ``"S2"`` → (H, W, B) float64 in reflectance units, Stokes in
    the ``DESIGN.md`` frame (``S1 = I(0°) − I(90°)``, 0° = image +x); zero off ``valid``.
    """
    _require_variant()
    valid = np.asarray(valid, dtype=bool)
    h, w = valid.shape
    wl = np.asarray(wavelengths_nm, dtype=np.float64)
    normals = np.asarray(normals, dtype=np.float64)
    valid = valid & np.all(np.isfinite(normals), axis=-1) & (np.nan_to_num(normals[..., 2]) > 0)
    safe_normals = np.where(valid[..., None], np.nan_to_num(normals), [0.0, 0.0, 1.0])
    thickness = np.where(valid, np.asarray(thickness_nm, dtype=np.float64), 0.0)
    thickness = np.clip(np.nan_to_num(thickness), 0.0, None)
    film = film_ior if isinstance(film_ior, str) else float(film_ior)
    if not valid.any():
        return {s: np.zeros((h, w, wl.size)) for s in ("S0", "S1", "S2")}
    if h == w:
        from thinfilm.generators.render import render_stokes_cube
        from thinfilm.generators.scene import normal_map_scene

        scene = normal_map_scene(safe_normals, thickness, valid, film, float(substrate_ior),
                                 float(substrate_k), rig={"dome_hole_deg": float(dome_hole_deg)})
        out = render_stokes_cube(scene, wl, float(band_fwhm_nm), passband, progress=progress)
        out.pop("mask", None)
    else:
        scene = _rectangular_scene(safe_normals, thickness, valid, film, substrate_ior, substrate_k,
                                   dome_hole_deg)
        out = _render_bands(scene, wl, band_fwhm_nm, passband, progress)
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
        captured = s_polarized_from_stokes(stokes_from_polarized(ds.polarized_rgb))
        rerendered = s_polarized_from_stokes(stokes_from_polarized(
            {a: rendered["polarized_rgb"][a] for a in ds.polarized_rgb}))
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
    from .dataset import atomic_output_dir, band_channel, pol_layer, write_exr, write_json

    with atomic_output_dir(out) as tmp:
        write_json(tmp / "metrics.json", result["metrics"])
        write_json(tmp / "evaluation.json", result["info"])
        rendered = result["rendered"]
        channels = {}
        for a, img in rendered["polarized_rgb"].items():
            for c, name in enumerate("RGB"):
                channels[f"{pol_layer(a)}.{name}"] = img[..., c]
        for b in range(rendered["spectral_s"].shape[-1]):
            channels[f"spectral_s.{band_channel(b)}"] = rendered["spectral_s"][..., b]
        write_exr(tmp / "rerendered.exr", channels)
        write_exr(tmp / "errors.exr", {**{k: np.nan_to_num(v, nan=0.0) for k, v in result["maps"].items()},
                                       "mask": result["mask"].astype(np.float32)})
        if figures:
            from . import figures as fig

            fig.write_evaluation_figures(tmp, result)
    return Path(out)


def cli_main(args) -> int:
    """``thinfilm evaluate DATASET ESTIMATE --out DIR``."""
    import sys

    import mitsuba as mi

    mi.set_variant(RENDER_VARIANT)
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
