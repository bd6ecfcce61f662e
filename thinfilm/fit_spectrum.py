"""``thinfilm fit-spectrum``: film thickness (and index) from measured reflection spectra.

::

    thinfilm fit-spectrum SPECTRUM... --film-ior N|MATERIAL|cauchy:A,B[,C]|cauchy-nm:A,B[,C] --substrate-ior N3
        [--substrate-k K] [--angle DEG] [--background FILE] [--reference FILE]
        [--wavelength-range MIN MAX] [--thickness-range MIN MAX] [--resolution FWHM]
        [--thickness-spread SIGMA] [--fit-film-ior] [--json]

Each SPECTRUM is fitted on its own (spectra sharing a wavelength grid are fitted in one batch);
the algorithm, its model of the instrument and its uncertainties are described in
:mod:`thinfilm.reconstruction.spectrum_fit`.

Files
-----
Two columns, wavelength in nm and value, separated by commas or whitespace. Lines starting
with ``#`` (and anything after a ``#``) are comments; one header line before the data is
allowed. Wavelengths must be strictly increasing or strictly decreasing (a decreasing file is
read backwards); repeated or unordered wavelengths are refused, never silently sorted.
NaN or infinite values are refused inside the fitted wavelength range and ignored outside
it. ``--background`` (a spectrum without film reflection: a black film, a dark reading) and
``--reference`` (a white reflector) are read the same way and interpolated linearly onto each
spectrum's wavelengths; they must cover its fitted range.

Indices
-------
``--film-ior`` is a number, a material name (a shipped table, :func:`thinfilm.bsdf.material_names`,
or a refractiveindex.info material, ``TiO2`` or ``main/TiO2/Sarkar``:
:func:`thinfilm.bsdf.materials.database_material`) or
``cauchy:A,B[,C]``, meaning ``n = A + B/λ² + C/λ⁴`` with λ in **µm** (B in µm², C in µm⁴), the
unit of :class:`thinfilm.bsdf.Cauchy` and of ``{"cauchy": [A, B, C]}`` in ``meta.json``.
Coefficients with λ in nm are taken only with their marker, ``cauchy-nm:A,B[,C]`` (B in nm², C
in nm⁴); ``cauchy:`` values plainly in nm (|B| > 1 µm², e.g. ``cauchy:1.5,4000``) and
``cauchy-nm:`` values plainly in µm are refused in one line that names the other form. ``--substrate-ior`` is a
number or a material name (``1`` for a free-standing film in air); ``--substrate-k`` its
extinction. With ``--fit-film-ior`` an offset to the film index is fitted (the given index is
the start) and reported at the middle of the fitted range.

Instrument
----------
The model of a reading includes the spectrometer's line width (``--resolution``, full width at
half maximum in nm) and the spread of the thickness over the light spot
(``--thickness-spread``, a standard deviation in nm); each is fitted (chosen among a few
values) unless given. Both wash out the fringes of thick films. The fit chooses the
interference order and regime itself; the best other reading is reported as the runner-up.

Limits
------
A spectrum file is at most :data:`MAX_SPECTRUM_BYTES` bytes (its size is checked before it is
read) and :data:`MAX_SPECTRUM_LINES` lines (counted while it is read, before it is parsed);
values beyond :data:`~thinfilm.reconstruction.spectrum_fit.MAX_VALUE` in magnitude are refused.
Before a fit starts its memory is estimated
(:func:`~thinfilm.reconstruction.spectrum_fit.estimated_memory_bytes`) and a fit that needs
more than the machine has is refused. A spectrum (less its background) without variation holds
no thickness information and is refused, as is a background brighter than the spectrum.

Errors
------
Every input is checked before anything is fitted: each bad file gets one line on stderr and
the exit code is 2, and no spectrum is fitted. (Fitting the good ones would leave a batch that
silently lacks rows; a user fixes or drops the bad file and runs again.)

Output
------
A table, or with ``--json`` one JSON object per line, one per SPECTRUM in the order given::

    {"path": ..., "thickness_nm": ..., "thickness_sigma_nm": ..., "film_ior": ...,
     "film_ior_wavelength_nm": ..., "film_ior_sigma": ... (with --fit-film-ior),
     "chi2": ..., "rms_residual": ..., "fringes": ..., "n_points": ...,
     "wavelength_range_nm": [min, max], "at_bound": ..., "thickness_spread_nm": ...,
     "resolution_nm": ..., "runner_up_thickness_nm": ..., "runner_up_chi2": ...,
     "runner_up_delta_bic": ...}

``chi2`` is the reduced chi-square against the spectrum's own point-to-point noise (well above
1: a misfit, or a smoothed spectrum); ``rms_residual`` is in the units of the spectrum;
``at_bound`` flags a thickness on an end of ``--thickness-range``. The runner-up is the best
reading a quarter of an interference order or more from the fit (``null`` where there is
none), ``runner_up_delta_bic`` how much worse it fits: a few units or less, and both readings
explain the spectrum about equally (the sigma then spans them).
"""

