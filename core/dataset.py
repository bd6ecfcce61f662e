"""Dataset folders, format ``thinfilm-dataset/1`` (``docs/design.md``, *Dataset folder*).

``scene.toml``, ``meta.json``, ``ground_truth.exr``, ``polarized_rgb.exr``, ``spectral_s.exr``,
``stokes_spectral.exr``, ``preview.png``, and the optional ``valid.exr`` (channel ``valid``: 1
where the captures can be trusted, 0 where they cannot, e.g. saturated pixels of an imported
capture; absent means every pixel). Every image is float32, all of one height and width, row
0 at the top.

:func:`read_dataset` stops with a :class:`~thinfilm.core.errors.UserError` that names the file
and the channel when a channel is missing, shapes disagree, captures hold NaN, or the
``format`` is unknown. :func:`write_dataset` writes into a folder that exists (see
:mod:`thinfilm.core.outputs` for safe output folders); the files are deterministic (same
arrays, same bytes).
"""

from __future__ import annotations

import os

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .errors import UserError
from .exr import band_channel, band_channels, pol_layer, polarized_rgb_channels, read_exr, write_exr
from .files import read_json, write_json

__all__ = ["FORMAT", "GROUND_TRUTH_CHANNELS", "POLARIZER_NOT_CORRECTED", "Dataset", "read_dataset", "write_dataset",
           "dataset_meta", "software_versions", "check_polarizer_calibration"]

#: ``calibration.polarizer.correction`` of an imported dataset whose captures could not be
#: corrected for the polarizer's measured extinction ratio or axis offset (one s-polarized
#: cube): the observation model (:mod:`thinfilm.core.model`, whose rig knows the polarizer
#: angles only) and every estimator assume ideal polarizers at the nominal angles
POLARIZER_NOT_CORRECTED = "none: the captures are those of the real polarizer"

FORMAT = "thinfilm-dataset/1"
GROUND_TRUTH_CHANNELS = ("normal.X", "normal.Y", "normal.Z", "zenith", "azimuth",
                         "thickness", "depth", "mask")


def _require(channels: dict, names, path, shape=None):
    out = {}
    for name in names:
        if name not in channels:
            raise UserError(f"{path}: missing channel '{name}'")
        arr = channels[name]
        if shape is not None and arr.shape != shape:
            raise UserError(f"{path}: channel '{name}' has shape {arr.shape}, expected {shape}")
        out[name] = arr
    return out


def _no_nan(arr, path, names):
    """``arr`` (..., C) holds channels ``names`` (C); name the first one with NaN or inf."""
    finite = np.isfinite(arr).reshape(-1, arr.shape[-1]).all(axis=0)
    if not finite.all():
        bad = names[int(np.argmin(finite))]
        raise UserError(f"{path}: channel '{bad}' contains NaN or infinite values")


#: the largest capture value taken in reflectance units (a reflectance is at most about 1; a
#: highlight or a saturated pixel a few times that): anything larger is a capture in other units
#: or a damaged file, refused rather than fitted
MAX_REFLECTANCE_CAPTURE = 1e3
#: the largest capture value taken in relative units (``units = "relative"``, raw counts)
MAX_RELATIVE_CAPTURE = 1e30


def _physical(arr, path, names, meta, valid=None):
    """``arr`` (..., C) of capture channels ``names`` holds no value beyond the limit of the
    dataset's units (inside ``valid`` when given); name the first channel that does."""
    relative = meta.get("units") == "relative"
    limit = MAX_RELATIVE_CAPTURE if relative else MAX_REFLECTANCE_CAPTURE
    flat = np.abs(arr).reshape(-1, arr.shape[-1])
    if valid is not None and valid.shape == arr.shape[:-1]:
        flat = flat[np.asarray(valid).reshape(-1)]
    if flat.size == 0:
        return
    peak = flat.max(axis=0)
    if np.any(peak > limit):
        i = int(np.argmax(peak > limit))
        units = "relative units" if relative else "reflectance units (a reflectance is at most about 1)"
        raise UserError(f"{path}: channel '{names[i]}' holds {float(peak[i]):.3g}, not a capture in "
                        f"{units}; at most {limit:g} is taken")


