"""Evaluation: colour differences, metrics, re-rendering round trips, CLI errors.

References are independent of our code: published CIEDE2000 test pairs (Sharma, Wu,
Dalal 2005), colour-science's documented examples and its own spectral integration,
analytic CIELAB values, hand-computed statistics, and captures predicted straight from the
optics core (checked against tmm) rather than by a second renderer.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from evaluation_synthetic import analytic_stokes, hemisphere_normals, write_synthetic_dataset
from thinfilm import color_difference as cd
from thinfilm import evaluation as ev
from thinfilm.core.film import Film
from thinfilm.core.colorimetry import illuminant_spd, spectra_to_camera_rgb
from thinfilm.core.io import read_exr, write_exr, write_json

WL = np.arange(400.0, 721.0, 4.0)


# -- colour differences ---------------------------------------------------------------------

# Sharma, Wu & Dalal (2005), "The CIEDE2000 color-difference formula: implementation notes,
# supplementary test data", Table 1 (pairs 1, 2, 3, 7, 17, and the pair 50/2.5/0 vs 50/0/-2.5).
SHARMA_PAIRS = [
    ((50.0, 2.6772, -79.7751), (50.0, 0.0, -82.7485), 2.0425),
    ((50.0, 3.1571, -77.2803), (50.0, 0.0, -82.7485), 2.8615),
    ((50.0, 2.8361, -74.0200), (50.0, 0.0, -82.7485), 3.4412),
    ((50.0, 0.0, 0.0), (50.0, -1.0, 2.0), 2.3669),
    ((50.0, 2.5, 0.0), (73.0, 25.0, -18.0), 27.1492),
    ((50.0, 2.5, 0.0), (50.0, 0.0, -2.5), 4.3065),
    ((60.2574, -34.0099, 36.2677), (60.4626, -34.1751, 39.4387), 1.2644),
]


def test_delta_e_2000_matches_sharma_test_data():
    a = np.array([p[0] for p in SHARMA_PAIRS])
    b = np.array([p[1] for p in SHARMA_PAIRS])
    expected = np.array([p[2] for p in SHARMA_PAIRS])
    np.testing.assert_allclose(cd.delta_e_2000(a, b), expected, atol=5e-5)
    # symmetric, and array in / array out with leading dimensions
    np.testing.assert_allclose(cd.delta_e_2000(b.reshape(7, 1, 3), a.reshape(7, 1, 3))[:, 0], expected, atol=5e-5)


def test_delta_e_colour_documented_examples():
    # colour-science's documented examples for delta_E(method="CIE 1976" / "CIE 2000")
    a = np.array([100.00000000, 21.57210357, 272.22819350])
    b = np.array([100.00000000, 426.67945353, 72.39590835])
    assert cd.delta_e_ab(a, b) == pytest.approx(451.7133019, abs=1e-6)
    assert cd.delta_e_2000(a, b) == pytest.approx(94.0356490, abs=1e-6)
    a = np.array([48.99183622, -0.10561667, 400.65619925])
    b = np.array([50.65907324, -0.11671910, 402.82235718])
    assert cd.delta_e_ab(a, b) == pytest.approx(2.7335037, abs=1e-6)
    assert cd.delta_e_2000(a, b) == pytest.approx(1.6709303, abs=1e-6)


def test_delta_e_ab_is_euclidean_in_lab():
    # paper Eq. 31 on a 3-4-12 triangle: sqrt(9 + 16 + 144) = 13
    assert cd.delta_e_ab([50.0, 10.0, -5.0], [53.0, 14.0, 7.0]) == pytest.approx(13.0, abs=1e-12)


def test_spectra_to_lab_white_and_grey_analytic():
    lab = cd.spectra_to_lab(np.stack([np.ones_like(WL), np.full_like(WL, 0.18)]), WL, "D65")
    np.testing.assert_allclose(lab[0], [100.0, 0.0, 0.0], atol=1e-9)
    np.testing.assert_allclose(lab[1], [116.0 * 0.18 ** (1 / 3) - 16.0, 0.0, 0.0], atol=1e-9)


@pytest.mark.parametrize("illuminant", ["D65", "A"])
def test_spectra_to_lab_matches_colour_integration(illuminant):
    import colour

    refl = 0.05 + 0.04 * np.sin(WL / 23.0) + 0.02 * np.cos(WL / 7.0)
    shape = colour.SpectralShape(WL[0], WL[-1], WL[1] - WL[0])
    sd = colour.SpectralDistribution(dict(zip(WL, refl)))
    # Our quadrature is the trapezoid rule (as for camera RGB); colour's "Integration" is a
    # plain sum with constant step, so hand colour the illuminant with halved end bands.
    trapezoid = np.ones_like(WL)
    trapezoid[[0, -1]] = 0.5
    ill = colour.SpectralDistribution(dict(zip(WL, illuminant_spd(illuminant, WL) * trapezoid)))
    cmfs = colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"].copy().align(shape)
    xyz_ref = colour.sd_to_XYZ(sd, cmfs, ill, method="Integration")
    np.testing.assert_allclose(cd.spectra_to_xyz(refl, WL, illuminant), xyz_ref, rtol=1e-10)
    white = colour.sd_to_XYZ(colour.SpectralDistribution(dict(zip(WL, np.ones_like(WL)))),
                             cmfs, ill, method="Integration")
    lab_ref = colour.XYZ_to_Lab(xyz_ref / 100.0, colour.XYZ_to_xy(white / 100.0))
    np.testing.assert_allclose(cd.spectra_to_lab(refl, WL, illuminant), lab_ref, atol=1e-9)


def test_camera_fit_exact_for_a_luther_camera(tmp_path):
    # A camera whose sensitivities are a linear mix of the CMFs satisfies the Luther
    # condition: the fitted matrix must then give exactly the CIELAB of the spectra.
    mix = np.array([[0.9, 0.3, 0.0], [0.2, 1.0, 0.1], [0.0, 0.1, 1.2]])
    grid = np.arange(380.0, 781.0, 1.0)
    sens = cd.cie1931_cmfs(grid) @ mix
    csv = tmp_path / "luther.csv"
    np.savetxt(csv, np.column_stack([grid, sens]), delimiter=",")
    rng = np.random.default_rng(3)
    d = rng.uniform(200, 800, size=(20, 1))
    from thinfilm.bsdf import optics

    rs, rp = optics.reflectances(np.cos(rng.uniform(0, 1.2, size=(20, 1))), WL, d, 1.37, 1.6)
    refl = 0.5 * (rs + rp)
    rgb = spectra_to_camera_rgb(refl, WL, str(csv), "D65")
    np.testing.assert_allclose(cd.camera_rgb_to_lab(rgb, WL, str(csv), "D65"),
                               cd.spectra_to_lab(refl, WL, "D65"), atol=1e-8)


def test_camera_fit_maps_white_to_white():
    m = cd.fit_camera_to_xyz(WL, "Nikon 5100 (NPL)", "D65")
    np.testing.assert_allclose(np.ones(3) @ m, cd.white_xyz(WL, "D65"), rtol=1e-12)
    np.testing.assert_allclose(cd.camera_rgb_to_lab(np.ones(3), WL), [100.0, 0.0, 0.0], atol=1e-9)


# -- statistics and geometry errors -----------------------------------------------------------

def _tilted(zenith_deg, azimuth_deg=30.0):
    t, p = np.radians(zenith_deg), np.radians(azimuth_deg)
    return np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], axis=-1)


def test_metrics_on_hand_made_estimate():
    # 2x3 image: ground truth flat (normal +z, zenith 0), thickness 500 nm; pixel (1, 2) is
    # off the object; pixel (1, 1) is invalid in the estimate.
    gt_mask = np.array([[True, True, True], [True, True, False]])
    gt = {"normal": np.tile([0.0, 0.0, 1.0], (2, 3, 1)), "zenith": np.zeros((2, 3)),
          "thickness": np.full((2, 3), 500.0), "mask": gt_mask}
    est_zen = np.array([[0.0, 10.0, 20.0], [30.0, 99.0, 50.0]])
    from thinfilm.core.io import Estimate

    est = Estimate(_tilted(est_zen), 500.0 + np.array([[5.0, -5.0, 10.0], [0.0, 77.0, 20.0]]),
                   np.array([[True, True, True], [True, False, True]]))
    maps = ev.geometry_error_maps(gt, est)
    mask = gt_mask & est.valid  # scored pixels: errors 0, 10, 20, 30 deg; 5, 5, 10, 0 nm
    m = ev.metrics_from_maps(maps, mask, film_ior_error=0.03)
    # by hand: mean (0+10+20+30)/4 = 15, median 15, p95 = 20 + 0.85*10 = 28.5, max 30
    for key in ("normal_error_deg", "zenith_error_deg"):
        assert m[key]["mean"] == pytest.approx(15.0, abs=1e-9)
        assert m[key]["median"] == pytest.approx(15.0, abs=1e-9)
        assert m[key]["p95"] == pytest.approx(28.5, abs=1e-9)
        assert m[key]["max"] == pytest.approx(30.0, abs=1e-9)
    # |errors| 5, 5, 10, 0: mean 5, median 5, p95 = 5 + 0.85*5 = 9.25, max 10
    assert m["thickness_error_nm"] == pytest.approx({"mean": 5.0, "median": 5.0, "p95": 9.25, "max": 10.0})
    assert m["film_ior_error"] == pytest.approx(0.03)
    assert set(m) == set(ev.METRIC_KEYS) | {"film_ior_error"} | set(ev.BOUND_KEYS)
    assert m["delta_e_ab"] == {"mean": None, "median": None, "p95": None, "max": None}


def test_angular_error_small_angles_and_normalization():
    a = _tilted(np.array([0.0, 1e-4, 45.0]), 0.0)
    b = np.array([[0, 0, 2.0], [0, 0, 1.0], [0, 0, 1.0]])
    np.testing.assert_allclose(ev.angular_error_deg(a, b), [0.0, 1e-4, 45.0], rtol=1e-7, atol=1e-12)


# -- re-rendering ------------------------------------------------------------------------------

@pytest.fixture
def mono_polarized(render_variant):
    return render_variant


def _estimate(path, normals, thickness, valid, info):
    """Write an estimate folder through the real writer."""
    from thinfilm.core.io import Estimate, write_estimate

    info = dict(info)
    path.mkdir(parents=True)
    write_estimate(path, Estimate(normals, thickness, valid, info.pop("film_ior"), info.pop("substrate_ior"),
                                  info=info))


@pytest.mark.parametrize("h, w", [(6, 6), (5, 7), (7, 5)])  # square, wide and tall images
def test_rerender_matches_optics_with_spatially_varying_fields(mono_polarized, h, w):
    rng = np.random.default_rng(7)
    zen = rng.uniform(0.0, 85.0, (h, w))
    az = rng.uniform(0.0, 360.0, (h, w))
    normals = _tilted(zen, az)
    thick = rng.uniform(100.0, 900.0, (h, w))
    valid = np.ones((h, w), bool)
    valid[2, 3] = False
    wl = np.array([420.0, 550.0, 690.0])
    got = ev.render_normal_map(normals, thick, valid, wl, Film.single(1.37, None, 1.6), band_fwhm_nm=0.0)
    ref = analytic_stokes(normals, valid, thick, wl, 1.37, 1.6)
    for s in ("S0", "S1", "S2"):
        np.testing.assert_allclose(got[s], ref[s], atol=2e-6, err_msg=s)
    assert np.all(got["S0"][2, 3] == 0.0)


def test_ground_truth_round_trip_on_analytic_captures(mono_polarized, tmp_path):
    root, n, mask, thick, _ = write_synthetic_dataset(tmp_path / "ds", size=24)
    _estimate(tmp_path / "est", n, thick, mask,
                   {"method": "ground_truth", "film_ior": 1.37, "substrate_ior": 1.6, "timings_s": {}})
    result = ev.evaluate(root, tmp_path / "est", tmp_path / "out")
    m = json.loads((tmp_path / "out" / "metrics.json").read_text())
    assert m == result["metrics"]
    assert m["delta_e_ab"]["mean"] <= 0.1
    assert m["delta_e_ab"]["max"] <= 0.1
    assert m["delta_e_2000"]["max"] <= 0.1
    assert m["spectral_rmse"]["max"] <= 1e-5
    assert m["normal_error_deg"]["max"] <= 1e-3 and m["thickness_error_nm"]["max"] == 0.0
    assert m["film_ior_error"] == 0.0
    assert result["info"]["coverage"] == 1.0
    for name in ("normals.png", "thickness.png", "appearance.png", "errors.png"):
        data = (tmp_path / "out" / name).read_bytes()
        assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 2000, name
    errors = read_exr(tmp_path / "out" / "errors.exr")
    assert set(ev.METRIC_KEYS) <= set(errors)


def test_rgb_only_round_trip_and_appearance_error_of_wrong_thickness(mono_polarized, tmp_path):
    root, n, mask, thick, _ = write_synthetic_dataset(tmp_path / "ds", size=16, parts=("polarized_rgb",))
    _estimate(tmp_path / "gt", n, thick, mask,
                   {"method": "ground_truth", "film_ior": 1.37, "substrate_ior": 1.6, "timings_s": {}})
    r = ev.evaluate(root, tmp_path / "gt")
    assert r["colour_kind"] == "camera_rgb"
    assert r["metrics"]["delta_e_ab"]["max"] <= 0.1
    assert r["metrics"]["spectral_rmse"]["mean"] is None  # no spectra to compare

    # 40 nm too thick, film index 1.40: the ΔE map must equal the ΔE between the analytic
    # appearances (camera RGB of the s-polarized spectra through the fitted matrix).
    _estimate(tmp_path / "off", n, thick + 40.0, mask,
                   {"method": "hand", "film_ior": 1.40, "substrate_ior": 1.6, "timings_s": {}})
    r = ev.evaluate(root, tmp_path / "off")
    wl = np.arange(400.0, 721.0, 16.0)

    def s_rgb(stokes):
        rgb = {k: spectra_to_camera_rgb(v, wl) for k, v in stokes.items()}
        return rgb["S0"] + np.sqrt(rgb["S1"] ** 2 + rgb["S2"] ** 2)

    ref_true = s_rgb(analytic_stokes(n, mask, thick, wl, 1.37, 1.6))
    ref_est = s_rgb(analytic_stokes(n, mask, thick + 40.0, wl, 1.40, 1.6))
    de = cd.delta_e_ab(cd.camera_rgb_to_lab(ref_true, wl), cd.camera_rgb_to_lab(ref_est, wl))
    np.testing.assert_allclose(r["maps"]["delta_e_ab"][mask], de[mask], atol=1e-3)
    assert r["metrics"]["delta_e_ab"]["mean"] == pytest.approx(float(de[mask].mean()), abs=1e-3)
    assert r["metrics"]["delta_e_ab"]["mean"] > 1.0
    assert r["metrics"]["thickness_error_nm"]["max"] == pytest.approx(40.0, abs=1e-3)
    assert r["metrics"]["film_ior_error"] == pytest.approx(0.03, abs=1e-9)


def test_spectral_rmse_is_paper_eq32(mono_polarized, tmp_path):
    root, n, mask, thick, stokes = write_synthetic_dataset(tmp_path / "ds", size=12, parts=("spectral_s",))
    _estimate(tmp_path / "off", n, thick - 25.0, mask,
                   {"method": "hand", "film_ior": 1.37, "substrate_ior": 1.6, "timings_s": {}})
    r = ev.evaluate(root, tmp_path / "off")
    wl = np.arange(400.0, 721.0, 16.0)
    est = analytic_stokes(n, mask, thick - 25.0, wl, 1.37, 1.6)
    r_o = stokes["S0"] + np.hypot(stokes["S1"], stokes["S2"])
    r_e = est["S0"] + np.hypot(est["S1"], est["S2"])
    rmse = np.sqrt(((r_o - r_e) ** 2).sum(axis=-1) / wl.size)  # sqrt(Σ (Ro − Re)² / N)
    np.testing.assert_allclose(r["maps"]["spectral_rmse"][mask], rmse[mask], atol=1e-6)


# -- command line --------------------------------------------------------------------------

def _run_cli(argv, capsys):
    from thinfilm.cli import main

    code = main(argv)
    return code, capsys.readouterr()


def _write_estimate_channels(path, channels, info):
    path.mkdir()
    write_exr(path / "estimate.exr", channels)
    write_json(path / "estimate.json", info)


INFO = {"method": "hand", "film_ior": 1.37, "substrate_ior": 1.6, "timings_s": {}}


def _full_channels(size):
    n, mask = hemisphere_normals(size)
    return {"normal.X": n[..., 0], "normal.Y": n[..., 1], "normal.Z": n[..., 2], "zenith": n[..., 0],
            "azimuth": n[..., 0], "thickness": np.full((size, size), 400.0),
            "valid": mask.astype(np.float32)}


@pytest.mark.parametrize("case", ["missing_channel", "wrong_size", "no_film_ior", "nan_in_valid"])
def test_cli_bad_estimate_one_line_exit_2(tmp_path, capsys, case):
    root, *_ = write_synthetic_dataset(tmp_path / "ds", size=12, parts=("spectral_s",))
    channels, info = _full_channels(12), dict(INFO)
    expect = {"missing_channel": "missing channel 'thickness'", "wrong_size": "10x10 pixels",
              "no_film_ior": "'film_ior'", "nan_in_valid": "NaN"}[case]
    if case == "missing_channel":
        del channels["thickness"]
    elif case == "wrong_size":
        channels = _full_channels(10)
    elif case == "no_film_ior":
        del info["film_ior"]
    else:
        channels["thickness"][6, 6] = np.nan
    _write_estimate_channels(tmp_path / "est", channels, info)
    code, cap = _run_cli(["evaluate", str(root), str(tmp_path / "est"), "--out", str(tmp_path / "out")], capsys)
    assert code == 2
    lines = cap.err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("thinfilm: error:") and expect in lines[0], cap.err
    assert "Traceback" not in cap.err
    assert not (tmp_path / "out").exists()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".out")]


def test_cli_evaluate_writes_metrics(tmp_path, capsys):
    root, n, mask, thick, _ = write_synthetic_dataset(tmp_path / "ds", size=12, parts=("spectral_s",))
    _estimate(tmp_path / "est", n, thick, mask, dict(INFO))
    code, cap = _run_cli(["evaluate", str(root), str(tmp_path / "est"), "--out", str(tmp_path / "out")], capsys)
    assert code == 0, cap.err
    m = json.loads((tmp_path / "out" / "metrics.json").read_text())
    assert set(m) == set(ev.METRIC_KEYS) | {"film_ior_error"} | set(ev.BOUND_KEYS) | set(ev.CALIBRATION_KEYS)
    for key in ev.METRIC_KEYS:
        assert set(m[key]) == {"mean", "median", "p95", "max"}
    assert m["delta_e_ab"]["mean"] <= 0.1
    assert "metrics.json" in cap.out


@pytest.mark.slow
@pytest.mark.parametrize("preset", ["hemisphere", "cylinder", "pyramid"])
def test_ground_truth_round_trip_on_generated_preset(mono_polarized, tmp_path, preset):
    # The acceptance check: the generator's noise-free captures of a preset are
    # reproduced by re-rendering the ground truth (mean ΔE*ab <= 0.1).
    from thinfilm.generators.generate import generate_dataset
    from thinfilm.generators.spec import load_spec
    from thinfilm.core.io import read_dataset

    spec = load_spec(preset, overrides=["noise.model=none"], resolution=24)
    generate_dataset(spec, tmp_path / "ds", progress=False)
    ds = read_dataset(tmp_path / "ds", need=("ground_truth", "spectral_s"))
    gt = ds.ground_truth
    _estimate(tmp_path / "gt", gt["normal"], gt["thickness"], gt["mask"],
                   {"method": "ground_truth", "film_ior": ds.meta["film_ior"],
                    "substrate_ior": ds.meta["substrate_ior"], "timings_s": {}})
    m = ev.evaluate(tmp_path / "ds", tmp_path / "gt")["metrics"]
    assert m["delta_e_ab"]["mean"] <= 0.1
    assert m["delta_e_ab"]["max"] <= 0.1
    assert m["spectral_rmse"]["max"] <= 1e-4
    assert gt["mask"].sum() > 100


def test_dataset_without_ground_truth_scores_appearance_only(mono_polarized, tmp_path):
    root, n, mask, thick, _ = write_synthetic_dataset(tmp_path / "ds", size=12, parts=("spectral_s",))
    (root / "ground_truth.exr").unlink()  # a capture of a real object: no truth
    _estimate(tmp_path / "est", n, thick, mask, dict(INFO))
    r = ev.evaluate(root, tmp_path / "est", tmp_path / "out")
    m = r["metrics"]
    assert m["normal_error_deg"]["mean"] is None and m["thickness_error_nm"]["mean"] is None
    assert m["delta_e_ab"]["max"] <= 0.1
    assert r["info"]["scored_pixels"] == int(mask.sum())
    assert (tmp_path / "out" / "appearance.png").is_file()
    assert not (tmp_path / "out" / "normals.png").exists()
