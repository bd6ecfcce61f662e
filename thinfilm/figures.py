"""PNG figures of an evaluation (matplotlib's Agg canvas, no pyplot global state).

- ``normals.png``: ground-truth normals, estimated normals, angular error (colour bar, deg).
- ``thickness.png``: ground-truth thickness, estimated thickness, ``|error|`` (colour bars, nm).
- ``appearance.png``: captured, re-rendered (sRGB of the s-polarized appearance, one common
  exposure), ΔE*ab map (colour bar).
- ``errors.png``: zenith error, thickness error, ΔE*ab and ΔE00 maps, each with a colour bar.

Normals are shown as ``(n + 1) / 2`` in RGB, camera frame (x right, y up, z towards the
camera), with a colour key beside each normal map: a sphere seen from the camera,
whose pixels show the colour of their own normal. Pixels outside the object mask are grey.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = [
    "normals_to_rgb",
    "normal_key",
    "lab_to_display_srgb",
    "save_panels",
    "write_evaluation_figures",
]

_BACKGROUND = 0.85


def normals_to_rgb(normals, mask) -> np.ndarray:
    """Normals (H, W, 3) as an RGB image ``(n + 1) / 2``, grey off ``mask``."""
    n = np.nan_to_num(np.asarray(normals, dtype=np.float64))
    rgb = np.clip((n + 1.0) / 2.0, 0.0, 1.0)
    rgb[~np.asarray(mask, dtype=bool)] = _BACKGROUND
    return rgb


def normal_key(size: int = 65) -> np.ndarray:
    """The colour key of :func:`normals_to_rgb`: a ``size`` x ``size`` RGB image of a sphere
    seen from the camera (each pixel the colour of the sphere's normal there; x right, y up,
    row 0 at the top), grey around it."""
    c = (np.arange(size) + 0.5) / size * 2.0 - 1.0
    x, y = np.meshgrid(c, -c)
    r2 = x * x + y * y
    inside = r2 <= 1.0
    normals = np.stack([x, y, np.sqrt(np.clip(1.0 - r2, 0.0, None))], axis=-1)
    return normals_to_rgb(normals, inside)


def lab_to_display_srgb(labs, mask, white_xy=None, percentile=99.0, target=0.85):
    """sRGB pictures of CIELAB images (list of (H, W, 3)), all with one exposure chosen so
    that the ``percentile`` of the first image's luminance under ``mask`` maps to ``target``."""
    import colour

    if white_xy is None:
        white_xy = colour.CCS_ILLUMINANTS["CIE 1931 2 Degree Standard Observer"]["D65"]
    mask = np.asarray(mask, dtype=bool)
    xyzs = [np.asarray(colour.Lab_to_XYZ(np.nan_to_num(lab), white_xy)) for lab in labs]
    y = xyzs[0][..., 1][mask]
    ref = np.percentile(y, percentile) if y.size else 1.0
    scale = target / ref if ref > 0 else 1.0
    out = []
    for xyz in xyzs:
        srgb = colour.XYZ_to_sRGB(xyz * scale, illuminant=white_xy)
        srgb = np.clip(np.nan_to_num(srgb), 0.0, 1.0)
        srgb[~mask] = _BACKGROUND
        out.append(srgb)
    return out


