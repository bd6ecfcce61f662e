"""Calibration on import: dark frame, flat field, and the polarizers' measured extinction ratio
and axis offset, for ``thinfilm import polarization`` and ``import spectral``: applied to
known synthetic captures, recorded in ``meta.json``, bad values stopped with one line (exit 2),
and an uncorrectable polarizer reported by every reader of the dataset."""

import json
import warnings

import numpy as np
import pytest

from _import_helpers import write_tiff
from thinfilm.cli import main
from thinfilm.core.errors import ThinfilmWarning
from thinfilm.core.io import read_dataset

ANGLES = (0, 45, 90, 135)


def _run(argv):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ThinfilmWarning)
        return main([*map(str, argv)])


def _stokes(h=10, w=12):
    yy, xx = np.mgrid[0:h, 0:w] / 12.0
    S0 = np.stack([0.4 + 0.1 * xx + 0.05 * k for k in range(3)], -1)
    S1 = 0.15 * np.cos(2 * yy)[..., None] * S0
    S2 = 0.15 * np.sin(2 * yy + 0.5)[..., None] * S0
    return S0, S1, S2


def _behind(S, angle, eps=0.0, offset=0.0):
    """Intensity behind a real polarizer, written out from its transmittances: a fraction
    t_max of the light polarized along its axis and t_min across it, normalized so that
    unpolarized light passes 1/2 (t_max + t_min = 1)."""
    t_max, t_min = 1.0 / (1.0 + eps), eps / (1.0 + eps)
    th = np.radians(angle + offset)
    along = 0.5 * (S[0] + S[1] * np.cos(2 * th) + S[2] * np.sin(2 * th))   # ideal, along the axis
    across = S[0] - along
    return t_max * along + t_min * across


def test_dark_and_flat_undo_gain_times_signal_plus_dark(tmp_path):
    """raw = gain x response x signal + dark (separate layout, 16-bit): with the dark frame, the
    flat field and the gains the import gives the signal back."""
    S = _stokes()
    h, w = S[0].shape[:2]
    yy, xx = np.mgrid[0:h, 0:w]
    response = (0.8 + 0.4 * xx / w)[..., None] * np.ones(3)        # per pixel, the same in R, G, B
    dark = (200 + 9 * (yy % 3))[..., None] * np.ones(3)
    gain = 40000.0
    files = []
    for a in ANGLES:
        raw = np.rint(gain * response * _behind(S, a) + dark)
        files.append(write_tiff(tmp_path / f"pol{a}.tif", raw.astype(np.uint16)))
    write_tiff(tmp_path / "dark.tif", dark.astype(np.uint16))
    write_tiff(tmp_path / "flat.tif", np.rint(gain * 0.5 * response + dark).astype(np.uint16))
    mean_response = response.mean(axis=(0, 1))                    # the flat is relative to its mean
    g = 65535.0 / gain / mean_response
    assert _run(["import", "polarization", *files, "--layout", "separate", "--angles", "0,45,90,135",
                 "--dark", tmp_path / "dark.tif", "--flat", tmp_path / "flat.tif",
                 "--white-balance", ",".join(repr(float(v)) for v in g), "--out", tmp_path / "ds"]) == 0
    ds = read_dataset(tmp_path / "ds")
    for a in ANGLES:
        np.testing.assert_allclose(ds.polarized_rgb[a], _behind(S, a), atol=3e-5)
    cal = json.loads((tmp_path / "ds" / "meta.json").read_text())["calibration"]
    assert cal["dark"]["role"] == "dark" and cal["flat"]["role"] == "flat"


def test_polarizer_extinction_and_offset_are_corrected_and_recorded(tmp_path):
    """Images behind polarizers of extinction ratio 0.05 whose axes sit 3 degrees off (float
    TIFFs, reflectance units): the import gives the images of ideal polarizers."""
    S = _stokes()
    files = [write_tiff(tmp_path / f"pol{a}.tif", _behind(S, a, 0.05, 3.0).astype(np.float32)) for a in ANGLES]
    args = ["import", "polarization", *files, "--layout", "separate", "--angles", "0,45,90,135",
            "--white-balance", "1,1,1"]
    (tmp_path / "eps.txt").write_text("# measured\n0.05\n")
    assert _run(args + ["--polarizer-extinction", tmp_path / "eps.txt", "--polarizer-offset", "3",
                        "--out", tmp_path / "ds"]) == 0
    assert _run(args + ["--out", tmp_path / "raw"]) == 0
    ds, raw = read_dataset(tmp_path / "ds"), read_dataset(tmp_path / "raw")
    for a in ANGLES:
        ideal = _behind(S, a)
        np.testing.assert_allclose(ds.polarized_rgb[a], ideal, atol=1e-6)
        assert np.abs(raw.polarized_rgb[a] - ideal).max() > 1e-3      # what was corrected
    pol = ds.meta["calibration"]["polarizer"]
    assert pol["extinction_ratio"] == [0.05] * 4 and pol["angle_offset_deg"] == [3.0] * 4
    assert pol["correction"].startswith("captures corrected") and pol["noise_gain_s1_s2"] == pytest.approx(1.05 / 0.95)
    assert any(r["role"] == "polarizer extinction" for r in ds.meta["imported_from"])