from __future__ import annotations

import json
import math
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from thinfilm.core.errors import UserError

__all__ = ["read_spectrum", "parse_index", "cli_main", "Spectrum"]


@dataclass
class Spectrum:
    """A spectrum read from a file: increasing wavelengths (nm), values, and the file's line
    number of each sample (for messages)."""

    path: str
    wavelengths_nm: np.ndarray
    values: np.ndarray
    lines: np.ndarray
    what: str = "spectrum"


def _fields(text):
    """The cells of one data line: comma-separated if it has a comma, else whitespace."""
    if "," in text:
        cells = [c.strip() for c in text.split(",")]
        if cells and cells[-1] == "":  # a trailing delimiter
            cells.pop()
        return cells
    return text.split()


def read_spectrum(path, what="spectrum") -> Spectrum:
    """Read a two-column spectrum file (see the module docstring for the format).

    Raises :class:`~thinfilm.core.errors.UserError` with one sentence naming the file (and the line)
    for a missing or unreadable file, a cell that is not a number, a line without exactly two
    cells, a non-positive or non-finite wavelength, repeated or unordered wavelengths, and a
    file without data.
    """
    p = Path(path)
    from thinfilm.core.io import read_text_file

    text = read_text_file(p, f"{what} file (two columns: wavelength in nm, value)", max_bytes=MAX_SPECTRUM_BYTES,
                          max_lines=MAX_SPECTRUM_LINES)

    rows, lines = [], []
    header_allowed = True
    for number, raw in enumerate(text.splitlines(), start=1):
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        cells = _fields(line)
        try:
            values = [float(c) for c in cells]
        except ValueError:
            if header_allowed:
                header_allowed = False
                continue
            bad = next(c for c in cells if not _is_number(c))
            raise UserError(f"{what} file {path}, line {number}: {bad!r} is not a number") from None
        header_allowed = False
        if len(values) != 2:
            raise UserError(f"{what} file {path}, line {number}: expected two columns "
                            f"(wavelength in nm, value), found {len(values)}")
        if not math.isfinite(values[0]) or values[0] <= 0.0:
            raise UserError(f"{what} file {path}, line {number}: the wavelength must be a positive "
                            f"number of nm, got {cells[0]!r}")
        rows.append(values)
        lines.append(number)
    if not rows:
        raise UserError(f"{what} file {path}: no data (expected two columns: wavelength in nm, value)")
    data = np.asarray(rows, dtype=np.float64)
    lines = np.asarray(lines)
    lam = data[:, 0]
    step = np.diff(lam)
    if lam.size > 1 and np.all(step < 0):
        data, lines = data[::-1], lines[::-1]
        lam = data[:, 0]
        step = np.diff(lam)
    if np.any(step <= 0):
        i = int(np.argmax(step <= 0)) + 1
        if step[i - 1] == 0:
            raise UserError(f"{what} file {path}, line {lines[i]}: wavelength {lam[i]:g} nm repeats "
                            f"the line before (wavelengths must be strictly increasing or decreasing)")
        raise UserError(f"{what} file {path}, line {lines[i]}: wavelength {lam[i]:g} nm is out of order "
                        f"(wavelengths must be strictly increasing or decreasing)")
    return Spectrum(str(path), lam.copy(), data[:, 1].copy(), lines, what)