def save_panels(path, panels, title=None, panel_size=3.2, dpi=100) -> Path:
    """Save a row of image panels to a PNG.

    Parameters
    ----------
    panels : list of dict
        Each ``{"image": (H, W) or (H, W, 3), "title": str}``; a 2-D image gets a colour map
        (``cmap``, default ``"viridis"``), limits ``vmin``/``vmax`` and a colour bar labelled
        ``label``; NaN pixels show grey. ``"key": "normals"`` adds the colour key of a normal
        map (:func:`normal_key`) beside its lower right corner.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    import matplotlib

    fig = Figure(figsize=(panel_size * len(panels), panel_size * 0.95 + (0.4 if title else 0)), dpi=dpi)
    FigureCanvasAgg(fig)
    axes = fig.subplots(1, len(panels), squeeze=False)[0]
    for ax, p in zip(axes, panels):
        img = np.asarray(p["image"])
        if img.ndim == 2:
            cmap = matplotlib.colormaps[p.get("cmap", "viridis")].with_extremes(bad=(_BACKGROUND,) * 3)
            finite = img[np.isfinite(img)]
            vmin = p.get("vmin", float(finite.min()) if finite.size else 0.0)
            vmax = p.get("vmax", float(finite.max()) if finite.size else 1.0)
            if vmax <= vmin:
                vmax = vmin + 1e-6
            im = ax.imshow(np.ma.masked_invalid(img), cmap=cmap, vmin=vmin, vmax=vmax, interpolation="nearest")
            cb = fig.colorbar(im, ax=ax, fraction=0.046, pad=0.04)
            if p.get("label"):
                cb.set_label(p["label"])
        else:
            ax.imshow(np.clip(img, 0.0, 1.0), interpolation="nearest")
        if p.get("key") == "normals":
            inset = ax.inset_axes([1.02, 0.0, 0.24, 0.24])
            inset.imshow(normal_key(), interpolation="bilinear")
            inset.set_xticks([])
            inset.set_yticks([])
            inset.set_title("key", fontsize=7, pad=2)
            inset.set_xlabel("x →, y ↑", fontsize=6, labelpad=1)
        ax.set_title(p.get("title", ""), fontsize=9)
        ax.set_xticks([])
        ax.set_yticks([])
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(str(path), format="png", metadata={"Software": None})
    return Path(path)


def _masked(img, mask):
    return np.where(mask, np.asarray(img, dtype=np.float64), np.nan)


def _robust_max(img, mask, q=99.0):
    v = np.asarray(img, dtype=np.float64)[mask]
    v = v[np.isfinite(v)]
    return float(np.percentile(v, q)) if v.size else 1.0


def write_evaluation_figures(out_dir, result: dict) -> list:
    """Write the evaluation figures into ``out_dir``; returns their paths.

    ``result`` is the dictionary :func:`thinfilm.evaluation.evaluate` returns.
    """
    from .color_difference import white_xyz

    out_dir = Path(out_dir)
    ds = result["dataset"]
    est = result["estimate"]
    maps = result["maps"]
    mask = result["mask"]
    method = result["info"].get("method") or "estimate"
    gt = ds.ground_truth
    obj = gt["mask"] if gt else est.valid
    written = []

    if gt:
        written.append(save_panels(out_dir / "normals.png", [
            {"image": normals_to_rgb(gt["normal"], obj), "title": "ground-truth normals", "key": "normals"},
            {"image": normals_to_rgb(est.normals, est.valid), "title": f"estimated normals ({method})",
             "key": "normals"},
            {"image": _masked(maps["normal_error_deg"], mask), "title": "normal error",
             "label": "degrees", "cmap": "magma", "vmin": 0.0,
             "vmax": max(_robust_max(maps["normal_error_deg"], mask), 1.0)},
        ]))
        t_gt = _masked(gt["thickness"], obj)
        t_est = _masked(est.thickness_nm, est.valid & obj)
        lo = float(np.nanmin(t_gt)) if np.isfinite(t_gt).any() else 0.0
        hi = float(np.nanmax(t_gt)) if np.isfinite(t_gt).any() else 1.0
        if hi - lo < 20.0:
            lo, hi = lo - 10.0, hi + 10.0
        written.append(save_panels(out_dir / "thickness.png", [
            {"image": t_gt, "title": "ground-truth thickness", "label": "nm", "vmin": lo, "vmax": hi},
            {"image": t_est, "title": f"estimated thickness ({method})", "label": "nm", "vmin": lo, "vmax": hi},
            {"image": _masked(maps["thickness_error_nm"], mask), "title": "|thickness error|",
             "label": "nm", "cmap": "magma", "vmin": 0.0,
             "vmax": max(_robust_max(maps["thickness_error_nm"], mask), 1.0)},
        ]))

    import colour

    white = white_xyz(ds.wavelengths_nm, ds.meta.get("illuminant", "D65"))
    white_xy = colour.XYZ_to_xy(white / white[1])
    cap, ren = lab_to_display_srgb([result["lab_captured"], result["lab_rendered"]], obj, white_xy)
    ren[~est.valid] = _BACKGROUND
    written.append(save_panels(out_dir / "appearance.png", [
        {"image": cap, "title": "captured (s-polarized)"},
        {"image": ren, "title": "re-rendered from estimate"},
        {"image": _masked(maps["delta_e_ab"], mask), "title": "ΔE*ab (CIE 1976)", "label": "ΔE*ab",
         "cmap": "inferno", "vmin": 0.0, "vmax": max(_robust_max(maps["delta_e_ab"], mask), 1.0)},
    ]))

    panels = []
    if gt:
        panels.append({"image": _masked(maps["zenith_error_deg"], mask), "title": "|zenith error|",
                       "label": "degrees", "cmap": "magma", "vmin": 0.0,
                       "vmax": max(_robust_max(maps["zenith_error_deg"], mask), 1.0)})
    panels.append({"image": _masked(maps["delta_e_2000"], mask), "title": "ΔE00 (CIEDE2000)",
                   "label": "ΔE00", "cmap": "inferno", "vmin": 0.0,
                   "vmax": max(_robust_max(maps["delta_e_2000"], mask), 1.0)})
    if np.isfinite(maps["spectral_rmse"][mask]).any():
        panels.append({"image": 100.0 * _masked(maps["spectral_rmse"], mask), "title": "spectral RMSE",
                       "label": "% reflectance", "cmap": "inferno", "vmin": 0.0})
    written.append(save_panels(out_dir / "errors.png", panels))
    if "crlb_normal_deg" in maps:
        bound = []
        for key, title, unit, err in (("crlb_normal_deg", "bound: normal (RMS angle)", "degrees", "normal_error_deg"),
                                      ("crlb_thickness_nm", "bound: thickness (std)", "nm", "thickness_error_nm")):
            img = _masked(maps[key], mask)
            finite = np.isfinite(img)
            vmax = float(np.percentile(img[finite], 95)) if finite.any() else 1.0
            bound.append({"image": img, "title": title, "label": unit, "cmap": "viridis", "vmin": 0.0,
                          "vmax": max(vmax, 1e-3)})
            ratio = _masked(maps[err] / maps[key], mask)
            bound.append({"image": ratio, "title": f"|{err.split('_')[0]} error| / bound", "label": "ratio",
                          "cmap": "magma", "vmin": 0.0, "vmax": 3.0})
        written.append(save_panels(out_dir / "bound.png", bound))
    return written
