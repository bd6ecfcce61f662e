"""Scene specs, bad input on the command line, band quadrature and the noise model
(no rendering except where a command must get past validation)."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest

from thinfilm.cli import main
from thinfilm.core.errors import ThinfilmWarning, UserError
from thinfilm.generators.spec import dump_toml, load_spec, wavelength_grid


# --- specs ---------------------------------------------------------------------------------

@pytest.mark.parametrize("preset", ["hemisphere", "cylinder", "pyramid"])
def test_presets_resolve_and_round_trip_through_toml(preset, tmp_path):
    spec = load_spec(preset)
    path = tmp_path / "s.toml"
    path.write_text(spec.to_toml())
    assert load_spec(path) == spec
    assert load_spec(path).to_toml() == spec.to_toml() == dump_toml(spec.to_dict())


def test_presets_hold_the_papers_objects():
    h, c, p = (load_spec(name).to_dict() for name in ("hemisphere", "cylinder", "pyramid"))
    assert (h["film"]["ior"], h["substrate"]["ior"], h["film"]["thickness"]) == (
        1.37, 1.6, {"profile": "uniform", "value": 400.0})
    assert (c["film"]["ior"], c["substrate"]["ior"]) == (1.37, 1.6)
    assert c["film"]["thickness"] | {} == {"profile": "linear", "start": 420.0, "end": 560.0, "axis": "x"}
    assert (p["film"]["ior"], p["substrate"]["ior"]) == (1.36, 1.5)
    assert (p["film"]["thickness"]["center"], p["film"]["thickness"]["edge"]) == (690.0, 400.0)
    rig = h["rig"]
    wl = wavelength_grid(rig)
    assert wl.size == 81 and wl[0] == 400 and wl[-1] == 720
    assert rig["band_fwhm_nm"] == 4.0 and rig["polarizer_angles_deg"] == [0, 45, 90, 135]
    assert rig["camera"] == "Nikon 5100 (NPL)" and rig["illuminant"] == "D65"


def test_overrides_resolution_and_seed():
    spec = load_spec("hemisphere", overrides=["film.thickness.value=450", "rig.band_fwhm_nm=2",
                                               "noise.model=none"], resolution=48, seed=5).to_dict()
    assert spec["film"]["thickness"]["value"] == 450.0
    assert spec["rig"]["band_fwhm_nm"] == 2.0
    assert spec["rig"]["resolution"] == 48 and spec["seed"] == 5
    assert spec["noise"]["model"] == "none"
    # switching the kind drops the old kind's keys and fills the new defaults
    cyl = load_spec("hemisphere", overrides=["shape.kind=cylinder", "shape.length=3"]).to_dict()
    assert cyl["shape"] == {"kind": "cylinder", "radius": 1.0, "length": 3.0}
    rad = load_spec("hemisphere", overrides=["film.thickness.profile=radial"]).to_dict()
    assert rad["film"]["thickness"]["profile"] == "radial" and "value" not in rad["film"]["thickness"]


def test_film_index_not_below_substrate_warns():
    with pytest.warns(ThinfilmWarning, match="film index 1.7 >= substrate index 1.6") as record:
        load_spec("hemisphere", overrides=["film.ior=1.7"])
    assert len(record) == 1
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        load_spec("hemisphere")


def test_absorbing_substrate_warns_that_spectral_s_is_not_rs():
    with pytest.warns(ThinfilmWarning, match=r"^substrate k = 0.8 > 0") as record:
        load_spec("hemisphere", overrides=["substrate.k=0.8"])
    assert len(record) == 1 and "max(R_s, R_p), not R_s" in str(record[0].message)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        load_spec("hemisphere", overrides=["substrate.k=0"])


def test_warnings_reach_the_command_line_as_one_line(tmp_path):
    # A warning is one line when the command succeeds; when it fails, its error is the only
    # line (the contract of a bad input: exactly one line on stderr).
    import subprocess
    import sys

    blocker = tmp_path / "file"
    blocker.write_text("x")
    argv = [sys.executable, "-m", "thinfilm.cli", "generate", "hemisphere", "--set", "substrate.k=0.8",
            "--resolution", "8", "--set", "rig.wavelengths_nm.step=40"]
    run = subprocess.run([*argv, "--out", str(blocker)], capture_output=True, text=True)
    assert run.returncode == 2
    err = run.stderr.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("thinfilm: error: --out") and "Traceback" not in run.stderr
    run = subprocess.run([*argv, "--out", str(tmp_path / "ds")], capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    err = run.stderr.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("thinfilm: warning: substrate k = 0.8 > 0")
    assert run.stdout.startswith("wrote ")


def test_stack_specs():
    spec = load_spec({"film": {"layers": [{"ior": "MgF2", "thickness_nm": 95}, {"ior": "2.1+0.01i",
                                                                                  "thickness_nm": 62}]}})
    assert [layer.thickness_nm for layer in spec.film.layers] == [95.0, 62.0]
    assert spec.film.layers[1].material.k == 0.01
    assert spec.thickness == {"profile": "uniform", "value": 95.0}   # the top layer's, by default
    assert load_spec(spec.to_dict()) == spec
    with pytest.raises(UserError, match="'film.ior' and 'film.layers' exclude each other"):
        load_spec({"film": {"ior": 1.4, "layers": [{"ior": 1.4, "thickness_nm": 9}]}})
    with pytest.raises(UserError, match=r"'film.layers\[1\].thickness_nm' must be a number > 0"):
        load_spec({"film": {"layers": [{"ior": 1.4, "thickness_nm": 9}, {"ior": 2.0, "thickness_nm": -1}]}})
    with pytest.raises(UserError, match=r"missing key 'film.layers\[0\].ior'"):
        load_spec({"film": {"layers": [{"thickness_nm": 9}]}})


def test_dict_specs_and_named_materials():
    spec = load_spec({"film": {"ior": "MgF2"}, "shape": {"kind": "pyramid"}})
    assert spec.film.layers[0].material.name == "MgF2" and spec.shape.params["base"] == 2.0
    with pytest.raises(UserError, match="film.ior"):
        load_spec({"film": {"ior": "unobtainium"}})


# --- bad input on the command line ---------------------------------------------------------

def _bad_specs(tmp_path):
    unknown_key = tmp_path / "unknown_key.toml"
    unknown_key.write_text('[shape]\nkind = "hemisphere"\nradius = 1.0\ncolour = "red"\n')
    missing_mesh = tmp_path / "missing_mesh.toml"
    missing_mesh.write_text('[shape]\nkind = "mesh"\npath = "nowhere.ply"\n')
    zero_res = tmp_path / "zero_res.toml"
    zero_res.write_text("[rig]\nresolution = 0\n")
    broken = tmp_path / "broken.toml"
    broken.write_text("[shape\nkind = 1\n")
    bad_bitmap = tmp_path / "neg.toml"
    np.save(tmp_path / "neg.npy", -np.ones((4, 4)))
    bad_bitmap.write_text('[film.thickness]\nprofile = "bitmap"\npath = "neg.npy"\n')
    return {
        "unknown preset": (["teapot"], "unknown preset"),
        "unknown key in file": ([str(unknown_key)], "shape.colour"),
        "unknown key in --set": (["hemisphere", "--set", "rig.exposure_time=3"], "rig.exposure_time"),
        "unknown top-level key": (["hemisphere", "--set", "lights.count=3"], "lights"),
        "wrong type": (["hemisphere", "--set", "shape.radius=big"], "shape.radius"),
        "wrong type list": (["hemisphere", "--set", "rig.polarizer_angles_deg=45"], "polarizer_angles_deg"),
        "negative thickness": (["hemisphere", "--set", "film.thickness.value=-5"], "film.thickness.value"),
        "negative linear thickness": (["cylinder", "--set", "film.thickness.start=-1"], "film.thickness.start"),
        "missing mesh": ([str(missing_mesh)], "does not exist"),
        "missing spec file": ([str(tmp_path / "nope.toml")], "not found"),
        "resolution 0 in file": ([str(zero_res)], "rig.resolution"),
        "resolution 0 in --set": (["hemisphere", "--set", "rig.resolution=-3"], "rig.resolution"),
        "negative seed": (["hemisphere", "--seed", "-1"], "seed"),
        "broken toml": ([str(broken)], "not valid TOML"),
        "malformed --set": (["hemisphere", "--set", "film.ior"], "KEY=VALUE"),
        "unknown camera": (["hemisphere", "--set", "rig.camera=Brownie"], "unknown camera"),
        "bad wavelengths": (["hemisphere", "--set", "rig.wavelengths_nm={start=500.0, stop=400.0, step=4.0}"],
                            "wavelengths_nm"),
        "degenerate polarizer angles": (["hemisphere", "--set", "rig.polarizer_angles_deg=[0, 90]"],
                                        "polarizer_angles_deg"),
        "negative bitmap thickness": ([str(bad_bitmap)], "negative thickness"),
    }


def test_every_bad_input_gives_one_line_exit_2_and_no_output(tmp_path, capsys):
    cases = _bad_specs(tmp_path)
    for name, (argv, needle) in cases.items():
        out = tmp_path / "out" / name.replace(" ", "_")
        rc = main(["generate", *argv, "--out", str(out)])
        err = capsys.readouterr().err
        lines = err.strip().splitlines()
        assert rc == 2, name
        assert len(lines) == 1 and lines[0].startswith("thinfilm: error:"), (name, err)
        assert needle in lines[0], (name, lines[0])
        assert "Traceback" not in err
        assert not out.exists(), name
    assert not (tmp_path / "out").exists() or not any((tmp_path / "out").iterdir())


def test_resolution_zero_on_the_command_line_exits_2(tmp_path, capsys):
    with pytest.raises(SystemExit) as e:
        main(["generate", "hemisphere", "--resolution", "0", "--out", str(tmp_path / "o")])
    assert e.value.code == 2
    assert "--resolution" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


def test_refuses_to_replace_a_folder_that_is_not_a_dataset(tmp_path, capsys):
    out = tmp_path / "precious"
    out.mkdir()
    (out / "thesis.tex").write_text("do not delete")
    assert main(["generate", "hemisphere", "--out", str(out)]) == 2
    assert "refusing" in capsys.readouterr().err
    assert (out / "thesis.tex").read_text() == "do not delete"


def test_unreadable_mesh_fails_cleanly(tmp_path, capsys):
    bad = tmp_path / "junk.ply"
    bad.write_text("this is not a mesh\n")
    out = tmp_path / "o"
    rc = main(["generate", "hemisphere", "--set", "shape.kind=mesh", "--set", f"shape.path={str(bad)!r}",
               "--resolution", "8", "--out", str(out)])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "junk.ply" in err[0]
    assert not out.exists() and list(tmp_path.iterdir()) == [bad]


# --- band quadrature -----------------------------------------------------------------------

@pytest.mark.parametrize("a", [0.0, 0.02, 0.075, 0.15, 0.3])
def test_gaussian_passband_quadrature_integrates_fringes(a):
    """Gaussian-weighted mean of cos(a lambda) has the closed form cos(a c) exp(-(a sigma)^2/2)."""
    from thinfilm.core.bands import passband_quadrature

    wl = np.arange(400.0, 721.0, 4.0)
    fwhm = 4.0
    sigma = fwhm / (2 * math.sqrt(2 * math.log(2)))
    sub, w = passband_quadrature(wl, fwhm, "gaussian")
    assert np.allclose(w.sum(axis=1), 1.0) and np.all(w >= 0)
    assert sub.size <= 2 * wl.size + 8  # shared 2 nm lattice, not 5+ renders per band
    got = w @ np.cos(a * sub)
    exact = np.cos(a * wl) * math.exp(-0.5 * (a * sigma) ** 2)
    np.testing.assert_allclose(got, exact, atol=1e-4)


@pytest.mark.parametrize("a", [0.02, 0.075, 0.15])
def test_box_passband_quadrature_integrates_fringes(a):
    from thinfilm.core.bands import passband_quadrature

    wl = np.arange(400.0, 721.0, 4.0)
    width = 4.0
    sub, w = passband_quadrature(wl, width, "box")
    got = w @ np.cos(a * sub)
    exact = np.cos(a * wl) * math.sin(a * width / 2) / (a * width / 2)
    np.testing.assert_allclose(got, exact, atol=(a * 1.0) ** 2 / 24 + 1e-12)


def test_zero_fwhm_point_samples():
    from thinfilm.core.bands import passband_quadrature

    wl = np.array([400.0, 500.0, 600.0])
    sub, w = passband_quadrature(wl, 0.0)
    np.testing.assert_array_equal(sub, wl)
    np.testing.assert_array_equal(w, np.eye(3))


# --- noise model ---------------------------------------------------------------------------

def test_camera_noise_statistics_match_the_model():
    """Fixed exposure: mean x, variance x/g + read^2/g^2 + quantization step^2/12."""
    from thinfilm.generators.noise import apply_camera_noise

    noise = {"model": "camera", "full_well": 10000.0, "read_noise": 5.0, "bits": 12, "exposure": 20000.0}
    x = 0.25
    img = np.full((4, 200, 200), x)
    out = apply_camera_noise(img, np.ones((200, 200), bool), noise, np.random.default_rng(1))
    g = 20000.0
    step = 10000.0 / 4095 / g
    var = x / g + (5.0 / g) ** 2 + step ** 2 / 12
    assert out.mean() == pytest.approx(x, abs=3 * math.sqrt(var / out.size) + step / 2)
    assert out.var() == pytest.approx(var, rel=0.03)
    # quantized to the ADC steps
    np.testing.assert_allclose(out / step, np.rint(out / step), atol=1e-6)


def test_auto_exposure_puts_the_brightest_object_pixel_at_90_percent_of_full_well():
    from thinfilm.generators.noise import apply_camera_noise, exposure_gains

    noise = {"model": "camera", "full_well": 1000.0, "read_noise": 0.0, "bits": 16, "exposure": "auto"}
    img = np.zeros((2, 10, 10))
    img[0, 5, 5], img[1, 2, 2] = 0.04, 0.5
    img[1, 9, 9] = 5.0  # brighter, but outside the object mask
    mask = np.zeros((10, 10), bool)
    mask[:8, :8] = True
    gains = exposure_gains(img, mask, noise)
    np.testing.assert_allclose(gains * [0.04, 0.5], 900.0)
    out = apply_camera_noise(img, mask, noise, np.random.default_rng(0))
    assert out[1, 9, 9] == pytest.approx(1000.0 / gains[1])  # saturated at the full well
    assert np.all(out >= 0)


def test_noise_none_is_exact_and_seeds_reproduce():
    from thinfilm.generators.noise import apply_camera_noise

    img = np.random.default_rng(0).random((3, 8, 8, 3))
    mask = np.ones((8, 8), bool)
    np.testing.assert_array_equal(apply_camera_noise(img, mask, {"model": "none"}, None), img)
    cam = {"model": "camera", "full_well": 5000.0, "read_noise": 3.0, "bits": 10, "exposure": "auto"}
    a = apply_camera_noise(img, mask, cam, np.random.default_rng(4))
    b = apply_camera_noise(img, mask, cam, np.random.default_rng(4))
    c = apply_camera_noise(img, mask, cam, np.random.default_rng(5))
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)
