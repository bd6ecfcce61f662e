"""Camera and illuminant spectra, and the camera response to reflectance spectra.

One place for ``I = Σ S(λ) E(λ) R(λ) Δλ`` (paper Eq. 1), used by the capture
generator, the RGB reconstruction's forward model and the evaluation.

Camera RGB is white-balanced so that a perfect mirror (R = 1 at every band) gives
``(1, 1, 1)``.

Examples
--------
>>> import numpy as np
>>> wl = np.arange(400.0, 721.0, 4.0)
>>> rgb = spectra_to_camera_rgb(np.ones(wl.shape), wl)
>>> np.allclose(rgb, 1.0)
True
"""

from __future__ import annotations

import functools
from pathlib import Path

import numpy as np

from .errors import UserError

__all__ = [
    "DEFAULT_CAMERA",
    "DEFAULT_ILLUMINANT",
    "band_widths",
    "camera_sensitivities",
    "illuminant_spd",
    "camera_weights",
    "spectra_to_camera_rgb",
]

DEFAULT_CAMERA = "Nikon 5100 (NPL)"
DEFAULT_ILLUMINANT = "D65"


def band_widths(wavelengths_nm) -> np.ndarray:
    """Quadrature weights Δλ (nm) of a wavelength grid (trapezoid rule; uniform grids get a
    constant step, with half weight at both ends)."""
    wl = np.asarray(wavelengths_nm, dtype=np.float64)
    if wl.ndim != 1 or wl.size < 2 or np.any(np.diff(wl) <= 0):
        raise UserError(f"wavelengths_nm must be increasing with at least 2 entries, got {wl.tolist()}")
    w = np.zeros_like(wl)
    d = np.diff(wl)
    w[:-1] += 0.5 * d
    w[1:] += 0.5 * d
    return w


def _read_csv(path: Path, columns: int, what: str) -> np.ndarray:
    """Rows ``wavelength_nm, value × columns`` of a CSV (``#`` comments, an optional header
    row): at least 2 rows, finite numbers, values >= 0, wavelengths increasing. Anything
    else is one :class:`UserError` naming the file and the line."""
    names = "wavelength_nm and " + (f"{columns} values" if columns > 1 else "a value")
    from .files import read_text_file

    text = read_text_file(path, f"{what} CSV", encoding="utf-8-sig")
    rows = []
    for lineno, line in enumerate(text.splitlines(), 1):
        line = line.split("#", 1)[0].strip()
        if not line:
            continue
        cells = [c.strip() for c in line.split(",")]
        try:
            values = [float(c) for c in cells]
        except ValueError:
            if not rows and not any(_is_float(c) for c in cells[:1]):
                continue  # a header row
            bad = next(c for c in cells if not _is_float(c))
            raise UserError(f"{path}: line {lineno}: {what} CSV cell {bad!r} is not a number") from None
        if len(values) != columns + 1:
            raise UserError(f"{path}: line {lineno}: {what} CSV needs {columns + 1} columns ({names}), "
                            f"found {len(values)}")
        if not all(np.isfinite(values)):
            raise UserError(f"{path}: line {lineno}: {what} CSV holds NaN or infinity")
        if values[0] <= 0 or any(v < 0 for v in values[1:]):
            raise UserError(f"{path}: line {lineno}: {what} CSV needs a wavelength > 0 and values >= 0")
        rows.append(values)
    if len(rows) < 2:
        raise UserError(f"{path}: {what} CSV needs at least 2 rows of {names}, found {len(rows)}")
    data = np.asarray(rows, dtype=np.float64)
    if np.any(np.diff(data[:, 0]) <= 0):
        raise UserError(f"{path}: {what} CSV wavelengths must be increasing")
    return data


