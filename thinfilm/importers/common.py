"""What both importers share: option parsing, reference spectra, provenance, ``meta.json``."""

from __future__ import annotations

import hashlib
import math
import warnings
from pathlib import Path

import numpy as np

from thinfilm.core.errors import ThinfilmWarning, UserError

__all__ = ["DEFAULT_WAVELENGTHS", "parse_numbers", "parse_angles", "parse_wavelengths", "read_spectrum_csv",
           "reference_reflectance", "file_record", "csv_records", "film_fields", "import_meta", "warn_relative_units", "input_files",
           "polarizer_calibration", "correct_polarizers", "check_dark_values", "POLARIZER_CORRECTED"]

#: ``calibration.polarizer.correction`` of ``meta.json`` when the captures were corrected to
#: ideal polarizers at the nominal angles
POLARIZER_CORRECTED = "captures corrected to ideal polarizers at the nominal angles"

#: The wavelength grid of the camera model when none is given (the generator's default bands).
DEFAULT_WAVELENGTHS = "400:720:4"


def parse_numbers(text, where: str, count: int | None = None) -> list:
    """Comma- (or space-) separated finite numbers; ``count`` of them when given."""
    parts = [t for t in str(text).replace(",", " ").split() if t]
    try:
        values = [float(t) for t in parts]
    except ValueError:
        raise UserError(f"{where}: expected comma-separated numbers, got {text!r}") from None
    if not values or not all(math.isfinite(v) for v in values):
        raise UserError(f"{where}: expected comma-separated finite numbers, got {text!r}")
    if count is not None and len(values) != count:
        raise UserError(f"{where}: expected {count} numbers, got {len(values)} ({text!r})")
    return values


def parse_angles(text, where: str = "--angles") -> list:
    """Polarizer angles in whole degrees, distinct modulo 180°, at least three that fix S0, S1,
    S2 (:func:`thinfilm.core.conventions.check_polarizer_angles`)."""
    from thinfilm.core.conventions import check_polarizer_angles

    values = parse_numbers(text, where)
    if any(abs(v - round(v)) > 1e-9 for v in values):
        raise UserError(f"{where}: polarizer angles must be whole degrees, got {text!r}")
    angles = [int(round(v)) for v in values]
    folded = [a % 180 for a in angles]
    dup = sorted({a for a in folded if folded.count(a) > 1})
    if dup:
        raise UserError(f"{where}: polarizer angle {dup[0]} (modulo 180 degrees) is given twice in {text!r}")
    check_polarizer_angles(angles, where)
    return angles


def parse_wavelengths(text, where: str = "--wavelengths") -> np.ndarray:
    """Band centres in nm: ``START:STOP:STEP`` (STOP included), comma-separated values, or a
    text/CSV file with one wavelength per line (first column). Increasing, positive, finite."""
    text = str(text).strip()
    path = Path(text).expanduser()
    if path.is_file():
        try:
            data = np.loadtxt(path, delimiter=",", comments="#", ndmin=2, usecols=0)
        except ValueError:
            try:
                data = np.loadtxt(path, delimiter=",", comments="#", ndmin=2, usecols=0, skiprows=1)
            except ValueError as e:
                raise UserError(f"{where}: {path}: not a list of numbers ({e})") from None
        wl = np.asarray(data, dtype=np.float64).ravel()
    elif text.count(":") == 2:
        start, stop, step = (parse_numbers(t, where, 1)[0] for t in text.split(":"))
        if step <= 0 or stop <= start:
            raise UserError(f"{where}: expected START:STOP:STEP with START < STOP and STEP > 0, got {text!r}")
        count = int(math.floor((stop - start) / step + 1e-9)) + 1
        if count > 100000:
            raise UserError(f"{where}: {text!r} gives more than 100000 bands")
        wl = start + step * np.arange(count, dtype=np.float64)
    else:
        wl = np.asarray(parse_numbers(text, where), dtype=np.float64)
    if wl.size < 2:
        raise UserError(f"{where}: need at least 2 wavelengths, got {wl.size}")
    if not np.all(np.isfinite(wl)) or np.any(wl <= 0):
        raise UserError(f"{where}: wavelengths must be positive numbers of nm")
    if np.any(np.diff(wl) <= 0):
        raise UserError(f"{where}: wavelengths must be increasing, got {wl[:6].tolist()}...")
    return wl