def _cube_files(tmp_path, cubes, wl):
    import tifffile

    out = []
    for k, c in enumerate(cubes):
        p = tmp_path / f"cube{k}.tif"
        tifffile.imwrite(p, np.moveaxis(c, -1, 0).astype(np.float32), photometric="minisblack")
        out.append(p)
    return out


def test_spectral_stokes_through_real_polarizers_and_a_flat(tmp_path):
    """Stokes cubes behind polarizers with per-angle extinction and offsets, counts = response x
    white x intensity + dark: --flat, --dark and the polarizer values give the Stokes cube back."""
    import tifffile

    h, w, b = 5, 6, 7
    wl = np.linspace(450, 650, b)
    rng = np.random.default_rng(1)
    S0 = 0.2 + 0.3 * rng.random((h, w, b))
    S1, S2 = 0.2 * S0 * rng.random((h, w, 1)), -0.1 * S0
    white, dark = 5000.0, 100.0
    response = 0.9 + 0.2 * rng.random((h, w, 1))
    eps, off = [0.02, 0.04, 0.03, 0.05], [1.0, -2.0, 0.5, 2.5]
    cubes = [2 * _behind((S0, S1, S2), a, e, d) * response * (white - dark) + dark for a, e, d in zip(ANGLES, eps, off)]
    files = _cube_files(tmp_path, cubes, wl)
    tifffile.imwrite(tmp_path / "flat.tif", (response[..., 0] * 3000 + dark).astype(np.float32))
    # the white target's counts at the mean response (the flat field is relative to its mean)
    np.savetxt(tmp_path / "white.csv", np.c_[wl, np.full(b, (white - dark) * response.mean() + dark)], delimiter=",")
    assert _run(["import", "spectral", *files, "--polarizer", "stokes", "--wavelengths", ",".join(map(str, wl)),
                 "--white", tmp_path / "white.csv", "--dark", dark, "--flat", tmp_path / "flat.tif",
                 "--polarizer-extinction", ",".join(map(str, eps)), "--polarizer-offset", ",".join(map(str, off)),
                 "--out", tmp_path / "ds"]) == 0
    ds = read_dataset(tmp_path / "ds", need=("stokes",))
    for got, want in zip((ds.stokes["S0"], ds.stokes["S1"], ds.stokes["S2"]), (S0, S1, S2)):
        np.testing.assert_allclose(got, want, atol=2e-5)
    cal = ds.meta["calibration"]
    assert cal["polarizer"]["extinction_ratio"] == eps and cal["flat"]["role"] == "flat"


def test_an_s_cube_through_a_real_polarizer_is_recorded_and_every_reader_warns(tmp_path, capsys):
    wl = np.linspace(450, 650, 6)
    files = _cube_files(tmp_path, [np.full((4, 5, 6), 0.3)], wl)
    assert main(["import", "spectral", str(files[0]), "--wavelengths", ",".join(map(str, wl)),
                 "--polarizer-extinction", "0.01", "--out", str(tmp_path / "ds")]) == 0
    assert "cannot be corrected for the polarizer's extinction" in capsys.readouterr().err
    with pytest.warns(ThinfilmWarning, match="estimators model an ideal polarizer"):
        ds = read_dataset(tmp_path / "ds", need=("spectral_s",))
    pol = ds.meta["calibration"]["polarizer"]
    assert pol["angles_deg"] == "s-direction" and pol["extinction_ratio"] == 0.01
    assert pol["correction"].startswith("none")