def _is_float(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


@functools.lru_cache(maxsize=32)
def _camera_table(name: str):
    path = Path(name)
    if path.suffix.lower() == ".csv":
        data = _read_csv(path, 3, "camera sensitivity")
        return data[:, 0], data[:, 1:]
    import colour

    if name not in colour.MSDS_CAMERA_SENSITIVITIES:
        names = ", ".join(sorted(colour.MSDS_CAMERA_SENSITIVITIES))
        raise UserError(f"unknown camera {name!r}: expected one of {names}, or a CSV path")
    msds = colour.MSDS_CAMERA_SENSITIVITIES[name]
    return np.asarray(msds.wavelengths, dtype=np.float64), np.asarray(msds.values, dtype=np.float64)


@functools.lru_cache(maxsize=32)
def _illuminant_table(name: str):
    path = Path(name)
    if path.suffix.lower() == ".csv":
        data = _read_csv(path, 1, "illuminant")
        return data[:, 0], data[:, 1]
    import colour

    if name not in colour.SDS_ILLUMINANTS:
        names = ", ".join(sorted(colour.SDS_ILLUMINANTS))
        raise UserError(f"unknown illuminant {name!r}: expected one of {names}, or a CSV path")
    sd = colour.SDS_ILLUMINANTS[name]
    return np.asarray(sd.wavelengths, dtype=np.float64), np.asarray(sd.values, dtype=np.float64)


def camera_sensitivities(camera: str, wavelengths_nm) -> np.ndarray:
    """Camera RGB sensitivities at ``wavelengths_nm``, shape (B, 3), zero outside the table.

    ``camera`` is a colour-science name (``colour.MSDS_CAMERA_SENSITIVITIES``) or a CSV
    file with columns ``wavelength_nm, r, g, b``.
    """
    wl, values = _camera_table(str(camera))
    x = np.asarray(wavelengths_nm, dtype=np.float64)
    return np.stack([np.interp(x, wl, values[:, c], left=0.0, right=0.0) for c in range(3)], axis=-1)


def illuminant_spd(illuminant: str, wavelengths_nm) -> np.ndarray:
    """Illuminant spectral power at ``wavelengths_nm``, shape (B,), zero outside the table.

    ``illuminant`` is a colour-science name (``colour.SDS_ILLUMINANTS``) or a CSV file with
    columns ``wavelength_nm, power``.
    """
    wl, values = _illuminant_table(str(illuminant))
    return np.interp(np.asarray(wavelengths_nm, dtype=np.float64), wl, values, left=0.0, right=0.0)


def camera_weights(wavelengths_nm, camera: str = DEFAULT_CAMERA,
                   illuminant: str = DEFAULT_ILLUMINANT) -> np.ndarray:
    """Weights W (B, 3) with ``rgb = R @ W``: S(λ) E(λ) Δλ, white-balanced per channel."""
    w = camera_sensitivities(camera, wavelengths_nm) * (
        illuminant_spd(illuminant, wavelengths_nm) * band_widths(wavelengths_nm))[:, None]
    total = w.sum(axis=0)
    if not np.all(np.isfinite(total)):
        raise UserError(f"camera {camera!r} and illuminant {illuminant!r}: their product overflows over "
                        f"{wavelengths_nm[0]:.0f}-{wavelengths_nm[-1]:.0f} nm (values too large)")
    if np.any(total <= 0):
        raise UserError(f"camera {camera!r} and illuminant {illuminant!r} give no signal over "
                        f"{wavelengths_nm[0]:.0f}-{wavelengths_nm[-1]:.0f} nm")
    return w / total


def spectra_to_camera_rgb(reflectance, wavelengths_nm, camera: str = DEFAULT_CAMERA,
                          illuminant: str = DEFAULT_ILLUMINANT) -> np.ndarray:
    """Linear, white-balanced camera RGB of reflectance spectra.

    Parameters
    ----------
    reflectance : array_like, shape (..., B)
        Reflectance (or any linear radiometric quantity in reflectance units, such as one
        Stokes component) sampled at ``wavelengths_nm``.

    Returns
    -------
    ndarray, shape (..., 3)
    """
    return np.asarray(reflectance, dtype=np.float64) @ camera_weights(
        np.asarray(wavelengths_nm, dtype=np.float64), camera, illuminant)