def _same_bands(ch, prefix, count, path, meta_path):
    """The band channels (``prefix`` + ``band000`` …) of an EXR are no more than ``count``, the
    wavelengths of ``meta.json`` (fewer: the first missing one is named by ``_require``)."""
    first = band_channel(0)
    stem = first.rstrip("0123456789")
    held = sum(1 for k in ch if k.startswith(prefix + stem) and k[len(prefix + stem):].isdigit())
    if held > count:
        raise UserError(f"{meta_path}: lists {count} wavelengths but {path.name} holds {held} bands "
                        f"({prefix}{stem}…); expected one wavelength per band")


def _check_meta(meta, meta_path):
    if not isinstance(meta, dict):
        raise UserError(f"{meta_path}: expected a JSON object, got {type(meta).__name__}")
    for key in ("wavelengths_nm", "polarizer_angles_deg"):
        if key not in meta:
            continue
        values = meta[key]
        if not isinstance(values, list) or not all(
                isinstance(v, (int, float)) and not isinstance(v, bool) and np.isfinite(v) for v in values):
            raise UserError(f"{meta_path}: '{key}' must be a list of numbers, got {values!r}"[:300])
    wl = meta.get("wavelengths_nm", [])
    if "wavelengths_nm" in meta and not wl:
        raise UserError(f"{meta_path}: 'wavelengths_nm' is empty; expected the bands' wavelengths in nm "
                        f"(or no such key)")
    if len(wl) > 1 and np.any(np.diff(wl) <= 0):
        raise UserError(f"{meta_path}: 'wavelengths_nm' must be increasing")
    if any(v <= 0 for v in wl):
        raise UserError(f"{meta_path}: 'wavelengths_nm' must be wavelengths in nm > 0")
    angles = meta.get("polarizer_angles_deg", [])
    if any(v != round(v) or not 0 <= v < 360 for v in angles):
        raise UserError(f"{meta_path}: 'polarizer_angles_deg' must be whole degrees from 0 to 359 "
                        f"(layer names pol000 … pol359), got {angles!r}"[:300])
    if len(set(angles)) != len(angles):
        raise UserError(f"{meta_path}: 'polarizer_angles_deg' holds an angle twice, got {angles!r}"[:300])


@dataclass
class Dataset:
    """A dataset folder in memory. Images are float32, row 0 at the top.

    Attributes
    ----------
    ground_truth : dict
        ``normal`` (H, W, 3), ``zenith``, ``azimuth`` (deg), ``thickness`` (nm), ``depth``,
        ``mask`` (bool), each H×W. Empty for a user capture without ground truth.
    polarized_rgb : dict
        polarizer angle in degrees (int) → (H, W, 3) camera RGB; empty if absent.
    spectral_s : ndarray or None
        (H, W, B) s-polarized reflectance per band.
    stokes : dict
        ``"S0"``, ``"S1"``, ``"S2"`` → (H, W, B); empty if absent.
    valid : ndarray or None
        (H, W) bool, the pixels whose captures can be trusted (``valid.exr``); None when the
        folder has no ``valid.exr`` (every pixel). Methods reconstruct only valid pixels.
    """

    path: Path
    meta: dict
    ground_truth: dict = field(default_factory=dict)
    polarized_rgb: dict = field(default_factory=dict)
    spectral_s: np.ndarray | None = None
    stokes: dict = field(default_factory=dict)
    valid: np.ndarray | None = None

    @property
    def wavelengths_nm(self) -> np.ndarray:
        return np.asarray(self.meta.get("wavelengths_nm", []), dtype=np.float64)

    @property
    def polarizer_angles_deg(self) -> list:
        return sorted(self.polarized_rgb)

    @property
    def mask(self) -> np.ndarray | None:
        return self.ground_truth.get("mask")

    def has(self, part: str) -> bool:
        """Whether the part (``ground_truth``, ``polarized_rgb``, ``spectral_s``, ``stokes``) was read."""
        value = {"ground_truth": self.ground_truth, "polarized_rgb": self.polarized_rgb,
                 "spectral_s": self.spectral_s, "stokes": self.stokes}[part]
        return value is not None and (not isinstance(value, dict) or bool(value))

    @property
    def pixel_size(self) -> float | None:
        """Scene units per pixel (``meta.json`` ``projection.pixel_size``), None when absent."""
        proj = self.meta.get("projection")
        if not isinstance(proj, dict) or proj.get("pixel_size") is None:
            return None
        value = proj["pixel_size"]
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not (np.isfinite(value) and value > 0):
            raise UserError(f"{self.path / 'meta.json'}: 'projection.pixel_size' must be a positive number, "
                            f"got {value!r}")
        return float(value)

    def film(self):
        """The film of ``meta.json`` (:meth:`thinfilm.core.film.Film.from_meta`)."""
        from .film import Film

        return Film.from_meta(self.meta, str(self.path / "meta.json"))

    @property
    def shape(self) -> tuple:
        for img in (self.spectral_s, *self.polarized_rgb.values(), self.stokes.get("S0"), self.ground_truth.get("mask"),
                    self.valid):
            if img is not None:
                return tuple(img.shape[:2])
        raise UserError(f"{self.path}: dataset holds no image")


