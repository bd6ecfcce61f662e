"""Every bad input of ``thinfilm import``: one line on stderr, exit code 2, no output folder."""

import numpy as np
import pytest

from _import_helpers import write_png, write_tiff
from thinfilm.cli import main


@pytest.fixture
def files(tmp_path):
    """Good and bad inputs, written once per test."""
    import spectral.io.envi as envi
    import tifffile
    from PIL import Image

    f = {}
    rgb8 = np.full((8, 8, 3), 100, np.uint8)
    for a in (0, 45, 90, 135):
        f[f"rgb{a}"] = write_png(tmp_path / f"rgb{a}.png", rgb8)
    f["rgb_small"] = write_png(tmp_path / "small.png", rgb8[:6])
    f["gray8"] = write_png(tmp_path / "gray8.png", rgb8[..., 0])
    f["mosaic16"] = write_tiff(tmp_path / "mosaic.tif", np.full((16, 16), 30000, np.uint16))
    f["mosaic_small"] = write_tiff(tmp_path / "mosaic_small.tif", np.full((12, 16), 30000, np.uint16))
    f["mosaic_tiny"] = write_tiff(tmp_path / "tiny.tif", np.full((6, 6), 30000, np.uint16))
    f["mosaic8"] = write_png(tmp_path / "mosaic8.png", np.full((16, 16), 100, np.uint8))
    f["mosaic_sat"] = write_tiff(tmp_path / "sat.tif", np.full((16, 16), 65535, np.uint16))
    f["mosaic_zero"] = write_tiff(tmp_path / "zero.tif", np.zeros((16, 16), np.uint16))
    f["rgb16"] = write_tiff(tmp_path / "rgb16.tif", np.full((16, 16, 3), 30000, np.uint16))
    f["rgb16_8"] = write_tiff(tmp_path / "rgb16_8.tif", np.full((8, 8, 3), 30000, np.uint16))
    f["float_nan"] = write_tiff(tmp_path / "nan.tif", np.where(np.eye(16) > 0, np.nan, 0.5).astype(np.float32))
    f["int32"] = write_tiff(tmp_path / "int32.tif", np.full((16, 16), 5, np.int32))
    tifffile.imwrite(tmp_path / "pages.tif", np.zeros((3, 16, 16), np.uint16), photometric="minisblack")
    f["pages"] = tmp_path / "pages.tif"
    Image.fromarray(np.zeros((16, 16), np.uint8)).convert("P").save(tmp_path / "palette.png")
    f["palette"] = tmp_path / "palette.png"
    (tmp_path / "text.png").write_text("not an image")
    f["text"] = tmp_path / "text.png"
    (tmp_path / "trunc.png").write_bytes((tmp_path / "rgb0.png").read_bytes()[:40])
    f["truncated"] = tmp_path / "trunc.png"
    f["missing"] = tmp_path / "nope.png"
    np.savetxt(tmp_path / "bad_refl.csv", [[400, 0.5]], delimiter=",")
    f["bad_refl"] = tmp_path / "bad_refl.csv"
    # cubes
    cube = np.random.default_rng(0).random((5, 6, 8)).astype(np.float32)
    envi.save_image(str(tmp_path / "nowl.hdr"), cube, force=True)
    f["cube_nowl"] = tmp_path / "nowl.hdr"
    envi.save_image(str(tmp_path / "cube.hdr"), cube, force=True,
                    metadata={"wavelength": list(np.linspace(400, 700, 8)), "wavelength units": "nm"})
    f["cube"] = tmp_path / "cube.hdr"
    envi.save_image(str(tmp_path / "other.hdr"), cube[:4], force=True,
                    metadata={"wavelength": list(np.linspace(400, 700, 8)), "wavelength units": "nm"})
    f["cube_other"] = tmp_path / "other.hdr"
    bad = cube.copy()
    bad[1, 1, 1] = np.nan
    envi.save_image(str(tmp_path / "nancube.hdr"), bad, force=True,
                    metadata={"wavelength": list(np.linspace(400, 700, 8)), "wavelength units": "nm"})
    f["cube_nan"] = tmp_path / "nancube.hdr"
    envi.save_image(str(tmp_path / "wn.hdr"), cube, force=True,
                    metadata={"wavelength": list(np.linspace(14000, 25000, 8)), "wavelength units": "wavenumber"})
    f["cube_wavenumber"] = tmp_path / "wn.hdr"
    (tmp_path / "garbage.hdr").write_text("this is not ENVI\n")
    f["cube_garbage"] = tmp_path / "garbage.hdr"
    (tmp_path / "lonely.hdr").write_text((tmp_path / "cube.hdr").read_text())
    f["cube_nodata"] = tmp_path / "lonely.hdr"
    tifffile.imwrite(tmp_path / "cube.tif", np.moveaxis(cube, -1, 0), photometric="minisblack")
    f["cube_tif"] = tmp_path / "cube.tif"
    f["out"] = tmp_path / "out"
    return f