def read_spectrum_csv(path, where: str) -> tuple:
    """A two-column CSV ``wavelength_nm, value`` (``#`` comments, an optional header line):
    ``(wavelengths, values)``, wavelengths increasing."""
    p = Path(path).expanduser()
    if not p.is_file():
        raise UserError(f"{where}: {p}: file not found")
    try:
        try:
            data = np.loadtxt(p, delimiter=",", comments="#", ndmin=2)
        except ValueError:
            data = np.loadtxt(p, delimiter=",", comments="#", ndmin=2, skiprows=1)
    except (ValueError, UnicodeDecodeError) as e:
        raise UserError(f"{where}: {p}: not a CSV of numbers ({' '.join(str(e).split())[:120]})") from None
    if data.shape[1] != 2 or data.shape[0] < 2:
        raise UserError(f"{where}: {p}: expected two columns (wavelength_nm, value) and at least 2 rows, "
                        f"got {data.shape[0]} x {data.shape[1]}")
    if not np.all(np.isfinite(data)):
        raise UserError(f"{where}: {p}: contains NaN or infinite values")
    order = np.argsort(data[:, 0])
    wl, values = data[order, 0], data[order, 1]
    if np.any(np.diff(wl) <= 0):
        raise UserError(f"{where}: {p}: a wavelength is listed twice")
    return wl, values


def reference_reflectance(text, where: str, wavelengths_nm):
    """The reflectance of a reference target: a number (the same at every band) or a CSV
    spectrum, interpolated onto ``wavelengths_nm``, which it must cover. Returns (B,)."""
    wl = np.asarray(wavelengths_nm, dtype=np.float64)
    try:
        value = float(text)
    except (TypeError, ValueError):
        value = None
    if value is not None:
        if not (math.isfinite(value) and value > 0):
            raise UserError(f"{where}: reflectance must be a number > 0, got {text!r}")
        return np.full(wl.shape, value)
    rw, rv = read_spectrum_csv(text, where)
    if rw[0] > wl[0] + 1e-9 or rw[-1] < wl[-1] - 1e-9:
        raise UserError(f"{where}: {text}: covers {rw[0]:g}-{rw[-1]:g} nm, not the bands {wl[0]:g}-{wl[-1]:g} nm")
    out = np.interp(wl, rw, rv)
    if np.any(out <= 0):
        raise UserError(f"{where}: {text}: reflectance must be > 0 over the bands")
    return out


def file_record(path, role: str) -> dict:
    """Provenance of an input file for ``meta.json``: absolute path, role and SHA-256."""
    p = Path(path).expanduser().resolve()
    h = hashlib.sha256()
    from thinfilm.core.files import open_regular

    with open_regular(p, f"{role} file") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return {"path": str(p), "role": role, "sha256": h.hexdigest()}


def csv_records(value, role: str) -> list:
    """The provenance (:func:`file_record`) of a CSV an option names (``--white-reflectance``,
    ``--camera``, ``--illuminant``), in a list; empty for a number or a built-in name."""
    if value is None or isinstance(value, (int, float)) or not str(value).lower().endswith(".csv"):
        return []
    return [file_record(value, role)]


def film_fields(film_ior=None, substrate_ior=None) -> dict:
    """``meta.json`` entries for a known film and/or substrate index (``--film-ior``,
    ``--substrate-ior``: a number, ``n+ki`` or a material name), written as the generator writes
    them (:meth:`thinfilm.core.film.Film.to_meta`); empty when neither is given."""
    from thinfilm.core.film import Film, as_index, index_to_json

    n2 = None if film_ior is None else as_index(_number_or_name(film_ior), "--film-ior")
    n3 = None if substrate_ior is None else as_index(_number_or_name(substrate_ior), "--substrate-ior")
    if n2 is not None and n3 is not None:
        return Film.single(n2, None, n3, 0.0, where="--film-ior/--substrate-ior").to_meta()
    out = {}
    if n2 is not None:
        out["film_ior"] = index_to_json(n2)
    if n3 is not None:
        out["substrate_ior"] = index_to_json(n3)
    return out


def _number_or_name(value):
    try:
        return float(value)
    except (TypeError, ValueError):
        return str(value)


def warn_relative_units(what: str) -> None:
    warnings.warn(f"no white reference or gains: the imported {what} are in relative units, not reflectance; "
                  f"methods that compare them with the film model will be off by a scale", ThinfilmWarning,
                  stacklevel=3)


def import_meta(kind: str, inputs: list, units: str, calibration: dict, **fields) -> dict:
    """``meta.json`` of an imported dataset: ``source = "imported"``, the inputs (path, role,
    SHA-256), the units (``reflectance`` or ``relative``), the calibration applied, and
    ``fields``."""
    from thinfilm.core.io import dataset_meta

    return dataset_meta(source="imported", imported_as=kind, imported_from=inputs, units=units,
                        calibration=calibration, **fields)


def input_files(*items) -> list:
    """The arguments that name existing files (images, cubes, references, CSVs): an output
    may not be, contain or lie inside any of them (:mod:`thinfilm.core.outputs`). Levels
    and names that are not files are left out."""
    out = []
    for item in items:
        if item is None or isinstance(item, (int, float)):
            continue
        path = Path(str(item)).expanduser()
        if path.exists():
            out.append(path)
    return out


