"""``thinfilm import polarization``: polarization-camera captures → a dataset folder.

Two layouts (``--layout``):

``separate``
    One RGB image per polarizer angle (a camera behind a rotated polarizer), ``--angles`` in
    the order of the files, three or more angles distinct modulo 180°.
``dofp-rgb``
    The raw image of a colour division-of-focal-plane sensor: each pixel behind one colour
    filter and one polarizer, in the pattern of ``--pattern`` (default: Sony IMX250MYR, see
    :mod:`thinfilm.core.mosaic` for the diagram and the notation). Several raw frames of the
    same scene are averaged. Demosaicing (``--demosaic``, :mod:`thinfilm.importers.demosaic`):
    ``residual`` (default), polarization- and colour-aware residual interpolation that
    interpolates the object and the background each from its own samples (the object's
    pixels: ``--mask IMAGE``, nonzero on the object, or found on the mosaic when it shows a
    lit object before a dark background; the object's outermost ``--edge-margin`` pixels,
    default :data:`thinfilm.importers.demosaic.DEFAULT_EDGE_MARGIN`, are marked invalid), or
    ``bilinear`` per plane; both float64 and exact at the sampled pixels.

Calibration, in this order, on the raw values of every image (and of the reference images);
bad calibration input (a shape that differs from the images', a negative or non-finite dark, a
flat field at or below the dark level anywhere, an extinction ratio outside [0, 1)) stops the
import with one line:

1. saturation: a sample at or above ``--saturation`` (default: within 0.2 % of the largest code
   of the bit depth, ``2^bits − 1``) invalidates its pixel (with ``dofp-rgb``: every pixel whose
   interpolation used it);
2. dark: ``--dark FILE`` (a dark frame of the same shape) or ``--dark LEVEL`` (digital numbers)
   is subtracted;
3. normalization by the bit depth: ``(raw − dark) / (2^bits − 1)``, in [0, 1] (floating-point
   TIFFs are taken as normalized already);
4. flat field: ``--flat FILE`` (an image of a uniform, unpolarized field, same shape; dark
   subtracted too) divides each pixel by its response relative to the mean of its colour and
   angle (``dofp-rgb``) or of its channel (``separate``);
5. polarizers (after the demosaicing, ``dofp-rgb``): ``--polarizer-extinction E`` (the measured
   extinction ratio, minimum over maximum transmittance) and ``--polarizer-offset DEG`` (the
   measured axis minus the nominal angle), each one number, one per angle (in the order of
   ``--angles``, or of the pattern's sorted angles) or a text file of them: per pixel the
   Stokes vector is fitted through the real analyzer
   (:func:`thinfilm.core.conventions.analyzer_matrix`) and the images are corrected to those
   of ideal polarizers at the nominal angles, which the reconstruction's model assumes;
   ``meta.json`` records the values and the factor by which the correction multiplies the
   noise of S1, S2;
6. white balance to reflectance units, where a perfect mirror seen without a polarizer gives
   (1, 1, 1) and unpolarized white behind an ideal polarizer 0.5:
   ``--white-balance R,G,B`` multiplies each colour by a gain; or ``--white-reference IMAGE``,
   an image of a diffuse reference target (unpolarized, seen through the polarizers like the
   captures) of reflectance ``--white-reflectance`` (a number or a CSV spectrum, default 1),
   gives the gains ``½ ρ_c / median_c`` (ρ_c: the camera RGB of the reflectance, the median over
   the reference's unsaturated pixels of colour c). Without either, the images are in relative
   units: ``meta.json`` says so and a warning is printed.

Values must be linear in the light (raw data, or raw-developed without gamma or tone curve).
The dataset holds ``polarized_rgb.exr`` (float32), ``valid.exr`` (pixels free of saturation and,
with ``dofp-rgb --demosaic bilinear``, off the object's silhouette, see
:func:`thinfilm.importers.demosaic.edge_pixels`; the reconstructions use only these), ``meta.json`` (``source = "imported"``, the inputs with
their SHA-256, the calibration, ``camera`` and ``illuminant`` when given, ``wavelengths_nm``
for the forward models) and ``preview.png``; no ground truth.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np

from thinfilm.core.errors import ThinfilmWarning, UserError

from .common import (DEFAULT_WAVELENGTHS, POLARIZER_CORRECTED, check_dark_values, correct_polarizers, csv_records,
                     file_record, film_fields, import_meta, input_files, parse_angles, parse_numbers, parse_wavelengths,
                     polarizer_calibration, reference_reflectance, warn_relative_units)
from .images import apply_bit_depth, read_image

__all__ = ["LAYOUTS", "SATURATION_MARGIN", "import_polarization", "cli_main"]

LAYOUTS = ("separate", "dofp-rgb")
#: Default saturation level: samples within this fraction of the largest code are saturated.
SATURATION_MARGIN = 0.002


def _colour_model(camera, illuminant, wavelengths):
    """Check the camera and illuminant (names or CSV paths) over the bands; CSV paths are made
    absolute, as the forward models read them later."""
    from thinfilm.core.colorimetry import DEFAULT_CAMERA, DEFAULT_ILLUMINANT, camera_weights

    def norm(value):
        if value is None:
            return None
        if str(value).lower().endswith(".csv"):
            p = Path(value).expanduser().resolve()
            if not p.is_file():
                raise UserError(f"{value}: CSV file not found")
            return str(p)
        return str(value)

    camera, illuminant = norm(camera), norm(illuminant)
    camera_weights(wavelengths, camera or DEFAULT_CAMERA, illuminant or DEFAULT_ILLUMINANT)
    return camera, illuminant


class _Calibration:
    """Raw values → normalized, dark-subtracted, flat-fielded values (steps 1–4)."""

    def __init__(self, bits, shape, dark, flat, saturation, index_map, is_float):
        self.bits, self.shape, self.is_float = bits, shape, is_float
        self.max_code = None if is_float else float(2 ** bits - 1)
        self.index_map = index_map          # (H, W[, 3]) class of each value for the flat field
        self.dark = self._dark(dark)
        self.saturation = self._saturation(saturation)
        self.flat, self.bad_flat = self._flat(flat)

    def _read(self, path, what):
        img = read_image(path, what)
        if img.is_float != self.is_float:
            raise UserError(f"{img.path}: the {what} is {'float' if img.is_float else 'integer'} data but the "
                            f"images are {'float' if self.is_float else 'integer'} data")
        if not img.is_float:
            img = apply_bit_depth(img, self.bits, "the bit depth of the images")
        if img.data.shape != self.shape:
            raise UserError(f"{img.path}: the {what} has shape {img.data.shape}, the images {self.shape}")
        return img

    def _dark(self, dark):
        self.dark_record = None
        if dark is None:
            return 0.0
        try:
            level = float(dark)
        except ValueError:
            level = None
        if level is not None:
            if not np.isfinite(level) or level < 0:
                raise UserError(f"--dark: a dark level must be a number >= 0, got {dark!r}")
            if self.max_code is not None and level >= self.max_code:
                raise UserError(f"--dark: level {level:g} is not below the largest code {self.max_code:g}")
            self.dark_record = level
            return level
        img = self._read(dark, "--dark frame")
        check_dark_values(img.data, f"{img.path}: the --dark frame")
        self.dark_record = file_record(img.path, "dark")
        return img.data.astype(np.float64)

    def _saturation(self, saturation):
        if saturation is not None:
            value = parse_numbers(saturation, "--saturation", 1)[0]
            if value <= 0:
                raise UserError(f"--saturation: expected a level > 0, got {saturation!r}")
            return value
        if self.max_code is None:
            return None
        return float(np.floor(self.max_code * (1.0 - SATURATION_MARGIN)))

    def normalize(self, data):
        """(saturated, normalized values)."""
        data = np.asarray(data, dtype=np.float64)
        sat = np.zeros(data.shape, dtype=bool) if self.saturation is None else data >= self.saturation
        x = data - self.dark
        if self.max_code is not None:
            x /= self.max_code
        return sat, x

    def _flat(self, flat):
        self.flat_record = None
        if flat is None:
            return None, None
        img = self._read(flat, "--flat field")
        self.flat_record = file_record(img.path, "flat")
        sat, x = self.normalize(img.data)
        good = (x > 0) & ~sat
        if not good.any():
            raise UserError(f"{img.path}: the --flat field is at or below the dark level (or saturated) everywhere")
        if not good.all():
            r, c = np.argwhere(~good)[0][:2]
            raise UserError(f"{img.path}: the --flat field is at or below the dark level (or saturated) at "
                            f"{int((~good).sum())} samples, the first at row {r}, column {c}; a flat field must be "
                            f"positive everywhere")
        rel = np.ones_like(x)
        for k in np.unique(self.index_map):
            sel = self.index_map == k
            ok = sel & good
            if not ok.any():
                raise UserError(f"{img.path}: the --flat field has no usable pixel for one colour/angle class")
            rel[sel] = x[sel] / x[ok].mean()
        bad = ~good
        return np.where(bad, 1.0, rel), bad

    def apply(self, data):
        sat, x = self.normalize(data)
        if self.flat is not None:
            x = x / self.flat
        return sat, x

    def record(self) -> dict:
        return {"dark": self.dark_record, "flat": self.flat_record,
                "normalization": ("(raw - dark) / (2^bits - 1)" if self.max_code is not None
                                  else "floating-point samples taken as normalized"),
                "bit_depth": self.bits, "saturation_level": self.saturation}


def _read_mask(path, shape):
    """``--mask``: an image of the mosaic's shape, nonzero on the object."""
    img = read_image(path, "--mask image")
    data = img.data if img.data.ndim == 2 else img.data.max(axis=-1)
    if data.shape != tuple(shape):
        raise UserError(f"{img.path}: the --mask image has shape {data.shape}, the mosaic {tuple(shape)}")
    obj = data > 0
    if not obj.any():
        raise UserError(f"{img.path}: the --mask image is zero everywhere (no object)")
    return obj


