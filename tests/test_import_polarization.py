"""``thinfilm import polarization``: layouts against independently built mosaics, bit depths,
calibration to reflectance units, saturation, and the valid mask reaching the reconstruction."""

import hashlib
import json
import warnings

import numpy as np
import pytest

from _import_helpers import (IMX250MYR, build_mosaic, smooth_images, write_png, write_png16_rgb,
                             write_tiff)
from thinfilm.cli import main
from thinfilm.core.errors import ThinfilmWarning
from thinfilm.core.io import read_dataset, read_exr
from thinfilm.core.mosaic import DEFAULT_PATTERN, parse_pattern
from thinfilm.importers.images import read_image


def _import(argv):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ThinfilmWarning)
        assert main(["import", "polarization", *map(str, argv)]) == 0


def _sites(table, h, w):
    """(angle, channel) of every pixel from a table of cells."""
    p, q = len(table), len(table[0])
    for r in range(h):
        for c in range(w):
            cell = table[r % p][c % q]
            yield r, c, int(cell[1:]), "RGB".index(cell[0])


def test_default_pattern_is_the_imx250myr_layout():
    p = parse_pattern(DEFAULT_PATTERN)
    for r in range(8):
        for c in range(8):
            colour, angle = p.cell(r, c)
            assert f"{colour}{angle}" == IMX250MYR[r % 4][c % 4]


@pytest.mark.parametrize("pattern_arg,table", [
    (None, IMX250MYR),
    ("BGGR:0,45,135,90", [["B0", "B45", "G0", "G45"], ["B135", "B90", "G135", "G90"],
                          ["G0", "G45", "R0", "R45"], ["G135", "G90", "R135", "R90"]]),
    ("G45 G0 R45 R0 / G90 G135 R90 R135 / B45 B0 G45 G0 / B90 B135 G90 G135",
     [["G45", "G0", "R45", "R0"], ["G90", "G135", "R90", "R135"],
      ["B45", "B0", "G45", "G0"], ["B90", "B135", "G90", "G135"]]),
])
def test_dofp_layout_against_an_independently_built_mosaic(tmp_path, pattern_arg, table):
    """Every sampled pixel comes back, exactly, in the image of its angle and channel."""
    h, w = 18, 22                               # not a multiple of the period
    rng = np.random.default_rng(1)
    src = {a: rng.uniform(0.05, 0.95, (h, w, 3)) for a in (0, 45, 90, 135)}
    codes = np.rint(build_mosaic(src, table) * 65535).astype(np.uint16)
    write_png(tmp_path / "raw.png", codes)
    args = [tmp_path / "raw.png", "--layout", "dofp-rgb", "--white-balance", "1,1,1", "--out", tmp_path / "ds",
            "--keep-edges"]
    if pattern_arg:
        args += ["--pattern", pattern_arg]
    _import(args)
    ds = read_dataset(tmp_path / "ds")
    assert sorted(ds.polarized_rgb) == [0, 45, 90, 135]
    for r, c, a, ch in _sites(table, h, w):
        assert ds.polarized_rgb[a][r, c, ch] == np.float32(codes[r, c] / 65535.0), (r, c, a, ch)
    assert ds.meta["source"] == "imported" and not ds.ground_truth


def test_demosaic_keeps_float_precision_and_is_exact_on_linear_images(tmp_path):
    """A float TIFF mosaic of linear ramps with steps far below 1/65535: the interpolated
    images reproduce the ramps to float32 precision (no rescaling to 16 bits)."""
    h, w = 24, 28
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    src = {a: np.stack([0.25 + 1e-7 * (xx + 2 * yy) + 0.01 * k + 1e-3 * a / 45 for k in range(3)], -1)
           for a in (0, 45, 90, 135)}
    write_tiff(tmp_path / "raw.tif", build_mosaic(src).astype(np.float32))
    _import([tmp_path / "raw.tif", "--layout", "dofp-rgb", "--demosaic", "bilinear", "--white-balance", "1,1,1",
             "--keep-edges", "--out", tmp_path / "ds"])
    ds = read_dataset(tmp_path / "ds")
    inner = (slice(4, h - 4), slice(4, w - 4))
    for a in src:
        np.testing.assert_allclose(ds.polarized_rgb[a][inner], src[a][inner], rtol=0, atol=1e-7)
        # the 1e-7 steps survive: neighbouring pixels differ
        assert np.all(np.diff(ds.polarized_rgb[a][inner][..., 0], axis=1) > 0)