def _calibration_numbers(text, where: str, count: int) -> tuple:
    """A number, comma-separated numbers (one per polarizer angle) or a text file of them
    (``#`` comments): (values (count,), the file's provenance record or None)."""
    from thinfilm.core.files import read_text_file

    path = Path(str(text)).expanduser()
    record = None
    if path.is_file():
        body = "\n".join(line.split("#", 1)[0] for line in read_text_file(path, f"{where} file").splitlines())
        values = parse_numbers(body, f"{where}: {path}")
        record = file_record(path, where.strip("-").replace("-", " "))
    else:
        values = parse_numbers(text, where)
    if len(values) == 1:
        values = values * count
    if len(values) != count:
        raise UserError(f"{where}: {len(values)} values for {count} polarizer angles (give one, or one per angle)")
    return values, record


def polarizer_calibration(extinction, offset, angles) -> tuple:
    """``--polarizer-extinction`` and ``--polarizer-offset`` (numbers, one per angle, or files
    of them) for the polarizers at ``angles``: (the ``calibration.polarizer`` entry of
    ``meta.json``, or None when neither is given; provenance records of the files).

    The extinction ratio ε is the polarizer's minimum over maximum transmittance, in [0, 1);
    the offset δ, in degrees within ±45°, is its measured axis minus its nominal angle, in
    the project's convention (counter-clockwise from image +x towards +y)."""
    if extinction is None and offset is None:
        return None, []
    n = len(angles)
    records = []
    eps, off = [0.0] * n, [0.0] * n
    if extinction is not None:
        eps, rec = _calibration_numbers(extinction, "--polarizer-extinction", n)
        records += [rec] if rec else []
        bad = [e for e in eps if not 0.0 <= e < 1.0]
        if bad:
            raise UserError(f"--polarizer-extinction: an extinction ratio (minimum over maximum transmittance) must "
                            f"lie in [0, 1), got {bad[0]:g}")
    if offset is not None:
        off, rec = _calibration_numbers(offset, "--polarizer-offset", n)
        records += [rec] if rec else []
        bad = [d for d in off if not abs(d) < 45.0]
        if bad:
            raise UserError(f"--polarizer-offset: an angle offset must lie within +-45 degrees, got {bad[0]:g}")
    entry = {"angles_deg": [int(a) for a in angles], "extinction_ratio": [float(e) for e in eps],
             "angle_offset_deg": [float(d) for d in off],
             "diattenuation": [float((1 - e) / (1 + e)) for e in eps],
             "model": "I = 1/2 (S0 + D (S1 cos 2(a + offset) + S2 sin 2(a + offset))), D = (1 - e) / (1 + e)"}
    return entry, records


def correct_polarizers(images: dict, entry: dict) -> tuple:
    """Images behind real polarizers (``entry``: :func:`polarizer_calibration`) → the images
    ideal polarizers at the nominal angles would give: per pixel the least-squares Stokes
    vector through the real analyzer (:func:`thinfilm.core.conventions.analyzer_matrix`)
    replaces the real polarizers' part of each image by the ideal ones' (what the fit does
    not explain, the noise, stays). Returns (images, noise gain): the gain is how much the
    correction multiplies the noise of the linear Stokes parameters S1, S2 (the square root
    of the ratio of their least-squares variances with the real and with ideal polarizers)."""
    from thinfilm.core.conventions import analyzer_matrix, stokes_design_matrix

    angles = entry["angles_deg"]
    real = analyzer_matrix(angles, entry["extinction_ratio"], entry["angle_offset_deg"])
    ideal = stokes_design_matrix(angles)
    stack = np.stack([np.asarray(images[a], dtype=np.float64) for a in angles])
    stokes = np.tensordot(np.linalg.pinv(real), stack, axes=(1, 0))
    corrected = stack + np.tensordot(ideal - real, stokes, axes=(1, 0))
    var_real = np.diag(np.linalg.inv(real.T @ real))[1:]
    var_ideal = np.diag(np.linalg.inv(ideal.T @ ideal))[1:]
    gain = float(np.sqrt(np.max(var_real / var_ideal)))
    return {a: corrected[k] for k, a in enumerate(angles)}, gain


def check_dark_values(values, where: str) -> None:
    """A dark frame or reference may hold no negative value (NaN and infinities are stopped
    by the readers)."""
    values = np.asarray(values, dtype=np.float64)
    if not np.all(np.isfinite(values)):
        raise UserError(f"{where}: contains NaN or infinite values")
    if np.any(values < 0):
        raise UserError(f"{where}: holds negative values (down to {float(values.min()):g}); a dark level is >= 0")
