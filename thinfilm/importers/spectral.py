"""``thinfilm import spectral``: hyperspectral cubes → a dataset folder.

Cubes are ENVI files (a ``.hdr`` header and its data file, read with the ``spectral`` package,
SPy; the header's ``wavelength`` list, in nm or µm, gives the bands) or TIFF files whose pages
(or samples) are the bands, with ``--wavelengths`` (``START:STOP:STEP``, a comma-separated list
or a text file). ``--wavelengths`` also overrides an ENVI header's list (it must have as many
entries as the cube has bands). Bands in decreasing order are reversed.

Counts become reflectance with reference measurements of the same camera:
``R = ρ_w (cube − dark) / (white − dark)``, where ``--white`` is a cube of the same shape (per
pixel) or a spectrum (a 1 × 1 cube, or a CSV ``wavelength_nm, counts``), ``--dark`` likewise or
a number, and ``ρ_w`` the white target's reflectance ``--white-reflectance`` (a number or a CSV
spectrum, default 1). Without ``--white`` the counts stay relative (``meta.json`` says so, a
warning is printed).

``--polarizer`` says what the cubes are:

``s`` (default)
    One cube taken behind a polarizer along the s-direction, the white reference behind the
    same polarizer: the result is the s-polarized reflectance ``spectral_s``.
``stokes``
    Three or more cubes behind polarizers at ``--angles`` (default 0,45,90,135; one per cube,
    in order), the white reference behind any of them (it is unpolarized). In reflectance units
    each cube is the intensity behind its polarizer, ``I(α) = ½ ρ_w (cube − dark) / (white −
    dark)``; the least-squares Stokes fit gives ``stokes_spectral.exr`` and ``spectral_s =
    S0 + sqrt(S1² + S2²)``, as the generator's hyperspectral camera does.

Calibration: ``--flat`` (with a ``--white`` spectrum; a cube of a uniform field of the cubes'
shape, or one image for every band) divides each pixel by its response relative to the band's
mean, dark subtracted. ``--polarizer-extinction`` and ``--polarizer-offset`` (the polarizers'
measured extinction ratio and axis offset; one number, one per cube or a text file) are
recorded in ``meta.json``; with ``stokes`` the Stokes cube is fitted through the real analyzer
(:func:`thinfilm.core.conventions.analyzer_matrix`), so the captures are those of ideal
polarizers; a single ``s`` cube cannot be corrected (``S0 + D P cos 2δ`` needs ``S0`` and
``P`` apart): the import and every estimator reading the dataset warn. A negative or
non-finite dark, a flat field at or below the dark level anywhere, or shapes that differ stop
the import with one line.

Integer cubes: samples at or above ``--saturation`` (default: the largest value of the data
type) invalidate their pixel (``valid.exr``), as do pixels where ``white ≤ dark``.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np

from thinfilm.core.dataset import POLARIZER_NOT_CORRECTED
from thinfilm.core.errors import ThinfilmWarning, UserError
from thinfilm.core.extras import require_extra

from .common import (POLARIZER_CORRECTED, check_dark_values, csv_records, file_record, film_fields, import_meta,
                     input_files, parse_angles, parse_numbers, parse_wavelengths, polarizer_calibration,
                     read_spectrum_csv, reference_reflectance, warn_relative_units)

__all__ = ["POLARIZERS", "read_cube", "import_spectral", "cli_main"]

POLARIZERS = ("s", "stokes")


class _Cube:
    """A cube read from its files: ``path`` names it in messages (the ``.hdr`` of an ENVI cube),
    ``files`` are every file it was read from (an ENVI cube's header and data file)."""

    def __init__(self, data, wavelengths, fwhm, path, int_max, files=None):
        self.data, self.wavelengths, self.fwhm, self.path, self.int_max = data, wavelengths, fwhm, path, int_max
        self.files = list(files) if files is not None else [path]

    def records(self, role: str) -> list:
        """The provenance of every file of the cube (:func:`file_record`): the header of an ENVI
        cube as ``"<role> header"``, its data file (or a TIFF file) as ``role``."""
        if len(self.files) == 1:
            return [file_record(self.files[0], role)]
        return [file_record(self.files[0], f"{role} header")] + [file_record(f, role) for f in self.files[1:]]


def _envi_header(p: Path):
    if p.suffix.lower() == ".hdr":
        return p
    for cand in (p.with_suffix(".hdr"), Path(str(p) + ".hdr")):
        if cand.is_file():
            return cand
    return None


def _envi_wavelengths(meta: dict, hdr: Path):
    wl = meta.get("wavelength")
    if not wl:
        return None
    try:
        values = np.asarray([float(v) for v in wl], dtype=np.float64)
    except (TypeError, ValueError):
        raise UserError(f"{hdr}: 'wavelength' holds something other than numbers") from None
    units = str(meta.get("wavelength units", "")).strip().lower()
    if units in ("nm", "nanometers", "nanometer", "nanometres", "nanometre"):
        return values
    if units in ("um", "µm", "micrometers", "micrometer", "micrometres", "micrometre", "microns", "micron"):
        return values * 1000.0
    if units in ("", "unknown"):
        return values if np.median(values) > 100 else values * 1000.0   # nm, else µm
    raise UserError(f"{hdr}: 'wavelength units' is {meta.get('wavelength units')!r}; expected nm or µm "
                    f"(or give --wavelengths)")


def read_cube(path, what: str = "cube") -> _Cube:
    """Read an ENVI or TIFF cube as (H, W, B) float64 with its header wavelengths (or None)."""
    from thinfilm.core.files import open_regular

    p = Path(path).expanduser()
    with open_regular(p, f"{what} file") as f:
        head = f.read(4)
    is_tiff = head in (b"II*\x00", b"MM\x00*", b"II+\x00", b"MM\x00+")
    hdr = None if is_tiff else _envi_header(p)
    if hdr is not None:
        envi = require_extra("spectral.io.envi", "import", what=f"{hdr}: reading an ENVI {what}")

        try:
            img = envi.open(str(hdr.resolve()), None if p.suffix.lower() == ".hdr" else str(p.resolve()))
            data = np.array(img.asarray())
            meta = img.metadata
            files = [hdr, Path(img.filename)]
        except UserError:
            raise
        except Exception as e:  # SPy raises its own exception types for bad headers/missing data
            raise UserError(f"{hdr}: cannot read the ENVI {what} ({' '.join(str(e).split())[:200]})") from None
        wl = _envi_wavelengths(meta, hdr)
        fwhm = meta.get("fwhm")
        try:
            fwhm = None if not fwhm else float(np.median([float(v) for v in fwhm]))
        except (TypeError, ValueError):
            fwhm = None
        if fwhm is not None and wl is not None and np.median(wl) > 100 and fwhm < 1 and \
                str(meta.get("wavelength units", "")).lower() in ("um", "µm", "micrometers", "microns"):
            fwhm *= 1000.0
        source = hdr
    else:
        if not is_tiff:
            raise UserError(f"{p}: the {what} is neither an ENVI file (no .hdr beside it) nor a TIFF file")
        tifffile = require_extra("tifffile", "import", what=f"{p}: reading a TIFF {what}")
        try:
            with tifffile.TiffFile(p) as tif:
                series = tif.series[0]
                data = series.asarray()
                axes = series.axes
        except Exception as e:
            raise UserError(f"{p}: cannot read the TIFF {what} ({' '.join(str(e).split())[:200]})") from None
        data = np.asarray(data)
        if data.ndim == 2:
            raise UserError(f"{p}: the TIFF {what} holds one band; expected one page (or sample) per band")
        if data.ndim != 3:
            raise UserError(f"{p}: the TIFF {what} has shape {data.shape} (axes {axes}); expected 3 axes")
        if axes.endswith("YX"):                      # pages (or planar samples) are bands
            data = np.moveaxis(data, 0, -1)
        wl, fwhm, source = None, None, p
        files = [p]
    if data.dtype.kind not in "uif":
        raise UserError(f"{source}: the {what} has {data.dtype} samples; expected numbers")
    int_max = float(np.iinfo(data.dtype).max) if data.dtype.kind in "ui" else None
    data = data.astype(np.float64)
    if data.ndim != 3 or data.shape[2] < 2:
        raise UserError(f"{source}: the {what} has shape {data.shape}; expected (rows, columns, bands) with 2 or "
                        f"more bands")
    if not np.all(np.isfinite(data)):
        raise UserError(f"{source}: the {what} contains NaN or infinite values")
    return _Cube(data, wl, fwhm, source, int_max, files)


def _reference(spec, what, shape, wavelengths, order):
    """A dark or white reference: (H, W, B) cube or (B,) spectrum, bands in the cubes' order,
    and the level given (a number) or the provenance records of every file read (a list)."""
    try:
        level = float(spec)
    except (TypeError, ValueError):
        level = None
    if level is not None:
        if what == "--white":
            raise UserError(f"--white: expected a cube or a spectrum file, got the number {spec!r}")
        if not np.isfinite(level) or level < 0:
            raise UserError(f"{what}: expected a finite number >= 0, got {spec!r}")
        return np.full(shape[2], level), level
    p = Path(spec).expanduser()
    if p.suffix.lower() == ".csv":
        rw, rv = read_spectrum_csv(p, what)
        if rw[0] > wavelengths[0] + 1e-6 or rw[-1] < wavelengths[-1] - 1e-6:
            raise UserError(f"{what}: {p}: covers {rw[0]:g}-{rw[-1]:g} nm, not the bands "
                            f"{wavelengths[0]:g}-{wavelengths[-1]:g} nm")
        values = np.interp(wavelengths, rw, rv)
        if what == "--dark":
            check_dark_values(values, f"{what}: {p}")
        return values, [file_record(p, what.strip("-"))]
    ref = read_cube(p, what.strip("-") + " reference")
    data = ref.data[..., order]
    if what == "--dark":
        check_dark_values(data, f"{ref.path}: the --dark reference")
    if data.shape == shape:
        return data, ref.records(what.strip("-"))
    if data.shape[:2] == (1, 1) and data.shape[2] == shape[2]:
        return data[0, 0], ref.records(what.strip("-"))
    raise UserError(f"{ref.path}: the {what} reference has shape {data.shape}; expected the cube's {shape} "
                    f"or a 1 x 1 x {shape[2]} spectrum")


def import_spectral(cubes, out, wavelengths=None, white=None, dark=None, white_reflectance="1", polarizer="s",
                    angles=None, saturation=None, band_fwhm=None, film_ior=None, substrate_ior=None,
                    pixel_size=None, flat=None, polarizer_extinction=None, polarizer_offset=None) -> dict:
    """Import hyperspectral cubes into a dataset folder ``out`` (see the module docstring).
    Returns a summary (``shape``, ``bands``, ``valid_pixels``, ``units``, ``path``)."""
    from thinfilm.core.conventions import fit_stokes, s_polarized
    from thinfilm.core.io import write_dataset
    from thinfilm.core.outputs import atomic_output_dir, check_output_dir

    if polarizer not in POLARIZERS:
        raise UserError(f"--polarizer: expected one of {', '.join(POLARIZERS)}, got {polarizer!r}")
    if not cubes:
        raise UserError("give at least one cube")
    if polarizer == "s":
        if angles is not None:
            raise UserError("--angles applies to --polarizer stokes")
        if len(cubes) != 1:
            raise UserError(f"--polarizer s takes one cube, got {len(cubes)} (cubes behind several polarizers: "
                            f"--polarizer stokes)")
        angle_list = None
    else:
        angle_list = parse_angles(angles if angles is not None else
                                  ("0,45,90,135" if len(cubes) == 4 else _need_angles(len(cubes))))
        if len(angle_list) != len(cubes):
            raise UserError(f"--angles: {len(angle_list)} angles for {len(cubes)} cubes")
    if band_fwhm is not None and not (np.isfinite(band_fwhm) and band_fwhm >= 0):
        raise UserError(f"--band-fwhm: expected a number of nm >= 0, got {band_fwhm}")
    if pixel_size is not None and not (np.isfinite(pixel_size) and pixel_size > 0):
        raise UserError(f"--pixel-size: expected a number > 0, got {pixel_size}")
    pol_entry, pol_records = polarizer_calibration(polarizer_extinction, polarizer_offset,
                                                   angle_list if angle_list is not None else [0])
    meta_film = film_fields(film_ior, substrate_ior)
    in_files = input_files(*cubes, white, dark, white_reflectance, flat, polarizer_extinction, polarizer_offset)
    out = check_output_dir(out, command="import spectral", inputs=in_files)
    # the lock of --out is held from here to the end: a second writer stops at once
    with atomic_output_dir(out, command="import spectral", inputs=in_files) as tmp:
        read = [read_cube(c) for c in cubes]
        first = read[0]
        for cube in read[1:]:
            if cube.data.shape != first.data.shape:
                raise UserError(f"{cube.path}: shape {cube.data.shape} differs from {first.path.name}'s {first.data.shape}")
        bands = first.data.shape[2]
        if wavelengths is not None:
            wl = parse_wavelengths(wavelengths)
            if wl.size != bands:
                raise UserError(f"--wavelengths: {wl.size} wavelengths for {bands} bands in {first.path}")
            order = np.arange(bands)
        else:
            if first.wavelengths is None:
                raise UserError(f"{first.path}: no wavelengths (an ENVI header without 'wavelength', or a TIFF); "
                                f"give --wavelengths")
            for cube in read[1:]:
                if cube.wavelengths is None or not np.allclose(cube.wavelengths, first.wavelengths):
                    raise UserError(f"{cube.path}: its wavelengths differ from {first.path.name}'s")
            wl = first.wavelengths
            if wl.size != bands:
                raise UserError(f"{first.path}: the header lists {wl.size} wavelengths for {bands} bands")
            order = np.argsort(wl)
            wl = wl[order]
            if not np.all(np.isfinite(wl)) or np.any(wl <= 0) or np.any(np.diff(wl) <= 0):
                raise UserError(f"{first.path}: the header's wavelengths must be distinct positive numbers")
        data = [c.data[..., order] for c in read]
        shape = data[0].shape

        if saturation is not None:
            sat_level = parse_numbers(saturation, "--saturation", 1)[0]
        else:
            sat_level = first.int_max
        saturated = np.zeros(shape[:2], dtype=bool)
        if sat_level is not None:
            for d in data:
                saturated |= np.any(d >= sat_level, axis=-1)

        inputs = [rec for c in read for rec in c.records("cube")]
        calib = {"saturation_level": sat_level}
        d_ref, calib["dark"] = (0.0, None) if dark is None else _reference(dark, "--dark", shape, wl, order)
        if isinstance(calib["dark"], list):
            inputs += calib["dark"]
            calib["dark"] = calib["dark"][-1]
        bad = np.zeros(shape[:2], dtype=bool)
        if white is not None:
            w_ref, recs = _reference(white, "--white", shape, wl, order)
            inputs += recs
            calib["white"] = recs[-1]
            span = w_ref - d_ref
            if np.ndim(span) == 1:
                if np.any(span <= 0):
                    raise UserError(f"--white: the white reference is not above the dark level at "
                                    f"{wl[int(np.argmin(span))]:g} nm")
            else:
                low = np.any(span <= 0, axis=-1)
                if low.all():
                    raise UserError("--white: the white reference is not above the dark level anywhere")
                bad |= low
                span = np.where(span > 0, span, 1.0)
            rho = reference_reflectance(white_reflectance, "--white-reflectance", wl)
            calib["white_reflectance"] = str(white_reflectance)
            inputs += csv_records(white_reflectance, "white reflectance")
            scale = rho / span
            units = "reflectance"
        else:
            scale = 1.0
            units = "relative"
            warn_relative_units("spectra")
        if flat is not None:
            if white is not None and np.ndim(w_ref) == 3:
                raise UserError("--flat: the --white reference is a cube of the same shape, which corrects each "
                                "pixel's response already; give a --white spectrum with --flat, or no --flat")
            rel, recs = _flat_field(flat, shape, d_ref, order)
            inputs += recs
            calib["flat"] = recs[-1]
            scale = scale / rel
        calibrated = [(d - d_ref) * scale for d in data]

        stokes = None
        if polarizer == "s":
            spectral_s = calibrated[0]
            if pol_entry is not None:
                # one cube cannot be corrected: S0 + D P cos 2(offset) needs S0 and P apart
                entry = {k: v[0] if isinstance(v, list) else v for k, v in pol_entry.items()}
                entry["angles_deg"] = "s-direction"
                calib["polarizer"] = dict(entry, correction=POLARIZER_NOT_CORRECTED)
                warnings.warn(f"{first.path}: a single s-polarized cube cannot be corrected for the polarizer's "
                              f"extinction or axis offset; they are recorded in meta.json, and the estimators, "
                              f"which model an ideal polarizer, warn", ThinfilmWarning, stacklevel=2)
        else:
            intensity = 0.5 * np.stack(calibrated)          # behind each polarizer, reflectance units
            if pol_entry is None:
                S0, S1, S2 = fit_stokes(intensity, angle_list)
            else:   # the Stokes cube through the real analyzer (extinction, axis offsets)
                from thinfilm.core.conventions import analyzer_matrix, stokes_design_matrix

                real = analyzer_matrix(angle_list, pol_entry["extinction_ratio"], pol_entry["angle_offset_deg"])
                S0, S1, S2 = np.tensordot(np.linalg.pinv(real), intensity, axes=(1, 0))
                ideal = stokes_design_matrix(angle_list)
                gain = float(np.sqrt(np.max(np.diag(np.linalg.inv(real.T @ real))[1:]
                                            / np.diag(np.linalg.inv(ideal.T @ ideal))[1:])))
                calib["polarizer"] = dict(pol_entry, correction=POLARIZER_CORRECTED, noise_gain_s1_s2=gain)
            stokes = {"S0": S0, "S1": S1, "S2": S2}
            spectral_s = s_polarized(S0, S1, S2)
        valid = ~saturated & ~bad
        if not valid.any():
            raise UserError(f"{first.path}: no pixel is usable (saturated, or white not above dark, everywhere)")

        fwhm = band_fwhm if band_fwhm is not None else first.fwhm
        fields = dict(
            wavelengths_nm=[float(v) for v in wl],
            **({"band_fwhm_nm": float(fwhm)} if fwhm is not None else {}),
            polarizer=polarizer,
            **({"cube_polarizer_angles_deg": [int(a) for a in angle_list]} if angle_list else {}),
            **meta_film,
            **({"projection": {"pixel_size": float(pixel_size)}} if pixel_size is not None else {}),
            saturated_pixels=int(saturated.sum()),
            valid_pixels=int(valid.sum()),
        )
        inputs += pol_records
        meta = import_meta("spectral", inputs, units, calib, **fields)
        write_dataset(tmp, meta, spectral_s=np.asarray(spectral_s, dtype=np.float32),
                      stokes=None if stokes is None else {k: np.asarray(v, dtype=np.float32) for k, v in stokes.items()},
                      valid=valid)
    return {"path": out, "shape": shape[:2], "bands": int(shape[2]), "valid_pixels": int(valid.sum()),
            "saturated_pixels": int(saturated.sum()), "units": units, "meta": meta, "spectral_s": spectral_s,
            "stokes": stokes, "valid": valid}


def _flat_field(spec, shape, d_ref, order):
    """``--flat``: a cube of a uniform field of the cubes' shape, or one image (H, W) for every
    band; dark subtracted, each band relative to its mean. Returns ((H, W, B), records)."""
    from .images import read_image

    p = Path(spec).expanduser()
    try:
        cube = read_cube(p, "flat field")
        data, recs, where = cube.data[..., order], cube.records("flat"), cube.path
    except UserError as e:
        if "holds one band" not in str(e) and "neither an ENVI" not in str(e):
            raise
        img = read_image(p, "--flat image")
        if img.data.ndim != 2:
            raise UserError(f"{img.path}: the --flat image must have one channel, it has shape {img.data.shape}") from None
        data, recs, where = np.repeat(img.data.astype(np.float64)[..., None], shape[2], axis=-1), \
            [file_record(img.path, "flat")], img.path
    if data.shape != shape:
        raise UserError(f"{where}: the --flat field has shape {data.shape}; expected the cube's {shape} (or an "
                        f"image of {shape[0]} x {shape[1]})")
    f = data - d_ref
    low = ~(f > 0)
    if low.any():
        r, c, b = np.argwhere(low)[0]
        raise UserError(f"{where}: the --flat field is at or below the dark level at {int(low.sum())} samples, the "
                        f"first at row {r}, column {c}, band {b}; a flat field must be positive everywhere")
    return f / f.mean(axis=(0, 1)), recs


def _need_angles(n):
    raise UserError(f"--polarizer stokes with {n} cubes needs --angles, one polarizer angle per cube")


def cli_main(args) -> int:
    """``thinfilm import spectral CUBE... --out DIR [...]``."""
    s = import_spectral(args.cubes, args.out, wavelengths=args.wavelengths, white=args.white, dark=args.dark,
                        white_reflectance=args.white_reflectance, polarizer=args.polarizer, angles=args.angles,
                        saturation=args.saturation, band_fwhm=args.band_fwhm, film_ior=args.film_ior,
                        substrate_ior=args.substrate_ior, pixel_size=args.pixel_size, flat=args.flat,
                        polarizer_extinction=args.polarizer_extinction, polarizer_offset=args.polarizer_offset)
    h, w = s["shape"]
    print(f"wrote {s['path']} ({w}x{h}, {s['bands']} bands, polarizer {args.polarizer}; {s['valid_pixels']} valid "
          f"pixels, {s['saturated_pixels']} saturated; units {s['units']})")
    return 0