def _rgb(f, *angles):
    return [str(f[f"rgb{a}"]) for a in angles]


POL = ["import", "polarization"]
SPE = ["import", "spectral"]

CASES = {
    # polarization: files
    "missing image": lambda f: (POL + [str(f["missing"]), "--layout", "dofp-rgb"], "file not found"),
    "not an image": lambda f: (POL + [str(f["text"]), "--layout", "dofp-rgb"], "neither a PNG nor a TIFF"),
    "truncated png": lambda f: (POL + [str(f["truncated"]), "--layout", "dofp-rgb"], "truncated"),
    "palette png": lambda f: (POL + [str(f["palette"]), "--layout", "dofp-rgb"], "palette"),
    "int32 tiff": lambda f: (POL + [str(f["int32"]), "--layout", "dofp-rgb"], "int32"),
    "multi-page tiff": lambda f: (POL + [str(f["pages"]), "--layout", "dofp-rgb"], "pages"),
    "float NaN": lambda f: (POL + [str(f["float_nan"]), "--layout", "dofp-rgb"], "NaN"),
    "bit depth above container": lambda f: (POL + [str(f["mosaic8"]), "--layout", "dofp-rgb", "--bit-depth", "12"],
                                            "holds 8-bit samples"),
    "values above bit depth": lambda f: (POL + [str(f["mosaic16"]), "--layout", "dofp-rgb", "--bit-depth", "12"],
                                         "above the largest 12-bit value"),
    "mixed bit depths": lambda f: (POL + [str(f["rgb0"]), str(f["rgb16_8"]), str(f["rgb90"]), "--layout", "separate",
                                          "--angles", "0,45,90"], "holds 8-bit samples"),
    "shapes differ": lambda f: (POL + _rgb(f, 0, 45) + [str(f["rgb_small"]), "--layout", "separate",
                                                          "--angles", "0,45,90"], "shape"),
    "dark shape": lambda f: (POL + [str(f["mosaic16"]), "--layout", "dofp-rgb", "--dark", str(f["mosaic_small"])],
                             "--dark frame has shape"),
    "flat shape": lambda f: (POL + [str(f["mosaic16"]), "--layout", "dofp-rgb", "--flat", str(f["mosaic_small"])],
                             "--flat field has shape"),
    "white reference shape": lambda f: (POL + [str(f["mosaic16"]), "--layout", "dofp-rgb", "--white-reference",
                                               str(f["mosaic_small"])], "--white-reference image has shape"),
    "dark level too high": lambda f: (POL + [str(f["mosaic16"]), "--layout", "dofp-rgb", "--dark", "70000"],
                                      "not below the largest code"),
    "dark of another bit depth": lambda f: (POL + [str(f["mosaic16"]), "--layout", "dofp-rgb", "--dark",
                                                   str(f["mosaic8"])], "bit depth of the images is 16 bits"),
    "saturated white reference": lambda f: (POL + [str(f["mosaic16"]), "--layout", "dofp-rgb", "--white-reference",
                                                   str(f["mosaic_sat"])], "saturated everywhere"),
    "flat at the dark level": lambda f: (POL + [str(f["mosaic16"]), "--layout", "dofp-rgb", "--flat",
                                                str(f["mosaic_zero"])], "at or below the dark level"),
    "everything saturated": lambda f: (POL + [str(f["mosaic_sat"]), "--layout", "dofp-rgb", "--white-balance",
                                              "1,1,1"], "no pixel is usable"),
    "missing dark": lambda f: (POL + [str(f["mosaic16"]), "--layout", "dofp-rgb", "--dark", str(f["missing"])],
                               "file not found"),
    # polarization: layouts and angles
    "fewer than 3 angles": lambda f: (POL + _rgb(f, 0, 90) + ["--layout", "separate", "--angles", "0,90"],
                                      ">= 3 polarizer angles"),
    "duplicate angles": lambda f: (POL + _rgb(f, 0, 45, 90) + ["--layout", "separate", "--angles", "0,90,180"],
                                   "given twice"),
    "angles count": lambda f: (POL + _rgb(f, 0, 45, 90) + ["--layout", "separate", "--angles", "0,45,90,135"],
                               "4 angles for 3 images"),
    "angles not numbers": lambda f: (POL + _rgb(f, 0, 45, 90) + ["--layout", "separate", "--angles", "0,x,90"],
                                     "numbers"),
    "separate without angles": lambda f: (POL + _rgb(f, 0, 45, 90) + ["--layout", "separate"], "needs --angles"),
    "separate with gray": lambda f: (POL + [str(f["gray8"])] * 3 + ["--layout", "separate", "--angles", "0,45,90"],
                                     "needs RGB images"),
    "dofp with RGB": lambda f: (POL + [str(f["rgb16"]), "--layout", "dofp-rgb"], "one channel"),
    "mosaic too small": lambda f: (POL + [str(f["mosaic_tiny"]), "--layout", "dofp-rgb"], "smaller than two periods"),
    "bad pattern": lambda f: (POL + [str(f["mosaic16"]), "--layout", "dofp-rgb", "--pattern", "RGBB:0,45,90,135"],
                              "Bayer order"),
    "pattern missing a colour at an angle": lambda f: (
        POL + [str(f["mosaic16"]), "--layout", "dofp-rgb", "--pattern", "R0 G45 / G90 B135"], "never appears"),
    "pattern with two angles": lambda f: (POL + [str(f["mosaic16"]), "--layout", "dofp-rgb", "--pattern",
                                                 "RGGB:0,90,0,90"], "at least 3 polarizer angles"),
    "both gains and reference": lambda f: (POL + [str(f["mosaic16"]), "--layout", "dofp-rgb", "--white-balance",
                                                  "1,1,1", "--white-reference", str(f["mosaic16"])], "not both"),
    "two gains": lambda f: (POL + [str(f["mosaic16"]), "--layout", "dofp-rgb", "--white-balance", "1,2"],
                            "expected 3 numbers"),
    "negative gain": lambda f: (POL + [str(f["mosaic16"]), "--layout", "dofp-rgb", "--white-balance", "1,-2,1"],
                                "> 0"),
    "reflectance CSV too short": lambda f: (POL + [str(f["mosaic16"]), "--layout", "dofp-rgb", "--white-reference",
                                                   str(f["mosaic16"]), "--white-reflectance", str(f["bad_refl"])],
                                            "at least 2 rows"),
    "unknown camera": lambda f: (POL + [str(f["mosaic16"]), "--layout", "dofp-rgb", "--camera", "Kodak Brownie"],
                                 "unknown camera"),
    "bad wavelengths": lambda f: (POL + [str(f["mosaic16"]), "--layout", "dofp-rgb", "--wavelengths", "700:400:4"],
                                  "START < STOP"),
    "bad film index": lambda f: (POL + [str(f["mosaic16"]), "--layout", "dofp-rgb", "--film-ior", "unobtainium"],
                                 "--film-ior"),
    # spectral
    "ENVI without wavelengths": lambda f: (SPE + [str(f["cube_nowl"])], "give --wavelengths"),
    "TIFF cube without wavelengths": lambda f: (SPE + [str(f["cube_tif"])], "give --wavelengths"),
    "wavelength count": lambda f: (SPE + [str(f["cube"]), "--wavelengths", "400:700:10"], "31 wavelengths for 8 bands"),
    "wavelength units": lambda f: (SPE + [str(f["cube_wavenumber"])], "wavelength units"),
    "ENVI garbage header": lambda f: (SPE + [str(f["cube_garbage"])], "cannot read the ENVI"),
    "ENVI data missing": lambda f: (SPE + [str(f["cube_nodata"])], "cannot read the ENVI"),
    "cube NaN": lambda f: (SPE + [str(f["cube_nan"])], "NaN"),
    "missing cube": lambda f: (SPE + [str(f["missing"])], "file not found"),
    "white shape": lambda f: (SPE + [str(f["cube"]), "--white", str(f["cube_other"])], "reference has shape"),
    "stokes with two cubes": lambda f: (SPE + [str(f["cube"])] * 2 + ["--polarizer", "stokes", "--angles", "0,90"],
                                        ">= 3 polarizer angles"),
    "stokes angle count": lambda f: (SPE + [str(f["cube"])] * 3 + ["--polarizer", "stokes", "--angles", "0,45,90,135"],
                                     "4 angles for 3 cubes"),
    "s with two cubes": lambda f: (SPE + [str(f["cube"])] * 2, "takes one cube"),
    "cube shapes differ": lambda f: (SPE + [str(f["cube"]), str(f["cube_other"]), str(f["cube"]), "--polarizer",
                                            "stokes", "--angles", "0,60,120"], "differs"),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_bad_input_is_one_line_and_exit_2(files, case, capsys):
    argv, expected = CASES[case](files)
    rc = main(argv + ["--out", str(files["out"])])
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if not ln.startswith("thinfilm: warning:")]
    assert rc == 2, err
    assert len(lines) == 1 and lines[0].startswith("thinfilm: error: "), err
    assert expected in lines[0], lines[0]
    assert not files["out"].exists()