@pytest.fixture
def bad(tmp_path):
    import tifffile

    f = {"out": tmp_path / "out"}
    f["mosaic"] = write_tiff(tmp_path / "mosaic.tif", np.full((16, 16), 30000, np.uint16))
    zero = np.full((16, 16), 30000, np.uint16)
    zero[5, 7] = 0
    f["flat_zero"] = write_tiff(tmp_path / "flat0.tif", zero)
    f["dark_neg"] = write_tiff(tmp_path / "darkneg.tif", np.full((16, 16), -0.01, np.float32))
    f["mosaic_float"] = write_tiff(tmp_path / "mf.tif", np.full((16, 16), 0.5, np.float32))
    # cubes of 4 bands (TIFF pages) of 6 x 5 pixels
    tifffile.imwrite(tmp_path / "cube.tif", np.full((4, 6, 5), 0.3, np.float32), photometric="minisblack")
    f["cube"] = tmp_path / "cube.tif"
    tifffile.imwrite(tmp_path / "flat_small.tif", np.ones((4, 6, 3), np.float32), photometric="minisblack")
    f["cube_flat_small"] = tmp_path / "flat_small.tif"
    cz = np.ones((4, 6, 5), np.float32)
    cz[3, 2, 1] = 0
    tifffile.imwrite(tmp_path / "flat_zero_cube.tif", cz, photometric="minisblack")
    f["cube_flat_zero"] = tmp_path / "flat_zero_cube.tif"
    (tmp_path / "eps_bad.txt").write_text("0.1 0.2\n")
    f["eps_two"] = tmp_path / "eps_bad.txt"
    return f


POL = lambda f: ["import", "polarization", str(f["mosaic"]), "--layout", "dofp-rgb"]  # noqa: E731
SPE = lambda f: ["import", "spectral", str(f["cube"]), "--wavelengths", "400,500,600,700"]  # noqa: E731
BAD = {
    "flat with a zero": lambda f: (POL(f) + ["--flat", str(f["flat_zero"])], "positive everywhere"),
    "negative dark frame": lambda f: (["import", "polarization", str(f["mosaic_float"]), "--layout", "dofp-rgb",
                                       "--dark", str(f["dark_neg"])], "negative values"),
    "negative dark level": lambda f: (POL(f) + ["--dark", "-3"], ">= 0"),
    "non-finite dark level": lambda f: (POL(f) + ["--dark", "nan"], ">= 0"),
    "extinction not finite": lambda f: (POL(f) + ["--polarizer-extinction", "nan"], "finite numbers"),
    "extinction of 1": lambda f: (POL(f) + ["--polarizer-extinction", "1"], "[0, 1)"),
    "negative extinction": lambda f: (POL(f) + ["--polarizer-extinction", "-0.1"], "[0, 1)"),
    "extinction count": lambda f: (POL(f) + ["--polarizer-extinction", str(f["eps_two"])], "2 values for 4"),
    "offset too large": lambda f: (POL(f) + ["--polarizer-offset", "50"], "+-45 degrees"),
    "offset not a number": lambda f: (POL(f) + ["--polarizer-offset", "north"], "numbers"),
    "negative edge margin": lambda f: (POL(f) + ["--edge-margin", "-1"], ">= 0"),
    "edge margin with bilinear": lambda f: (POL(f) + ["--demosaic", "bilinear", "--edge-margin", "2"],
                                            "applies to --demosaic residual"),
    "spectral negative dark": lambda f: (SPE(f) + ["--dark", "-1"], ">= 0"),
    "spectral flat shape": lambda f: (SPE(f) + ["--flat", str(f["cube_flat_small"])], "--flat field has shape"),
    "spectral flat with a zero": lambda f: (SPE(f) + ["--flat", str(f["cube_flat_zero"])], "positive everywhere"),
    "spectral flat with a white cube": lambda f: (SPE(f) + ["--white", str(f["cube"]), "--flat", str(f["cube"])],
                                                  "corrects each pixel's response already"),
    "spectral extinction": lambda f: (SPE(f) + ["--polarizer-extinction", "inf"], "finite numbers"),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_calibration_is_one_line_and_exit_2(bad, case, capsys):
    argv, expected = BAD[case](bad)
    rc = main(argv + ["--out", str(bad["out"])])
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if not ln.startswith("thinfilm: warning:")]
    assert rc == 2, err
    assert len(lines) == 1 and lines[0].startswith("thinfilm: error: "), err
    assert expected in lines[0], lines[0]
    assert not bad["out"].exists()