def _is_number(text):
    try:
        float(text)
    except ValueError:
        return False
    return True


def parse_index(text, option="--film-ior", allow_cauchy=True):
    """A dispersion model from ``N``, a material name, ``cauchy:A,B[,C]`` (λ in µm, the
    project's one unit of Cauchy coefficients) or ``cauchy-nm:A,B[,C]`` (λ in nm).

    B and C plainly in the other unit (``cauchy:1.5,4000``: B = 4000 µm²) are refused in one
    line that gives the form to write (:func:`thinfilm.core.film.cauchy_index`).

    Examples
    --------
    >>> round(float(parse_index("cauchy:1.5,0.004")(500.0)), 4)
    1.516
    >>> round(float(parse_index("cauchy-nm:1.5,4000")(500.0)), 4)
    1.516
    >>> parse_index("1.33")(600.0)
    1.33
    """
    from thinfilm.bsdf.materials import as_dispersion, named_material
    from thinfilm.core.film import cauchy_index

    text = str(text).strip()
    lowered = text.lower()
    if allow_cauchy and lowered.startswith(("cauchy:", "cauchy-nm:")):
        unit = "nm" if lowered.startswith("cauchy-nm:") else "um"
        body = text.split(":", 1)[1]
        marker, other = ("cauchy-nm", "cauchy") if unit == "nm" else ("cauchy", "cauchy-nm")
        lam = "λ in nm" if unit == "nm" else "λ in µm"
        try:
            coef = [float(c) for c in body.split(",")]
        except ValueError:
            coef = []
        if not 1 <= len(coef) <= 3 or not all(math.isfinite(c) for c in coef):
            raise UserError(f"{option}: expected {marker}:A,B[,C] with numbers (n = A + B/λ² + C/λ⁴, "
                            f"{lam}), got {text!r}")
        if coef[0] <= 0:
            raise UserError(f"{option}: the Cauchy constant A must be positive, got {coef[0]:g}")
        if not INDEX_RANGE[0] <= coef[0] <= INDEX_RANGE[1]:
            raise UserError(f"{option}: expected Cauchy constants with A from {INDEX_RANGE[0]:g} to "
                            f"{INDEX_RANGE[1]:g}, got {text!r}")
        return cauchy_index(coef, option, unit, other_form=f"for {'λ in µm' if unit == 'nm' else 'λ in nm'} "
                                                           f"write {other}:{body.strip()}")
    try:
        value = float(text)
    except ValueError:
        try:
            return named_material(text)
        except ValueError as e:
            forms = "a number, cauchy:A,B[,C] (λ in µm)" if allow_cauchy else "a number"
            raise UserError(f"{option}: {e}".replace("expected a number, n+ki,", f"expected {forms},")) from None
    if not math.isfinite(value) or value <= 0:
        raise UserError(f"{option}: the refractive index must be a positive number, got {text}")
    if not INDEX_RANGE[0] <= value <= INDEX_RANGE[1]:
        raise UserError(f"{option}: the refractive index must be from {INDEX_RANGE[0]:g} to {INDEX_RANGE[1]:g}, "
                        f"got {text}")
    return as_dispersion(value)


#: the largest spectrum file read, in bytes (its size is checked before any byte is read)
MAX_SPECTRUM_BYTES = 16 * 2**20
#: the most lines a spectrum file may have (counted while it is read, before it is parsed)
MAX_SPECTRUM_LINES = 100_000

#: refractive indices accepted, as in scene specs
INDEX_RANGE = (0.01, 100.0)
#: the thickest film searched (nm), as in scene specs
MAX_THICKNESS_NM = 1e5


# ---------------------------------------------------------------------------
# The command
# ---------------------------------------------------------------------------