def _read_inputs(paths, layout, bit_depth):
    if not paths:
        raise UserError("give at least one image")
    imgs = []
    for p in paths:
        img = read_image(p, "image")
        if bit_depth is not None:
            if img.is_float:
                raise UserError(f"{img.path}: --bit-depth applies to integer images, this one holds floats")
            img = apply_bit_depth(img, bit_depth)
        imgs.append(img)
    first = imgs[0]
    for img in imgs[1:]:
        if img.data.shape != first.data.shape:
            raise UserError(f"{img.path}: shape {img.data.shape} differs from {first.path.name}'s {first.data.shape}")
        if img.bits != first.bits:
            what = lambda i: "float" if i.is_float else f"{i.bits}-bit"  # noqa: E731
            raise UserError(f"{img.path}: {what(img)} samples, but {first.path.name} holds {what(first)} samples")
    shape = first.data.shape
    if layout == "separate" and (len(shape) != 3 or shape[-1] != 3):
        raise UserError(f"{first.path}: --layout separate needs RGB images, this one has shape {shape}")
    if layout == "dofp-rgb" and len(shape) != 2:
        raise UserError(f"{first.path}: a raw mosaic (--layout dofp-rgb) has one channel, this image has shape "
                        f"{shape}; for demosaiced RGB images use --layout separate")
    if bit_depth is None and not first.is_float and first.container_bits == 16:
        top = max(int(i.data.max()) for i in imgs)
        if top < 2 ** 12:
            warnings.warn(f"{first.path}: 16-bit samples that never exceed {top}: if the camera delivers 10- or "
                          f"12-bit values, give --bit-depth (the values are normalized by 2^16 - 1 now)",
                          ThinfilmWarning, stacklevel=3)
    return imgs