def check_polarizer_calibration(meta: dict, where) -> bool:
    """Warn (:class:`~thinfilm.core.errors.ThinfilmWarning`) when ``meta.json`` records a
    polarizer extinction ratio or axis offset that the captures were not corrected for
    (:data:`POLARIZER_NOT_CORRECTED`): the estimators model ideal polarizers. Returns whether
    it warned."""
    import warnings

    from .errors import ThinfilmWarning

    cal = meta.get("calibration")
    pol = cal.get("polarizer") if isinstance(cal, dict) else None
    if not isinstance(pol, dict) or pol.get("correction") != POLARIZER_NOT_CORRECTED:
        return False
    warnings.warn(f"{where}: the captures were taken through a polarizer of extinction ratio "
                  f"{pol.get('extinction_ratio')} and axis offset {pol.get('angle_offset_deg')} deg that they could "
                  f"not be corrected for; the estimators model an ideal polarizer at the nominal angle, so the "
                  f"polarized part of the estimate is biased", ThinfilmWarning, stacklevel=3)
    return True


def read_dataset(path, need=("polarized_rgb",), optional=None) -> Dataset:
    """Read and validate a dataset folder.

    Parameters
    ----------
    path : path-like
        The folder.
    need : iterable of str
        Parts that must be present: any of ``"ground_truth"``, ``"polarized_rgb"``,
        ``"spectral_s"``, ``"stokes"``.
    optional : iterable of str or None
        Parts read (and validated) only when present. ``None``: every part not in ``need``.
        Parts in neither are not read at all.

    The optional ``valid.exr`` is read whenever it is present (:attr:`Dataset.valid`).

    Raises
    ------
    UserError
        One sentence naming the file and channel: missing folder, file or channel, unknown
        ``format``, shape mismatch, NaN in a capture.
    """
    root = Path(path)
    if not root.is_dir():
        raise UserError(f"{root}: dataset folder not found")
    meta_path = root / "meta.json"
    meta = read_json(meta_path, missing="not a thinfilm dataset folder", finite=True)
    _check_meta(meta, meta_path)
    check_polarizer_calibration(meta, meta_path)
    if meta.get("format") != FORMAT:
        raise UserError(f"{meta_path}: unknown format {meta.get('format')!r}, expected '{FORMAT}'")
    need = set(need)
    parts = {"ground_truth", "polarized_rgb", "spectral_s", "stokes"}
    unknown = need - parts
    if unknown:
        raise ValueError(f"read_dataset: unknown parts {sorted(unknown)}")
    wanted = need | (parts - need if optional is None else set(optional))
    ds = Dataset(path=root, meta=meta)
    shape = None
    file_part = {"ground_truth.exr": "ground_truth", "polarized_rgb.exr": "polarized_rgb",
                 "spectral_s.exr": "spectral_s", "stokes_spectral.exr": "stokes"}

    def load(name, required):
        p = root / name
        if file_part[name] not in wanted:
            return None
        if not os.path.exists(p) or os.path.isdir(p):  # a pipe or a device: read_exr refuses it
            if required:
                raise UserError(f"{p}: file not found")
            return None
        return p, read_exr(p)

    def valid_mask():  # the pixels whose captures are checked: valid.exr's, when it is readable
        p = root / "valid.exr"
        if not os.path.isfile(p):
            return None
        try:
            return read_exr(p, ["valid"])["valid"] > 0.5
        except UserError:
            return None  # reported below, with the shape check

    got = load("ground_truth.exr", "ground_truth" in need)
    if got:
        p, ch = got
        shape = next(iter(ch.values())).shape
        gt = _require(ch, GROUND_TRUTH_CHANNELS, p, shape)
        _no_nan(np.stack([gt[k] for k in GROUND_TRUTH_CHANNELS], axis=-1), p, list(GROUND_TRUTH_CHANNELS))
        ds.ground_truth = {
            "normal": np.stack([gt["normal.X"], gt["normal.Y"], gt["normal.Z"]], axis=-1),
            "zenith": gt["zenith"], "azimuth": gt["azimuth"], "thickness": gt["thickness"],
            "depth": gt["depth"], "mask": gt["mask"] > 0.5,
        }

    got = load("polarized_rgb.exr", "polarized_rgb" in need)
    if got:
        p, ch = got
        shape = shape or next(iter(ch.values())).shape
        layers = sorted({k.split(".")[0] for k in ch if k.startswith("pol")})
        angles = meta.get("polarizer_angles_deg") or [int(layer[3:]) for layer in layers]
        for a in angles:
            layer = pol_layer(a)
            rgb = _require(ch, [f"{layer}.R", f"{layer}.G", f"{layer}.B"], p, shape)
            img = np.stack(list(rgb.values()), axis=-1)
            _no_nan(img, p, list(rgb))
            _physical(img, p, list(rgb), meta, valid_mask())
            ds.polarized_rgb[int(round(a)) % 360] = img

    bands = meta.get("wavelengths_nm", [])
    got = load("spectral_s.exr", "spectral_s" in need)
    if got:
        p, ch = got
        shape = shape or next(iter(ch.values())).shape
        names = [band_channel(i) for i in range(len(bands))]
        if not names:
            raise UserError(f"{meta_path}: 'wavelengths_nm' is empty but {p.name} is present")
        _same_bands(ch, "", len(bands), p, meta_path)
        cube = np.stack(list(_require(ch, names, p, shape).values()), axis=-1)
        _no_nan(cube, p, names)
        _physical(cube, p, names, meta, valid_mask())
        ds.spectral_s = cube

    got = load("stokes_spectral.exr", "stokes" in need)
    if got:
        p, ch = got
        shape = shape or next(iter(ch.values())).shape
        if not bands:
            raise UserError(f"{meta_path}: no 'wavelengths_nm' but {p.name} is present")
        for s in ("S0", "S1", "S2"):
            _same_bands(ch, f"{s}.", len(bands), p, meta_path)
            names = [f"{s}.{band_channel(i)}" for i in range(len(bands))]
            cube = np.stack(list(_require(ch, names, p, shape).values()), axis=-1)
            _no_nan(cube, p, names)
            if s == "S0":
                _physical(cube, p, names, meta, valid_mask())
            ds.stokes[s] = cube

    p = root / "valid.exr"
    if os.path.exists(p) and not os.path.isdir(p):
        arr = read_exr(p, ["valid"])["valid"]
        if shape is not None and arr.shape != shape:
            raise UserError(f"{p}: channel 'valid' has shape {arr.shape}, expected {shape}")
        _no_nan(arr[..., None], p, ["valid"])
        ds.valid = arr > 0.5
    return ds