def _check_options(args):
    """The options, checked before any file is read. Returns (FilmModel, wavelength range,
    thickness range)."""
    from thinfilm.reconstruction.spectrum_fit import FilmModel

    film = parse_index(args.film_ior, "--film-ior")
    substrate = parse_index(args.substrate_ior, "--substrate-ior", allow_cauchy=False)
    k3 = args.substrate_k
    if k3 is not None and not (math.isfinite(k3) and 0 <= k3 <= 100):
        raise UserError(f"--substrate-k: the extinction must be a number from 0 to 100, got {k3:g}")
    angle = float(args.angle)
    if not (math.isfinite(angle) and 0.0 <= angle < 90.0):
        raise UserError(f"--angle: the angle of incidence must be in [0, 90) degrees, got {angle:g}")
    lam_range = None
    if args.wavelength_range is not None:
        lo, hi = args.wavelength_range
        if not (math.isfinite(lo) and math.isfinite(hi) and 0 < lo < hi):
            raise UserError(f"--wavelength-range: expected MIN MAX with 0 < MIN < MAX nm, got {lo:g} {hi:g}")
        lam_range = (lo, hi)
    d_range = None
    if args.thickness_range is not None:
        lo, hi = args.thickness_range
        if not (math.isfinite(lo) and math.isfinite(hi) and 0 <= lo < hi):
            raise UserError(f"--thickness-range: expected MIN MAX with 0 <= MIN < MAX nm, got {lo:g} {hi:g}")
        if hi > MAX_THICKNESS_NM:
            raise UserError(f"--thickness-range: MAX must be at most {MAX_THICKNESS_NM:g} nm, got {hi:g}")
        d_range = (lo, hi)
    for option, value in (("--resolution", getattr(args, "resolution", None)),
                          ("--thickness-spread", getattr(args, "thickness_spread", None))):
        if value is not None and not (math.isfinite(value) and 0.0 <= value <= 1000.0):
            raise UserError(f"{option}: expected a width from 0 to 1000 nm, got {value:g}")
    return FilmModel(film, substrate, k3, angle), lam_range, d_range


def _fitted_part(spec, lam_range, min_points):
    """The samples of ``spec`` in the wavelength range, checked: enough of them, all finite."""
    keep = np.ones(spec.wavelengths_nm.size, dtype=bool)
    where = ""
    if lam_range is not None:
        keep = (spec.wavelengths_nm >= lam_range[0]) & (spec.wavelengths_nm <= lam_range[1])
        where = f" between {lam_range[0]:g} and {lam_range[1]:g} nm"
        if not np.any(keep):
            raise UserError(f"spectrum file {spec.path}: no samples{where} "
                            f"(the file covers {spec.wavelengths_nm[0]:g}-{spec.wavelengths_nm[-1]:g} nm)")
    count = int(keep.sum())
    if count < min_points:
        raise UserError(f"spectrum file {spec.path}: {count} samples{where}, at least {min_points} needed")
    bad = keep & ~np.isfinite(spec.values)
    if np.any(bad):
        line = spec.lines[np.argmax(bad)]
        raise UserError(f"spectrum file {spec.path}, line {line}: the value is not a finite number "
                        f"(NaN or infinite values are refused inside the fitted range)")
    _bounded(spec, keep)
    return spec.wavelengths_nm[keep], spec.values[keep]


def _covers(model, lam, path):
    """A database material's range must cover the fitted wavelengths (no value is extrapolated)."""
    for option, index in (("--film-ior", model.film_ior), ("--substrate-ior", model.substrate_ior)):
        if hasattr(index, "check_range"):
            try:
                index.check_range(float(lam[0]), float(lam[-1]), f"the fitted wavelengths of {path}")
            except ValueError as e:
                raise UserError(f"{option}: {e} (--wavelength-range MIN MAX narrows the fit)") from None


def _bounded(spec, keep):
    """Values in the fitted range no larger than :data:`MAX_VALUE` in magnitude."""
    from thinfilm.reconstruction.spectrum_fit import MAX_VALUE

    big = keep & (np.abs(np.nan_to_num(spec.values)) > MAX_VALUE)
    if np.any(big):
        i = int(np.argmax(big))
        raise UserError(f"{spec.what} file {spec.path}, line {spec.lines[i]}: the value {spec.values[i]:g} is "
                        f"beyond {MAX_VALUE:g} in magnitude; not a measured intensity")