def test_demosaic_of_a_smooth_scene_is_second_order_accurate():
    """Bilinear interpolation: the error of a smooth scene falls 4x when it is sampled twice as
    finely, and is small already at 64 x 64."""
    from thinfilm.importers.demosaic import demosaic

    errors = []
    for n in (64, 128):
        src = smooth_images(n, n)
        out = demosaic(build_mosaic(src), parse_pattern(DEFAULT_PATTERN), "bilinear")
        inner = (slice(n // 16, -n // 16), slice(n // 16, -n // 16))
        errors.append(np.median([np.abs(out[a][inner] - src[a][inner]) / src[a][inner] for a in src]))
    assert errors[0] < 0.005
    assert errors[0] / errors[1] > 3.5


def test_separate_layout_with_three_angles_and_16_bit_rgb_png(tmp_path):
    src = smooth_images(12, 10, angles=(0, 60, 120))
    files = []
    for i, a in enumerate((0, 60, 120)):
        codes = np.rint(src[a] * 65535).astype(np.uint16)
        files.append(write_png16_rgb(tmp_path / f"p{a}.png", codes, filters=(0, 1, 2, 3, 4)[i:] + (0, 1, 2, 3, 4)[:i]))
    _import([*files, "--layout", "separate", "--angles", "0,60,120", "--white-balance", "2,2,2",
             "--out", tmp_path / "ds"])
    ds = read_dataset(tmp_path / "ds")
    assert sorted(ds.polarized_rgb) == [0, 60, 120] and ds.meta["polarizer_angles_deg"] == [0, 60, 120]
    for a in (0, 60, 120):
        np.testing.assert_allclose(ds.polarized_rgb[a], 2 * src[a], atol=2 / 65535)


def test_png16_decoder_undoes_every_row_filter(tmp_path):
    rng = np.random.default_rng(3)
    arr = rng.integers(0, 65536, (9, 7, 3)).astype(np.uint16)
    for filters in ((0,), (1,), (2,), (3,), (4,), (4, 3, 2, 1, 0)):
        img = read_image(write_png16_rgb(tmp_path / "f.png", arr, filters))
        assert img.bits == 16 and np.array_equal(img.data, arr), filters


@pytest.mark.parametrize("kind", ["png8", "png16", "tiff8", "tiff16", "tiff12", "png12_sbit"])
def test_bit_depths_normalize_to_unit_range(tmp_path, kind):
    rng = np.random.default_rng(4)
    bits = {"png8": 8, "tiff8": 8, "png16": 16, "tiff16": 16, "tiff12": 12, "png12_sbit": 12}[kind]
    top = 2 ** bits - 1
    values = rng.integers(0, top - 20, (8, 8, 3))
    path = tmp_path / ("img.png" if kind.startswith("png") else "img.tif")
    extra = []
    if kind == "png8":
        write_png(path, values.astype(np.uint8))
    elif kind == "png16":
        write_png16_rgb(path, values.astype(np.uint16), (1, 4))
    elif kind == "tiff8":
        write_tiff(path, values.astype(np.uint8))
    elif kind == "tiff16":
        write_tiff(path, values.astype(np.uint16))
    elif kind == "tiff12":
        write_tiff(path, values.astype(np.uint16))
        extra = ["--bit-depth", "12"]
    else:  # a 12-bit image scaled up to 16 bits, with the sBIT chunk the PNG standard asks for
        write_png(path, (values[..., 0] << 4).astype(np.uint16), sbit=12)
        values = values[..., :1].repeat(3, axis=-1)
    files = [path] * 3 if kind != "png12_sbit" else []
    if kind == "png12_sbit":  # gray: use it as a mosaic
        _import([path, "--layout", "dofp-rgb", "--white-balance", "1,1,1", "--keep-edges", "--out", tmp_path / "ds"])
        ds = read_dataset(tmp_path / "ds")
        assert ds.meta["calibration"]["bit_depth"] == 12
        assert ds.polarized_rgb[90][0, 0, 0] == np.float32(values[0, 0, 0] / top)
        return
    _import([*files, "--layout", "separate", "--angles", "0,45,90", "--white-balance", "1,1,1", *extra,
             "--out", tmp_path / "ds"])
    ds = read_dataset(tmp_path / "ds")
    assert ds.meta["calibration"]["bit_depth"] == bits
    np.testing.assert_array_equal(ds.polarized_rgb[45], (values / top).astype(np.float32))


def test_dark_flat_and_white_balance_give_reflectance(tmp_path):
    """raw = reflectance x flat response / gain + dark, quantized: the import undoes each step."""
    h, w = 20, 24
    src = smooth_images(h, w)
    refl = build_mosaic(src)
    table_colour = np.array([["RGB".index(IMX250MYR[r % 4][c % 4][0]) for c in range(w)] for r in range(h)])
    gains = np.array([1.8, 1.1, 1.4])                        # normalized raw -> reflectance
    yy, xx = np.mgrid[0:h, 0:w]
    response = 0.8 + 0.4 * xx / w                            # vignetting-like flat response
    dark = 300 + (yy % 3) * 7.0                              # fixed-pattern dark
    top = 65535.0
    raw = np.rint(refl * response / gains[table_colour] * top + dark)
    flat = np.rint(0.5 * response * top + dark)              # uniform unpolarized field
    write_tiff(tmp_path / "raw.tif", raw.astype(np.uint16))
    write_tiff(tmp_path / "dark.tif", dark.astype(np.uint16))
    write_tiff(tmp_path / "flat.tif", flat.astype(np.uint16))
    # the flat field is normalized to mean 1 in each colour/angle class: what remains of the
    # response is its class mean (part of the white balance)
    cls = np.array([[IMX250MYR[r % 4][c % 4] for c in range(w)] for r in range(h)])
    mean_response = np.zeros((h, w))
    for k in np.unique(cls):
        mean_response[cls == k] = response[cls == k].mean()
    _import([tmp_path / "raw.tif", "--layout", "dofp-rgb", "--dark", tmp_path / "dark.tif", "--flat",
             tmp_path / "flat.tif", "--white-balance", ",".join(map(str, gains)), "--keep-edges",
             "--out", tmp_path / "ds"])
    ds = read_dataset(tmp_path / "ds")
    meta = json.loads((tmp_path / "ds" / "meta.json").read_text())
    assert meta["units"] == "reflectance" and meta["calibration"]["white_balance"] == gains.tolist()
    roles = {r["role"]: r for r in meta["imported_from"]}
    assert roles["dark"]["sha256"] == hashlib.sha256((tmp_path / "dark.tif").read_bytes()).hexdigest()
    got = build_mosaic(ds.polarized_rgb)                     # the sampled values
    np.testing.assert_allclose(got, refl * mean_response, rtol=1e-4, atol=2e-5)


def test_white_reference_sets_the_gains(tmp_path):
    h, w = 16, 16
    src = smooth_images(h, w)
    gains = np.array([1.7, 1.0, 1.3])
    colour = np.array([["RGB".index(IMX250MYR[r % 4][c % 4][0]) for c in range(w)] for r in range(h)])
    top = 65535.0
    write_tiff(tmp_path / "raw.tif", np.rint(build_mosaic(src) / gains[colour] * top).astype(np.uint16))
    # a diffuse target of reflectance 0.6, unpolarized: 0.3 behind every polarizer
    write_tiff(tmp_path / "white.tif", np.rint(0.3 / gains[colour] * top).astype(np.uint16) + np.zeros((h, w), np.uint16))
    _import([tmp_path / "raw.tif", "--layout", "dofp-rgb", "--white-reference", tmp_path / "white.tif",
             "--white-reflectance", "0.6", "--keep-edges", "--out", tmp_path / "ds"])
    ds = read_dataset(tmp_path / "ds")
    np.testing.assert_allclose(ds.meta["calibration"]["white_balance"], gains, rtol=2e-4)
    np.testing.assert_allclose(build_mosaic(ds.polarized_rgb), build_mosaic(src), rtol=1e-3, atol=1e-4)


def test_without_gains_units_are_relative_and_a_warning_says_so(tmp_path):
    write_tiff(tmp_path / "raw.tif", np.full((8, 8), 30000, np.uint16))
    with pytest.warns(ThinfilmWarning, match="relative units"):
        from thinfilm.importers.polarization import import_polarization

        import_polarization([tmp_path / "raw.tif"], tmp_path / "ds", "dofp-rgb")
    assert read_dataset(tmp_path / "ds").meta["units"] == "relative"


@pytest.mark.parametrize("cell", [(9, 8), (10, 10), (9, 11)])     # an R, a G, a B sample
def test_a_saturated_sample_invalidates_exactly_its_interpolation_footprint(tmp_path, cell):
    h, w = 24, 24
    raw = np.full((h, w), 20000, np.uint16)
    raw[cell] = 65535
    write_tiff(tmp_path / "raw.tif", raw)
    _import([tmp_path / "raw.tif", "--layout", "dofp-rgb", "--white-balance", "1,1,1", "--out", tmp_path / "ds"])
    valid = read_exr(tmp_path / "ds" / "valid.exr")["valid"] > 0.5
    r0, c0 = cell
    yy, xx = np.mgrid[0:h, 0:w]
    dr, dc = yy - r0, xx - c0
    if IMX250MYR[r0 % 4][c0 % 4][0] == "G":              # checkerboard: bilinear along the diagonals
        reach = (np.abs(dr + dc) < 4) & (np.abs(dr - dc) < 4)
    else:                                                # one lattice: bilinear along rows and columns
        reach = (np.abs(dr) < 4) & (np.abs(dc) < 4)
    np.testing.assert_array_equal(~valid, reach)
    assert read_dataset(tmp_path / "ds").meta["saturated_pixels"] == int(reach.sum())


def test_object_silhouette_is_marked_invalid_but_not_the_interior():
    from thinfilm.importers.demosaic import edge_pixels

    h = w = 64
    yy, xx = np.mgrid[0:h, 0:w]
    disc = (yy - 31.5) ** 2 + (xx - 31.5) ** 2 < 20 ** 2
    src = {a: np.where(disc[..., None], img, 1e-4) for a, img in smooth_images(h, w).items()}
    pattern = parse_pattern(DEFAULT_PATTERN)
    edges = edge_pixels(build_mosaic(src), pattern)
    from scipy import ndimage

    d_in = ndimage.distance_transform_cdt(disc, metric="chessboard")
    d_out = ndimage.distance_transform_cdt(~disc, metric="chessboard")
    # every pixel whose bilinear footprint (3 px) crosses the silhouette, and none beyond the
    # footprint, the 2 x 2 intensity window and the 2 px margin
    assert edges[(d_in > 0) & (d_in <= 3)].all() and edges[(d_out > 0) & (d_out <= 3)].all()
    assert not edges[d_in > 6].any() and not edges[d_out > 6].any()
    assert not edge_pixels(build_mosaic(smooth_images(h, w)), pattern).any()   # no dark background


def test_valid_mask_reaches_the_rgb_capture(tmp_path):
    from thinfilm.core.film import Film
    from thinfilm.core.io import dataset_meta, write_dataset
    from thinfilm.core.registry import Options
    from thinfilm.reconstruction.rgb_capture import capture_from_dataset

    src = smooth_images(16, 16)
    valid = np.ones((16, 16), bool)
    valid[4:7, 5:9] = False
    write_dataset(tmp_path, dataset_meta(wavelengths_nm=[400.0, 500.0, 600.0, 700.0],
                                         polarizer_angles_deg=[0, 45, 90, 135], camera="Nikon 5100 (NPL)",
                                         illuminant="D65"),
                  polarized_rgb=src, valid=valid, preview=False)
    ds = read_dataset(tmp_path)
    np.testing.assert_array_equal(ds.valid, valid)
    cap = capture_from_dataset(ds, Options(film=Film.single(1.37, None, 1.6)))
    assert not (cap.mask & ~valid).any() and cap.mask[valid].all()


def test_meta_records_the_inputs_camera_and_film(tmp_path):
    write_tiff(tmp_path / "raw.tif", np.full((8, 8), 30000, np.uint16))
    _import([tmp_path / "raw.tif", "--layout", "dofp-rgb", "--white-balance", "1,1,1", "--camera",
             "Nikon 5100 (NPL)", "--illuminant", "D65", "--film-ior", "1.37", "--substrate-ior", "1.6",
             "--out", tmp_path / "ds"])
    meta = read_dataset(tmp_path / "ds").meta
    assert meta["source"] == "imported" and meta["imported_as"] == "polarization"
    rec = meta["imported_from"][0]
    assert rec["role"] == "capture" and rec["sha256"] == hashlib.sha256((tmp_path / "raw.tif").read_bytes()).hexdigest()
    assert meta["camera"] == "Nikon 5100 (NPL)" and meta["illuminant"] == "D65"
    assert meta["film_ior"] == 1.37 and meta["substrate_ior"] == 1.6
    assert meta["sensor"]["pattern"] == DEFAULT_PATTERN and len(meta["wavelengths_nm"]) == 81


def _fringe_field(n, period):
    """An analytic smooth polarized field with interference-like fringes: per colour an S0
    oscillating along a direction with its own period, a degree and angle of linear
    polarization that vary slowly (Malus' law behind each polarizer)."""
    yy, xx = np.mgrid[0:n, 0:n].astype(np.float64)
    S0 = np.stack([0.3 + 0.25 * np.cos(2 * np.pi * (xx + 0.3 * yy) / pl + k)
                   for k, pl in enumerate((period, 0.85 * period, 0.7 * period))], -1)
    rho = (0.2 + 0.5 * xx / n)[..., None]
    phi = (np.pi * (0.3 + 0.5 * yy / n))[..., None]
    return {a: 0.5 * S0 * (1 + rho * np.cos(2 * np.radians(a) - 2 * phi)) for a in (0, 45, 90, 135)}


def _stokes_errors(out, src, sel):
    from thinfilm.core.conventions import fit_stokes

    ang = sorted(src)
    e = fit_stokes(np.stack([out[a] for a in ang]), ang)
    t = fit_stokes(np.stack([src[a] for a in ang]), ang)
    return float(np.abs(e[0] - t[0])[sel].mean()), float(np.hypot(e[1] - t[1], e[2] - t[2])[sel].mean())


# mean absolute errors measured (residual, bilinear): S0 and |(S1, S2)|
_FIELDS = {"smooth": (5.3e-5, 1.41e-4, 1.34e-4, 6.31e-4), "fringes 24 px": (9.33e-3, 1.76e-2, 8.02e-3, 1.30e-2),
           "fringes 16 px": (2.30e-2, 3.72e-2, 1.81e-2, 2.81e-2)}


@pytest.mark.parametrize("field", sorted(_FIELDS))
def test_residual_demosaic_beats_bilinear_on_smooth_polarized_fields(field):
    """Against the known field (not against either method's output): the residual method's
    intensity and polarization errors are below bilinear's, and it keeps every sample. The
    fields: the smooth scene of the other tests (its angle of polarization turns by 180° over
    the image), and fringes of 24 and 16 px period (interference colours of a film)."""
    from thinfilm.importers.demosaic import demosaic

    n = 96
    src = smooth_images(n, n) if field == "smooth" else _fringe_field(n, float(field.split()[1]))
    raw = build_mosaic(src)
    p = parse_pattern(DEFAULT_PATTERN)
    inner = (slice(6, -6), slice(6, -6))
    res = demosaic(raw, p, "residual")
    bil = demosaic(raw, p, "bilinear")
    s0_r, s12_r = _stokes_errors(res, src, inner)
    s0_b, s12_b = _stokes_errors(bil, src, inner)
    assert s0_r < 0.75 * s0_b and s12_r < 0.9 * s12_b, (s0_r, s0_b, s12_r, s12_b)
    # the known errors, within 10 %
    np.testing.assert_allclose([s0_r, s0_b, s12_r, s12_b], _FIELDS[field], rtol=0.1)
    assert np.array_equal(build_mosaic(res), raw)


def test_residual_demosaic_keeps_the_object_edge():
    """A fringed disc before a dark background: the object mask is found exactly, no pixel is
    lost at the silhouette, and the pixels next to it are far closer to the field than the
    bilinear ones (which mix object and background samples)."""
    from scipy import ndimage

    from thinfilm.importers.demosaic import demosaic, object_mask, residual_demosaic

    n = 96
    yy, xx = np.mgrid[0:n, 0:n]
    disc = (yy - 47.5) ** 2 + (xx - 47.5) ** 2 < 36 ** 2
    src = {a: np.where(disc[..., None], img, 1e-4) for a, img in _fringe_field(n, 24.0).items()}
    raw = build_mosaic(src)
    p = parse_pattern(DEFAULT_PATTERN)
    mask = object_mask(raw, p)
    np.testing.assert_array_equal(mask, disc)
    res, unserved = residual_demosaic(raw, p, mask=mask)
    assert not unserved.any()
    bil = demosaic(raw, p, "bilinear")
    band = disc & (ndimage.distance_transform_cdt(disc, metric="chessboard") <= 3)
    s0_r, s12_r = _stokes_errors(res, src, band)
    s0_b, s12_b = _stokes_errors(bil, src, band)
    # measured: S0 0.016 vs 0.062, S1/S2 0.018 vs 0.050 (mean absolute errors)
    assert s0_r < 0.35 * s0_b and s12_r < 0.45 * s12_b
    # the background stays dark: no object light is smeared outside the silhouette
    outside = ~disc
    assert max(float(np.abs(res[a][outside] - src[a][outside]).max()) for a in src) < 1e-9


def test_dofp_import_keeps_the_silhouette_valid_with_the_residual_method(tmp_path):
    """residual: only the object's outermost --edge-margin pixels are invalid (0: none), the
    background beside the object stays valid; bilinear: a band on both sides."""
    from scipy import ndimage

    n = 64
    yy, xx = np.mgrid[0:n, 0:n]
    disc = (yy - 31.5) ** 2 + (xx - 31.5) ** 2 < 22 ** 2
    src = {a: np.where(disc[..., None], img, 1e-4) for a, img in _fringe_field(n, 24.0).items()}
    write_tiff(tmp_path / "raw.tif", np.rint(build_mosaic(src) * 60000).astype(np.uint16))
    base = [tmp_path / "raw.tif", "--layout", "dofp-rgb", "--white-balance", "1,1,1"]
    _import(base + ["--demosaic", "residual", "--out", tmp_path / "res"])
    _import(base + ["--demosaic", "residual", "--edge-margin", "0", "--out", tmp_path / "kept"])
    _import(base + ["--out", tmp_path / "bil"])  # the default
    res, kept, bil = (read_dataset(tmp_path / k) for k in ("res", "kept", "bil"))
    depth = ndimage.distance_transform_cdt(disc, metric="chessboard")     # 1 at the outermost pixels
    np.testing.assert_array_equal(~res.valid, disc & (depth <= 3))
    assert kept.valid is None or kept.valid.all()
    assert not bil.valid[disc & (depth <= 3)].any()
    assert (~bil.valid).sum() > 2 * (~res.valid).sum()
    sensor = res.meta["sensor"]
    assert sensor["demosaic"] == "residual" and sensor["object_mask"] == "found" and sensor["edge_margin"] == 3
    assert kept.meta["sensor"]["edge_margin"] == 0 and bil.meta["sensor"]["demosaic"] == "bilinear"