def import_polarization(images, out, layout, angles=None, pattern=None, bit_depth=None, dark=None, flat=None,
                        white_balance=None, white_reference=None, white_reflectance="1", camera=None,
                        illuminant=None, wavelengths=None, saturation=None, keep_edges=False, film_ior=None,
                        substrate_ior=None, pixel_size=None, demosaic="bilinear", mask=None,
                        polarizer_extinction=None, polarizer_offset=None, edge_margin=None) -> dict:
    """Import polarization-camera images into a dataset folder ``out`` (see the module
    docstring for every option). Returns a summary (``shape``, ``angles``, ``valid_pixels``,
    ``units``, ``path``)."""
    from thinfilm.core.colorimetry import DEFAULT_CAMERA, DEFAULT_ILLUMINANT, spectra_to_camera_rgb
    from thinfilm.core.io import write_dataset
    from thinfilm.core.mosaic import DEFAULT_PATTERN, parse_pattern
    from thinfilm.core.outputs import atomic_output_dir, check_output_dir

    from .demosaic import METHODS

    if layout not in LAYOUTS:
        raise UserError(f"--layout: expected one of {', '.join(LAYOUTS)}, got {layout!r}")
    demosaic_method = demosaic
    if demosaic_method not in METHODS:
        raise UserError(f"--demosaic: expected one of {', '.join(METHODS)}, got {demosaic_method!r}")
    if edge_margin is not None and (int(edge_margin) != edge_margin or edge_margin < 0):
        raise UserError(f"--edge-margin: expected a whole number of pixels >= 0, got {edge_margin}")
    if edge_margin is not None and demosaic_method != "residual":
        raise UserError("--edge-margin applies to --demosaic residual (bilinear marks its own band; see --keep-edges)")
    if layout == "separate" and mask is not None:
        raise UserError("--mask describes the object on a mosaic; it applies to --layout dofp-rgb only")
    if layout == "separate":
        if pattern is not None:
            raise UserError("--pattern describes a mosaic; it applies to --layout dofp-rgb only")
        if angles is None:
            raise UserError("--layout separate needs --angles, one polarizer angle per image (e.g. 0,45,90,135)")
        angle_list = parse_angles(angles)
        if len(angle_list) != len(images):
            raise UserError(f"--angles: {len(angle_list)} angles for {len(images)} images")
        pat = None
    else:
        if angles is not None:
            raise UserError("--angles applies to --layout separate; a mosaic's angles come from --pattern")
        pat = parse_pattern(pattern or DEFAULT_PATTERN)
        angle_list = list(pat.angles)
    if white_balance is not None and white_reference is not None:
        raise UserError("give either --white-balance or --white-reference, not both")
    pol_entry, pol_records = polarizer_calibration(polarizer_extinction, polarizer_offset, angle_list)
    if bit_depth is not None and not 1 <= int(bit_depth) <= 16:
        raise UserError(f"--bit-depth: expected 1 to 16 bits, got {bit_depth}")
    if pixel_size is not None and not (np.isfinite(pixel_size) and pixel_size > 0):
        raise UserError(f"--pixel-size: expected a number > 0, got {pixel_size}")
    wl = parse_wavelengths(wavelengths or DEFAULT_WAVELENGTHS)
    camera, illuminant = _colour_model(camera, illuminant, wl)
    meta_film = film_fields(film_ior, substrate_ior)
    in_files = input_files(*images, dark, flat, white_reference, white_reflectance, camera, illuminant, mask,
                           polarizer_extinction, polarizer_offset)
    out = check_output_dir(out, command="import polarization", inputs=in_files)
    # the lock of --out is held from here to the end: a second writer stops at once
    with atomic_output_dir(out, command="import polarization", inputs=in_files) as tmp:
        imgs = _read_inputs([Path(p) for p in images], layout, bit_depth)
        first = imgs[0]
        shape = first.data.shape
        hw = shape[:2]
        if layout == "dofp-rgb":
            P, Q = pat.shape
            if hw[0] < 2 * P or hw[1] < 2 * Q:
                raise UserError(f"{first.path}: a {hw[0]}x{hw[1]} mosaic is smaller than two periods of the pattern")
            colour_map, angle_map = pat.maps(hw)
            index_map = colour_map * 1000 + angle_map
        else:
            colour_map = np.broadcast_to(np.arange(3), shape)
            index_map = colour_map
        cal = _Calibration(first.bits, shape, dark, flat, saturation, index_map, first.is_float)
        object_mask_given = None if mask is None else _read_mask(mask, hw)

        # 1-4: saturation, dark, normalization, flat field
        calibrated, saturated = [], np.zeros(shape, dtype=bool)
        for img in imgs:
            sat, x = cal.apply(img.data)
            saturated |= sat
            calibrated.append(x)

        # 5: gains to reflectance units
        inputs = [file_record(img.path, "capture") for img in imgs]
        inputs += [r for r in (cal.dark_record, cal.flat_record) if isinstance(r, dict)]
        inputs += csv_records(camera, "camera") + csv_records(illuminant, "illuminant")
        calib = cal.record()
        if white_balance is not None:
            gains = np.asarray(parse_numbers(white_balance, "--white-balance", 3))
            if np.any(gains <= 0):
                raise UserError(f"--white-balance: gains must be > 0, got {white_balance!r}")
            units = "reflectance"
            calib["white_balance"] = gains.tolist()
        elif white_reference is not None:
            ref = cal._read(white_reference, "--white-reference image")
            inputs.append(file_record(ref.path, "white reference"))
            inputs += csv_records(white_reflectance, "white reflectance")
            sat, x = cal.apply(ref.data)
            rho = reference_reflectance(white_reflectance, "--white-reflectance", wl)
            rho_rgb = spectra_to_camera_rgb(rho, wl, camera or DEFAULT_CAMERA, illuminant or DEFAULT_ILLUMINANT)
            medians = []
            for c in range(3):
                sel = (colour_map == c) & ~sat
                if cal.bad_flat is not None:
                    sel &= ~cal.bad_flat
                if not sel.any():
                    raise UserError(f"{ref.path}: the --white-reference image is saturated everywhere in "
                                    f"{'RGB'[c]}")
                medians.append(float(np.median(x[sel])))
            medians = np.asarray(medians)
            if np.any(medians <= 0):
                raise UserError(f"{ref.path}: the --white-reference image is at or below the dark level in "
                                f"{'RGB'[int(np.argmin(medians))]}")
            gains = 0.5 * rho_rgb / medians
            units = "reflectance"
            calib["white_reference"] = {"reflectance": str(white_reflectance), "reflectance_rgb": rho_rgb.tolist(),
                                        "median_normalized": medians.tolist(), "behind_polarizer": True}
            calib["white_balance"] = gains.tolist()
        else:
            gains = np.ones(3)
            units = "relative"
            warn_relative_units("polarizer images")
        frame = np.mean(calibrated, axis=0) if layout == "dofp-rgb" else None

        # demosaic / assemble, and the pixels that can be trusted
        if layout == "dofp-rgb":
            from .demosaic import (DEFAULT_EDGE_MARGIN, demosaic, edge_pixels, footprint, object_mask, residual_demosaic,
                                   silhouette_band)

            frame = frame * gains[colour_map]
            bad_samples = saturated | (cal.bad_flat if cal.bad_flat is not None else False)
            bad = footprint(bad_samples, pat)
            n_sat = int(footprint(saturated, pat).sum())
            if demosaic_method == "residual":
                obj, mask_kind = (object_mask_given, "given") if object_mask_given is not None else (
                    object_mask(frame, pat), "found")
                if obj is None:
                    mask_kind = "none (no dark background)"
                polarized, unserved = residual_demosaic(frame, pat, mask=obj, exclude=bad_samples)
                bad = bad | unserved
                margin = DEFAULT_EDGE_MARGIN if edge_margin is None else int(edge_margin)
                edges = np.zeros(hw, dtype=bool) if (obj is None or keep_edges) else silhouette_band(obj, margin)
                edge_text = (f"each side of the object's silhouette is interpolated from its own samples; the object's "
                             f"outermost {0 if keep_edges else margin} pixels are marked invalid"
                             if obj is not None else "kept")
                mask_info = {"object_mask": mask_kind, "unserved_pixels": int(unserved.sum()),
                             "edge_margin": 0 if keep_edges else margin}
            else:
                polarized = demosaic(frame, pat, "bilinear")
                edges = np.zeros(hw, dtype=bool) if keep_edges else edge_pixels(frame, pat)
                edge_text = "kept" if keep_edges else ("pixels whose interpolation crosses the object's silhouette "
                                                       "are marked invalid")
                mask_info = {}
            valid = ~bad & ~edges
            layout_info = {"layout": layout, "pattern": pat.text, "pattern_period": pat.diagram().split("\n"),
                           "frames": len(imgs), "demosaic": demosaic_method, **mask_info,
                           "edge_pixels": int(edges.sum()), "edges": edge_text}
        else:
            polarized = {a: x * gains for a, x in zip(angle_list, calibrated)}
            bad = saturated.any(axis=-1)
            if cal.bad_flat is not None:
                bad |= cal.bad_flat.any(axis=-1)
            n_sat = int(saturated.any(axis=-1).sum())
            valid = ~bad
            layout_info = {"layout": layout, "files_angles_deg": dict(zip([img.path.name for img in imgs], angle_list))}
        if not valid.any():
            raise UserError(f"{first.path}: no pixel is usable (saturated or at the flat field's dark level everywhere)")
        if pol_entry is not None:   # real polarizers (extinction, axis offsets) -> ideal ones
            polarized, gain = correct_polarizers(polarized, pol_entry)
            calib["polarizer"] = dict(pol_entry, correction=POLARIZER_CORRECTED, noise_gain_s1_s2=gain)
            inputs += pol_records

        fields = dict(
            wavelengths_nm=[float(v) for v in wl],
            polarizer_angles_deg=sorted(int(a) for a in angle_list),
            **({"camera": camera} if camera else {}),
            **({"illuminant": illuminant} if illuminant else {}),
            **meta_film,
            **({"projection": {"pixel_size": float(pixel_size)}} if pixel_size is not None else {}),
            sensor=layout_info,
            saturated_pixels=n_sat,
            valid_pixels=int(valid.sum()),
        )
        meta = import_meta("polarization", inputs, units, calib, **fields)
        images32 = {int(a) % 360: np.asarray(img, dtype=np.float32) for a, img in polarized.items()}
        write_dataset(tmp, meta, polarized_rgb=images32, valid=valid)
    return {"path": out, "shape": hw, "angles": sorted(images32), "valid_pixels": int(valid.sum()),
            "saturated_pixels": n_sat, "units": units, "meta": meta, "valid": valid, "images": images32}


def cli_main(args) -> int:
    """``thinfilm import polarization IMAGES... --layout separate|dofp-rgb --out DIR [...]``."""
    s = import_polarization(
        args.images, args.out, args.layout, angles=args.angles, pattern=args.pattern, bit_depth=args.bit_depth,
        dark=args.dark, flat=args.flat, white_balance=args.white_balance, white_reference=args.white_reference,
        white_reflectance=args.white_reflectance, camera=args.camera, illuminant=args.illuminant,
        wavelengths=args.wavelengths, saturation=args.saturation, keep_edges=args.keep_edges,
        film_ior=args.film_ior, substrate_ior=args.substrate_ior, pixel_size=args.pixel_size,
        demosaic=args.demosaic, mask=args.mask, polarizer_extinction=args.polarizer_extinction,
        polarizer_offset=args.polarizer_offset, edge_margin=args.edge_margin)
    h, w = s["shape"]
    print(f"wrote {s['path']} ({args.layout}, {w}x{h}, polarizer angles {', '.join(map(str, s['angles']))}; "
          f"{s['valid_pixels']} valid pixels, {s['saturated_pixels']} saturated; units {s['units']})")
    return 0