def _varies(path, values, background):
    """A spectrum (less its background) that varies, and a background darker than it."""
    signal = values - (background if background is not None else 0.0)
    if np.ptp(signal) <= 1e-12 * np.max(np.abs(signal)):
        what = "less the background " if background is not None else ""
        raise UserError(f"spectrum file {path}: its {values.size} values {what}in the fitted range show no "
                        f"variation (all {signal[0]:g}): a spectrum without variation holds no thickness "
                        f"information")
    if background is not None and np.mean(signal > 0) < 0.5:
        raise UserError(f"the background is brighter than spectrum {path} at {int(np.sum(signal <= 0))} of its "
                        f"{signal.size} wavelengths (a background has no film reflection: it must be darker)")


def physical_memory():
    """Bytes of physical memory of this machine (None where the system does not say)."""
    import os

    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (AttributeError, ValueError, OSError):
        return None


def _on_grid(aux, lam, spec_path):
    """An auxiliary spectrum (background or reference) interpolated onto wavelengths ``lam``."""
    what = aux.what
    lo, hi = aux.wavelengths_nm[0], aux.wavelengths_nm[-1]
    tol = 1e-9 * hi
    if lam[0] < lo - tol or lam[-1] > hi + tol:
        raise UserError(f"{what} file {aux.path} covers {lo:g}-{hi:g} nm but spectrum {spec_path} is "
                        f"fitted over {lam[0]:g}-{lam[-1]:g} nm (narrow it with --wavelength-range)")
    # the samples interpolation uses: those in the range and the two bracketing it
    first = max(int(np.searchsorted(aux.wavelengths_nm, lam[0], side="right")) - 1, 0)
    last = min(int(np.searchsorted(aux.wavelengths_nm, lam[-1], side="left")), aux.wavelengths_nm.size - 1)
    seg = slice(first, last + 1)
    bad = ~np.isfinite(aux.values[seg])
    if np.any(bad):
        line = aux.lines[seg][np.argmax(bad)]
        raise UserError(f"{what} file {aux.path}, line {line}: the value is not a finite number "
                        f"(NaN or infinite values are refused inside the fitted range)")
    keep = np.zeros(aux.values.size, dtype=bool)
    keep[seg] = True
    _bounded(aux, keep)
    return np.interp(lam, aux.wavelengths_nm, aux.values)


def _format_row(r):
    out = {
        "path": r["path"],
        "thickness_nm": r["fit"].thickness_nm,
        "thickness_sigma_nm": r["fit"].thickness_sigma_nm,
        "film_ior": r["fit"].film_ior,
        "film_ior_wavelength_nm": r["fit"].film_ior_wavelength_nm,
    }
    if r["fit"].film_ior_sigma is not None:
        out["film_ior_sigma"] = r["fit"].film_ior_sigma
    out.update({
        "chi2": r["fit"].chi2,
        "rms_residual": r["fit"].rms_residual,
        "fringes": r["fit"].fringes,
        "n_points": r["fit"].n_points,
        "wavelength_range_nm": [float(r["lam"][0]), float(r["lam"][-1])],
        "at_bound": r["fit"].at_bound,
        "thickness_spread_nm": r["fit"].thickness_spread_nm,
        "resolution_nm": r["fit"].resolution_nm,
        "runner_up_thickness_nm": r["fit"].runner_up_thickness_nm,
        "runner_up_chi2": r["fit"].runner_up_chi2,
        "runner_up_delta_bic": r["fit"].runner_up_delta_bic,
    })
    return {k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in out.items()}


