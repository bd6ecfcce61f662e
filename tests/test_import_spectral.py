"""``thinfilm import spectral``: ENVI and TIFF cubes, white and dark references, s-polarized
and Stokes cubes, and an imported cube that ``reconstruct spectral`` takes like the original."""

import warnings

import numpy as np
import pytest

from thinfilm.cli import main
from thinfilm.core.errors import ThinfilmWarning
from thinfilm.core.io import read_dataset


def _save_envi(path, cube, wavelengths=None, units="nm", dtype=None, fwhm=None):
    import spectral.io.envi as envi

    meta = {}
    if wavelengths is not None:
        meta["wavelength"] = [float(w) for w in wavelengths]
        meta["wavelength units"] = units
    if fwhm is not None:
        meta["fwhm"] = [float(fwhm)] * cube.shape[2]
    envi.save_image(str(path), np.asarray(cube, dtype=dtype or cube.dtype), force=True, metadata=meta)
    return path


def _cli(*argv):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ThinfilmWarning)
        assert main(["import", "spectral", *map(str, argv)]) == 0


def _scene(h=6, w=7, bands=12, seed=0):
    rng = np.random.default_rng(seed)
    wl = np.linspace(420.0, 700.0, bands)
    refl = 0.05 + 0.3 * rng.random((h, w, bands))
    return wl, refl


def test_envi_counts_with_micrometres_white_spectrum_and_dark_level(tmp_path):
    wl, refl = _scene()
    white = 30000 + 10000 * np.sin(wl / 50.0)                  # counts of the white target per band
    dark = 200.0
    counts = np.rint(refl / 0.8 * (white - dark) + dark)       # white target of reflectance 0.8
    _save_envi(tmp_path / "cube.hdr", counts.astype(np.uint16), wl / 1000.0, units="Micrometers", fwhm=0.005)
    np.savetxt(tmp_path / "white.csv", np.stack([wl, white], -1), delimiter=",", header="wavelength_nm,counts")
    _cli(tmp_path / "cube.hdr", "--white", tmp_path / "white.csv", "--dark", dark, "--white-reflectance", "0.8",
         "--substrate-ior", "1.6", "--out", tmp_path / "ds")
    ds = read_dataset(tmp_path / "ds", need=("spectral_s",))
    np.testing.assert_allclose(ds.wavelengths_nm, wl)
    np.testing.assert_allclose(ds.spectral_s, refl, atol=0.8 / (white.min() - dark))
    assert ds.meta["units"] == "reflectance" and ds.meta["band_fwhm_nm"] == pytest.approx(5.0)
    assert ds.meta["substrate_ior"] == 1.6 and ds.meta["polarizer"] == "s"


def test_tiff_pages_with_wavelengths_and_per_pixel_white_and_dark_cubes(tmp_path):
    import tifffile

    wl, refl = _scene(bands=9)
    rng = np.random.default_rng(2)
    white = 20000 + 5000 * rng.random(refl.shape)
    dark = 100 + 20 * rng.random(refl.shape)
    counts = refl * (white - dark) + dark
    tifffile.imwrite(tmp_path / "cube.tif", np.moveaxis(counts, -1, 0).astype(np.float32),
                     photometric="minisblack")    # one page per band
    tifffile.imwrite(tmp_path / "white.tif", np.moveaxis(white, -1, 0).astype(np.float32), photometric="minisblack")
    tifffile.imwrite(tmp_path / "dark.tif", np.moveaxis(dark, -1, 0).astype(np.float32), photometric="minisblack")
    _cli(tmp_path / "cube.tif", "--wavelengths", f"{wl[0]}:{wl[-1]}:{wl[1] - wl[0]}", "--white", tmp_path / "white.tif",
         "--dark", tmp_path / "dark.tif", "--out", tmp_path / "ds")
    ds = read_dataset(tmp_path / "ds", need=("spectral_s",))
    np.testing.assert_allclose(ds.spectral_s, refl, rtol=1e-4, atol=1e-6)
    roles = sorted(r["role"] for r in ds.meta["imported_from"])
    assert roles == ["cube", "dark", "white"]


def test_decreasing_envi_bands_are_reordered(tmp_path):
    wl, refl = _scene(bands=8)
    _save_envi(tmp_path / "cube.hdr", refl[..., ::-1].astype(np.float32), wl[::-1])
    _cli(tmp_path / "cube.hdr", "--out", tmp_path / "ds")
    ds = read_dataset(tmp_path / "ds", need=("spectral_s",))
    np.testing.assert_allclose(ds.wavelengths_nm, wl)
    np.testing.assert_allclose(ds.spectral_s, refl, rtol=1e-6)
    assert ds.meta["units"] == "relative"