def software_versions() -> dict:
    """Versions of the packages that shape a dataset's bytes (for ``meta.json``)."""
    from importlib import metadata

    import thinfilm

    out = {"thinfilm": thinfilm.__version__, "numpy": np.__version__}
    for dist in ("mitsuba", "drjit"):
        try:
            out[dist] = metadata.version(dist)
        except metadata.PackageNotFoundError:
            pass
    return out


def dataset_meta(**fields) -> dict:
    """A ``meta.json`` dictionary: ``format`` and ``versions`` filled in, then ``fields``."""
    meta = {"format": FORMAT, "versions": software_versions()}
    meta.update(fields)
    return meta


def write_dataset(folder, meta: dict, ground_truth: dict | None = None, polarized_rgb: dict | None = None,
                  spectral_s=None, stokes: dict | None = None, scene_toml: str | None = None,
                  preview: bool = True, valid=None) -> Path:
    """Write the files of a ``thinfilm-dataset/1`` folder into ``folder`` (which exists).

    Parameters
    ----------
    meta : dict
        ``meta.json`` (see :func:`dataset_meta`); must hold ``format``.
    ground_truth : dict, optional
        ``normal`` (H, W, 3), ``zenith``, ``azimuth``, ``thickness``, ``depth``, ``mask``.
    polarized_rgb : dict, optional
        angle (deg) → (H, W, 3) camera RGB.
    spectral_s : ndarray (H, W, B), optional
    stokes : dict, optional
        ``S0``, ``S1``, ``S2`` → (H, W, B).
    scene_toml : str, optional
        The resolved scene spec (``scene.toml``).
    preview : bool
        Write ``preview.png`` (needs ``polarized_rgb``; the normal map beside it when there is
        ground truth).
    valid : (H, W) bool, optional
        Pixels whose captures can be trusted (``valid.exr``); None: every pixel, no file.
    """
    folder = Path(folder)
    if meta.get("format") != FORMAT:
        raise ValueError(f"meta.json must have format {FORMAT!r}")
    if scene_toml is not None:
        (folder / "scene.toml").write_text(scene_toml, encoding="utf-8")
    write_json(folder / "meta.json", meta)
    if ground_truth:
        gt = ground_truth
        write_exr(folder / "ground_truth.exr", {
            "normal.X": gt["normal"][..., 0], "normal.Y": gt["normal"][..., 1],
            "normal.Z": gt["normal"][..., 2], "zenith": gt["zenith"], "azimuth": gt["azimuth"],
            "thickness": gt["thickness"], "depth": gt["depth"],
            "mask": np.asarray(gt["mask"]).astype(np.float32)})
    if polarized_rgb:
        write_exr(folder / "polarized_rgb.exr", polarized_rgb_channels(polarized_rgb))
    if spectral_s is not None:
        write_exr(folder / "spectral_s.exr", band_channels(np.asarray(spectral_s)))
    if stokes:
        write_exr(folder / "stokes_spectral.exr", {
            k: v for s in ("S0", "S1", "S2") for k, v in band_channels(np.asarray(stokes[s]), f"{s}.").items()})
    if valid is not None:
        write_exr(folder / "valid.exr", {"valid": np.asarray(valid).astype(np.float32)})
    if preview and polarized_rgb:
        _write_preview(folder / "preview.png", polarized_rgb, ground_truth)
    return folder