def _table(rows, fit_ior):
    """A readable table, one row per spectrum."""
    def num(v, fmt):
        return "-" if v is None or not math.isfinite(v) else format(v, fmt)

    head = ["spectrum", "thickness_nm", "sigma_nm"]
    if fit_ior:
        head += ["film_ior", "sigma"]
    head += ["chi2", "rms_residual", "fringes", "runner_up_nm", "its_chi2", "note"]
    body = []
    for r in rows:
        f = r["fit"]
        cells = [r["path"], num(f.thickness_nm, ".2f"), num(f.thickness_sigma_nm, ".2g")]
        if fit_ior:
            cells += [num(f.film_ior, ".4f"), num(f.film_ior_sigma, ".2g")]
        cells += [num(f.chi2, ".3g"), num(f.rms_residual, ".3g"), num(f.fringes, ".1f"),
                  num(f.runner_up_thickness_nm, ".2f"), num(f.runner_up_chi2, ".3g"),
                  "at the end of --thickness-range" if f.at_bound else ""]
        body.append(cells)
    widths = [max(len(str(x[i])) for x in [head] + body) for i in range(len(head))]
    lines = []
    for cells in [head] + body:
        text = "  ".join(str(c).ljust(w) if i in (0, len(head) - 1) else str(c).rjust(w)
                         for i, (c, w) in enumerate(zip(cells, widths)))
        lines.append(text.rstrip())
    if fit_ior and rows:
        lines.append(f"(film_ior at {rows[0]['fit'].film_ior_wavelength_nm:.0f} nm, the middle of the fitted range)")
    return "\n".join(lines)


def cli_main(args):
    """Run ``thinfilm fit-spectrum`` (arguments as declared in :mod:`thinfilm.cli`)."""
    from thinfilm.reconstruction.spectrum_fit import MIN_POINTS, fit_spectra

    model, lam_range, d_range = _check_options(args)

    # every input first; one line per bad file, nothing fitted if any is bad
    errors = []
    aux = {}
    for what, path in (("background", args.background), ("reference", args.reference)):
        if path is None:
            continue
        try:
            aux[what] = read_spectrum(path, what)
        except UserError as e:
            errors.append(str(e))
    prepared = []
    for path in args.spectra:
        try:
            spec = read_spectrum(path)
            lam, values = _fitted_part(spec, lam_range, MIN_POINTS)
            _covers(model, lam, spec.path)
            extra = {what: _on_grid(a, lam, path) for what, a in aux.items()}
            if "reference" in extra:
                level = extra["reference"] - extra.get("background", 0.0)
                if not np.all(level > 0):
                    at = lam[np.argmax(~(level > 0))]
                    raise UserError(f"reference file {aux['reference'].path} is not above "
                                    f"{'the background' if 'background' in extra else 'zero'} at {at:g} nm "
                                    f"(a white reference must be brighter than the dark level)")
            n2 = model.film_ior(lam)
            if not np.all(np.asarray(n2) > 0):
                raise UserError(f"--film-ior: the index is not positive over {path}'s fitted range "
                                f"{lam[0]:g}-{lam[-1]:g} nm")
            _varies(path, values, extra.get("background"))
            prepared.append({"path": path, "lam": lam, "values": values, **extra})
        except UserError as e:
            errors.append(str(e))
    if errors:
        for message in errors:
            print(f"thinfilm: error: {message}", file=sys.stderr)
        return 2

    # spectra sharing a wavelength grid: one batch
    groups = {}
    for i, r in enumerate(prepared):
        groups.setdefault((r["lam"].size, r["lam"].tobytes()), []).append(i)
    from thinfilm.reconstruction.spectrum_fit import estimated_memory_bytes

    have = physical_memory()
    for members in groups.values():
        first = prepared[members[0]]
        need = estimated_memory_bytes(first["lam"], model, d_range, len(members))
        if have and need > have:
            print(f"thinfilm: error: spectrum file {first['path']}: fitting {first['lam'].size} samples needs about "
                  f"{need / 2**30:.1f} GiB of memory, this machine has {have / 2**30:.1f} GiB (narrow "
                  f"--wavelength-range or resample the spectrum)", file=sys.stderr)
            return 2
    for members in groups.values():
        first = prepared[members[0]]
        fits = fit_spectra(first["lam"], np.stack([prepared[i]["values"] for i in members]), model,
                           background=first.get("background"), reference=first.get("reference"),
                           thickness_range_nm=d_range, fit_film_ior=args.fit_film_ior,
                           thickness_spread_nm=getattr(args, "thickness_spread", None),
                           resolution_nm=getattr(args, "resolution", None))
        for i, f in zip(members, fits):
            prepared[i]["fit"] = f

    if args.json:
        for r in prepared:
            print(json.dumps(_format_row(r)))
    else:
        print(_table(prepared, args.fit_film_ior))
    return 0