def test_stokes_cubes_behind_four_polarizers(tmp_path):
    h, w, b = 5, 6, 10
    rng = np.random.default_rng(4)
    S0 = 0.1 + 0.2 * rng.random((h, w, b))
    dop = 0.6 * rng.random((h, w, b))
    psi = np.pi * rng.random((h, w, 1))
    S1, S2 = S0 * dop * np.cos(2 * psi), S0 * dop * np.sin(2 * psi)
    wl = np.linspace(450.0, 650.0, b)
    files = []
    for a in (0, 45, 90, 135):
        t = np.radians(a)
        intensity = 0.5 * (S0 + S1 * np.cos(2 * t) + S2 * np.sin(2 * t))   # Malus, reflectance units
        files.append(_save_envi(tmp_path / f"c{a}.hdr", (2 * intensity * 1000.0).astype(np.float32), wl))
    np.savetxt(tmp_path / "white.csv", np.stack([wl, np.full(b, 1000.0)], -1), delimiter=",")
    _cli(*files, "--polarizer", "stokes", "--white", tmp_path / "white.csv", "--out", tmp_path / "ds")
    ds = read_dataset(tmp_path / "ds", need=("spectral_s", "stokes"))
    for name, ref in (("S0", S0), ("S1", S1), ("S2", S2)):
        np.testing.assert_allclose(ds.stokes[name], ref, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(ds.spectral_s, S0 + np.hypot(S1, S2), rtol=1e-5, atol=1e-6)
    assert ds.meta["cube_polarizer_angles_deg"] == [0, 45, 90, 135]


def test_saturated_samples_invalidate_their_pixel(tmp_path):
    wl, refl = _scene()
    counts = np.rint(refl * 60000).astype(np.uint16)
    counts[2, 3, 5] = 65535
    _save_envi(tmp_path / "cube.hdr", counts, wl)
    _cli(tmp_path / "cube.hdr", "--out", tmp_path / "ds")
    ds = read_dataset(tmp_path / "ds", need=("spectral_s",))
    expected = np.ones(refl.shape[:2], bool)
    expected[2, 3] = False
    np.testing.assert_array_equal(ds.valid, expected)


@pytest.fixture(scope="module")
def generated(tmp_path_factory, render_variant_module):
    from thinfilm.generators.generate import generate_dataset
    from thinfilm.generators.spec import load_spec

    out = tmp_path_factory.mktemp("gen") / "cyl"
    generate_dataset(load_spec("cylinder", overrides=["noise.model=none"], resolution=48), out, progress=False)
    return out


def test_imported_stokes_cubes_reconstruct_like_the_original(generated, tmp_path):
    """A generated dataset's Stokes cube, written as four polarizer cubes (ENVI float), comes
    back as the same spectral_s, and reconstruct spectral gives the same estimate."""
    from thinfilm.reconstruct import reconstruct

    src = read_dataset(generated, need=("spectral_s", "stokes"))
    wl = src.wavelengths_nm
    files = []
    for a in (0, 45, 90, 135):
        t = np.radians(a)
        intensity = 0.5 * (src.stokes["S0"] + src.stokes["S1"] * np.cos(2 * t) + src.stokes["S2"] * np.sin(2 * t))
        files.append(_save_envi(tmp_path / f"c{a}.hdr", (2 * intensity).astype(np.float32), wl))
    np.savetxt(tmp_path / "white.csv", np.stack([wl, np.ones_like(wl)], -1), delimiter=",")
    _cli(*files, "--polarizer", "stokes", "--white", tmp_path / "white.csv", "--substrate-ior", "1.6",
         "--out", tmp_path / "ds")
    imp = read_dataset(tmp_path / "ds", need=("spectral_s",))
    np.testing.assert_allclose(imp.spectral_s, src.spectral_s, rtol=1e-5, atol=1e-6)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ThinfilmWarning)
        a = reconstruct("spectral", generated)[0]
        b = reconstruct("spectral", tmp_path / "ds")[0]
    both = a.valid & b.valid
    assert both.sum() >= 0.95 * a.valid.sum()
    np.testing.assert_allclose(b.thickness_nm[both], a.thickness_nm[both], atol=1.0)
    assert abs(float(b.film_ior) - float(a.film_ior)) < 1e-3


def test_provenance_hashes_the_data_file_of_an_envi_cube_as_well_as_its_header(tmp_path):
    import hashlib
    import json

    wl, refl = _scene(h=3, w=4, bands=5)
    seen = set()
    for i in range(3):  # three cubes with the same header and different samples
        folder = tmp_path / f"c{i}"
        folder.mkdir()
        _save_envi(folder / "cube.hdr", (refl + 0.01 * i).astype(np.float32), wl)
        _cli(folder / "cube.hdr", "--out", folder / "ds")
        records = json.loads((folder / "ds" / "meta.json").read_text())["imported_from"]
        roles = {r["role"]: r for r in records}
        assert sorted(roles) == ["cube", "cube header"]
        for name, role in (("cube.hdr", "cube header"), ("cube.img", "cube")):
            assert roles[role]["path"] == str((folder / name).resolve())
            assert roles[role]["sha256"] == hashlib.sha256((folder / name).read_bytes()).hexdigest()
        seen.add(roles["cube"]["sha256"])
        assert (folder / "cube.hdr").read_bytes() == (tmp_path / "c0" / "cube.hdr").read_bytes()
    assert len(seen) == 3


def test_provenance_of_an_envi_white_cube_and_a_reflectance_csv(tmp_path):
    import json

    wl, refl = _scene(h=3, w=4, bands=5)
    _save_envi(tmp_path / "cube.hdr", refl.astype(np.float32), wl)
    _save_envi(tmp_path / "white.hdr", np.ones((1, 1, 5), np.float32), wl)
    np.savetxt(tmp_path / "rho.csv", np.stack([wl, np.full(5, 0.9)], -1), delimiter=",", header="wavelength_nm,r")
    _cli(tmp_path / "cube.hdr", "--white", tmp_path / "white.hdr", "--white-reflectance", tmp_path / "rho.csv",
         "--out", tmp_path / "ds")
    meta = json.loads((tmp_path / "ds" / "meta.json").read_text())
    files = {(r["role"], r["path"].rsplit("/", 1)[-1]) for r in meta["imported_from"]}
    assert files == {("cube header", "cube.hdr"), ("cube", "cube.img"), ("white header", "white.hdr"),
                     ("white", "white.img"), ("white reflectance", "rho.csv")}
    assert meta["calibration"]["white"]["path"].endswith("white.img")