def _srgb8(linear: np.ndarray) -> np.ndarray:
    x = np.clip(linear, 0.0, 1.0)
    srgb = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)
    return np.rint(srgb * 255.0).astype(np.uint8)


def _write_preview(path: Path, polarized_rgb: dict, ground_truth: dict | None) -> None:
    """The camera's unpolarized RGB (auto-scaled, sRGB), and the normal map when known."""
    from PIL import Image

    from .conventions import stokes_from_polarizer_images

    s0 = stokes_from_polarizer_images(polarized_rgb)[0]
    mask = None if not ground_truth else np.asarray(ground_truth["mask"], dtype=bool)
    sel = mask if mask is not None and mask.any() else np.ones(s0.shape[:2], dtype=bool)
    level = np.percentile(s0[sel], 99) if sel.any() else 1.0
    panels = [_srgb8(s0 / (level if level > 0 else 1.0))]
    if mask is not None:
        normal = np.where(mask[..., None], 0.5 * (ground_truth["normal"] + 1.0), 0.0)
        panels += [np.zeros((s0.shape[0], 4, 3), dtype=np.uint8),
                   np.rint(np.clip(normal, 0, 1) * 255).astype(np.uint8)]
    Image.fromarray(np.concatenate(panels, axis=1)).save(path, format="PNG")
