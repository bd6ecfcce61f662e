"""Capture generator end to end: physics against tmm, ground truth against analytic
geometry, polarizer consistency, determinism, mesh specs, normal-map re-rendering."""

from __future__ import annotations

import math

import numpy as np
import pytest

from _gen_fixtures import interior_pixels, make_dataset, pixel_centres, small_spec, tmm_band, tmm_rs_rp

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module", autouse=True)
def mono_polarized(render_variant_module):
    """The generator's variant for every test of the module."""
    return render_variant_module


@pytest.fixture(scope="module")
def datasets(tmp_path_factory, mono_polarized):
    """Noise-free datasets of the three presets (small)."""
    out = {}
    for preset, res in (("hemisphere", 40), ("cylinder", 32), ("pyramid", 32)):
        out[preset] = make_dataset(tmp_path_factory, preset, small_spec(preset, res))
    return out


def _angle_deg(a, b):
    """Angle between unit vectors, accurate for tiny angles (atan2 of |a x b| and a . b)."""
    return np.degrees(np.arctan2(np.linalg.norm(np.cross(a, b), axis=-1), np.sum(a * b, axis=-1)))


def _optics(ds):
    return ds.meta["film_ior"], ds.meta["substrate_ior"]


# --- physics: spectral_s against tmm -------------------------------------------------------

@pytest.mark.parametrize("preset", ["hemisphere", "cylinder", "pyramid"])
def test_spectral_s_matches_tmm_point_values_within_2_percent(datasets, preset):
    """R_s from tmm at the ground-truth zenith and thickness, at the band centres.

    The dataset's bands are Gaussian passbands (FWHM 4 nm), which damp the thin-film fringes
    by exp(-(a sigma)^2 / 2) (a = phase rate): well under 2 % here. The exact band-integrated
    comparison is the next test."""
    ds = datasets[preset]
    gt = ds.ground_truth
    n_film, n_sub = _optics(ds)
    wl = ds.wavelengths_nm
    rows, cols = interior_pixels(gt["mask"] & (gt["zenith"] < 75), 12)
    worst = 0.0
    for r, c in zip(rows, cols):
        ref = np.array([tmm_rs_rp(gt["zenith"][r, c], lam, gt["thickness"][r, c], n_film, n_sub)[0]
                        for lam in wl])
        got = ds.spectral_s[r, c]
        worst = max(worst, float(np.max(np.abs(got - ref) / ref)))
    assert worst < 0.02, worst


@pytest.mark.parametrize("preset", ["hemisphere", "pyramid"])
def test_band_integrated_spectral_s_and_stokes_match_tmm(datasets, preset):
    """Against tmm integrated over the same Gaussian passband (dense sum): the renderer's
    band quadrature is exact to float32 precision; S0 = (Rs + Rp)/2 and
    S1 = -(Rs - Rp)/2 cos 2 phi, S2 = -(Rs - Rp)/2 sin 2 phi (s-direction at phi + 90)."""
    ds = datasets[preset]
    gt = ds.ground_truth
    n_film, n_sub = _optics(ds)
    wl = ds.wavelengths_nm
    fwhm = ds.meta["band_fwhm_nm"]
    bands = np.arange(0, wl.size, 10)
    rows, cols = interior_pixels(gt["mask"] & (gt["zenith"] > 5) & (gt["zenith"] < 70), 4, seed=1)
    for r, c in zip(rows, cols):
        z, t, phi = gt["zenith"][r, c], gt["thickness"][r, c], math.radians(gt["azimuth"][r, c])
        for b in bands:
            rs = tmm_band(z, wl[b], fwhm, t, n_film, n_sub, "s")
            rp = tmm_band(z, wl[b], fwhm, t, n_film, n_sub, "p")
            assert ds.spectral_s[r, c, b] == pytest.approx(rs, rel=2e-4, abs=2e-6)
            assert ds.stokes["S0"][r, c, b] == pytest.approx(0.5 * (rs + rp), rel=2e-4, abs=2e-6)
            lin = 0.5 * (rs - rp)
            assert ds.stokes["S1"][r, c, b] == pytest.approx(-lin * math.cos(2 * phi), abs=2e-5)
            assert ds.stokes["S2"][r, c, b] == pytest.approx(-lin * math.sin(2 * phi), abs=2e-5)


def test_absorbing_substrate_warns_and_spectral_s_is_the_larger_of_rs_and_rp(tmp_path):
    """On an absorbing substrate R_p exceeds R_s in places (the film's s fringes dip deeper), so
    the rotating-polarizer capture S0 + sqrt(S1² + S2²) = max(R_s, R_p) is no longer R_s: the
    generator says so on stderr, and the data are what it says (tmm, band-integrated)."""
    from thinfilm.core.io import read_dataset
    from thinfilm.generators.generate import generate_dataset

    from thinfilm.core.errors import ThinfilmWarning

    with pytest.warns(ThinfilmWarning, match=r"max\(R_s, R_p\), not R_s") as record:
        spec = small_spec("hemisphere", 24, extra=("substrate.k=2.0",))
    assert len(record) == 1
    generate_dataset(spec, tmp_path / "out", progress=False)
    ds = read_dataset(tmp_path / "out", need=("ground_truth", "spectral_s"))
    assert ds.meta["substrate_k"] == 2.0
    gt = ds.ground_truth
    n_film, n_sub = _optics(ds)
    wl = ds.wavelengths_nm
    fwhm = ds.meta["band_fwhm_nm"]
    rows, cols = interior_pixels(gt["mask"] & (gt["zenith"] > 40) & (gt["zenith"] < 65), 3)
    p_larger = 0
    for r, c in zip(rows, cols):
        z, t = gt["zenith"][r, c], gt["thickness"][r, c]
        for b in range(0, wl.size, 6):
            rs = tmm_band(z, wl[b], fwhm, t, n_film, n_sub, "s", k_sub=2.0)
            rp = tmm_band(z, wl[b], fwhm, t, n_film, n_sub, "p", k_sub=2.0)
            assert ds.spectral_s[r, c, b] == pytest.approx(max(rs, rp), rel=2e-4, abs=2e-6)
            p_larger += rp > rs + 0.005
    assert p_larger >= 3  # bands where the capture is R_p, clearly not R_s


# --- ground truth --------------------------------------------------------------------------

def test_hemisphere_ground_truth_matches_analytic_sphere(datasets):
    ds = datasets["hemisphere"]
    gt = ds.ground_truth
    x, y = pixel_centres(ds.meta, gt["mask"].shape)
    r2 = x ** 2 + y ** 2  # radius 1
    inside = r2 < 1 - 1e-4
    outside = r2 > 1 + 1e-4
    assert np.all(gt["mask"][inside]) and not np.any(gt["mask"][outside])
    analytic = np.stack([x, y, np.sqrt(np.clip(1 - r2, 0, None))], axis=-1)
    m = gt["mask"]
    err_deg = _angle_deg(gt["normal"][m], analytic[m])
    # float32 normals of Mitsuba's analytic sphere: exact up to float32 rounding.
    assert err_deg.max() < 1e-3
    assert np.median(err_deg) < 1e-4
    # depth: camera plane to the sphere surface
    height = ds.meta["projection"]["camera_z"] - gt["depth"][m]
    np.testing.assert_allclose(height, analytic[m][:, 2], atol=1e-4)
    np.testing.assert_array_equal(gt["thickness"][m], 400.0)


def test_cylinder_and_pyramid_ground_truth_analytic(datasets):
    ds = datasets["cylinder"]
    gt = ds.ground_truth
    x, y = pixel_centres(ds.meta, gt["mask"].shape)
    m = gt["mask"]
    inside = (np.abs(x) < 1 - 1e-4) & (np.abs(y) < 1 - 1e-4)
    assert np.all(m[inside]) and not np.any(m[(np.abs(x) > 1 + 1e-4) | (np.abs(y) > 1 + 1e-4)])
    analytic = np.stack([x, np.zeros_like(x), np.sqrt(np.clip(1 - x ** 2, 0, None))], axis=-1)
    np.testing.assert_allclose(gt["normal"][m], analytic[m], atol=2e-4)
    # linear thickness 420 -> 560 nm across the object's extent x in [-1, 1]
    np.testing.assert_allclose(gt["thickness"][m], (420 + 140 * (x + 1) / 2)[m], atol=1e-3)

    ds = datasets["pyramid"]
    gt = ds.ground_truth
    x, y = pixel_centres(ds.meta, gt["mask"].shape)
    m = gt["mask"] & (np.abs(np.abs(x) - np.abs(y)) > 1e-3)
    b, h = 1.0, 0.6  # half base, height
    nx = np.where(np.abs(x) > np.abs(y), np.sign(x) * h, 0.0)
    ny = np.where(np.abs(y) > np.abs(x), np.sign(y) * h, 0.0)
    analytic = np.stack([nx, ny, np.full_like(x, b)], axis=-1) / math.hypot(h, b)
    np.testing.assert_allclose(gt["normal"][m], analytic[m], atol=1e-5)
    np.testing.assert_allclose(gt["zenith"][m], math.degrees(math.atan2(h, b)), atol=1e-3)
    # radial 690 nm at the centre -> 400 nm at the base corners (distance sqrt 2)
    r = np.hypot(x, y) / math.sqrt(2)
    np.testing.assert_allclose(gt["thickness"][m], (690 - 290 * r)[m], atol=1e-3)


@pytest.mark.parametrize("preset", ["hemisphere", "cylinder", "pyramid"])
def test_zenith_azimuth_agree_with_normals(datasets, preset):
    gt = datasets[preset].ground_truth
    m = gt["mask"]
    n = gt["normal"][m]
    np.testing.assert_allclose(np.linalg.norm(n, axis=-1), 1.0, atol=1e-5)
    assert np.all(n[:, 2] > 0)
    z = np.radians(gt["zenith"][m])
    a = np.radians(gt["azimuth"][m])
    rebuilt = np.stack([np.sin(z) * np.cos(a), np.sin(z) * np.sin(a), np.cos(z)], axis=-1)
    np.testing.assert_allclose(rebuilt, n, atol=1e-4)
    assert gt["azimuth"].min() >= 0 and gt["azimuth"].max() < 360


def test_rendered_object_is_the_ground_truth_mask(datasets):
    for ds in datasets.values():
        lit = ds.stokes["S0"].max(axis=-1) > 0
        np.testing.assert_array_equal(lit, ds.ground_truth["mask"])


# --- polarizer images ----------------------------------------------------------------------

@pytest.mark.parametrize("preset", ["hemisphere", "pyramid"])
def test_polarizer_images_form_one_stokes_state(datasets, preset):
    rgb = datasets[preset].polarized_rgb
    lhs = rgb[0] + rgb[90]
    rhs = rgb[45] + rgb[135]
    np.testing.assert_allclose(lhs, rhs, rtol=1e-5, atol=1e-7)


def test_white_balance_and_rgb_from_camera_weights(datasets):
    """Polarized RGB equals thinfilm.core.colorimetry applied to I(alpha) spectra."""
    from thinfilm.core.colorimetry import spectra_to_camera_rgb

    ds = datasets["cylinder"]
    s = ds.stokes
    for a, img in ds.polarized_rgb.items():
        t = math.radians(a)
        spectrum = 0.5 * (s["S0"] + math.cos(2 * t) * s["S1"] + math.sin(2 * t) * s["S2"])
        ref = spectra_to_camera_rgb(spectrum, ds.wavelengths_nm, ds.meta["camera"], ds.meta["illuminant"])
        np.testing.assert_allclose(img, ref, rtol=1e-5, atol=1e-7)


# --- determinism and noise -----------------------------------------------------------------

FILES = ("scene.toml", "meta.json", "ground_truth.exr", "polarized_rgb.exr", "spectral_s.exr",
         "stokes_spectral.exr", "preview.png")


def test_same_seed_same_bytes_other_seed_other_noise(tmp_path):
    from thinfilm.generators.generate import generate_dataset
    from thinfilm.generators.spec import load_spec

    spec = small_spec("cylinder", 24, noise="camera", seed=7)
    a, b, c = tmp_path / "a", tmp_path / "b", tmp_path / "c"
    generate_dataset(spec, a, progress=False)
    generate_dataset(spec, b, progress=False)
    generate_dataset(small_spec("cylinder", 24, noise="camera", seed=8), c, progress=False)
    for name in FILES:
        assert (a / name).read_bytes() == (b / name).read_bytes(), name
    for name in ("polarized_rgb.exr", "spectral_s.exr", "stokes_spectral.exr"):
        assert (a / name).read_bytes() != (c / name).read_bytes(), name
    assert (a / "ground_truth.exr").read_bytes() == (c / "ground_truth.exr").read_bytes()
    # The written scene.toml regenerates the same dataset.
    d = tmp_path / "d"
    generate_dataset(load_spec(a / "scene.toml"), d, progress=False)
    for name in FILES:
        assert (a / name).read_bytes() == (d / name).read_bytes(), name
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a", "b", "c", "d"]  # no temp folders left


def test_same_bytes_with_one_thread_or_all_cores(tmp_path):
    """A Dask worker's thread budget (one thread per worker on a full machine) sizes Dr.Jit's
    and OpenEXR's pools and the noise threads; the dataset is the same bytes either way."""
    from thinfilm.core.threads import set_thread_budget, thread_budget
    from thinfilm.generators.generate import generate_dataset

    spec = small_spec("cylinder", 24, noise="camera", seed=7)
    try:
        set_thread_budget(1)
        assert thread_budget() == 1
        generate_dataset(spec, tmp_path / "one", progress=False)
    finally:
        set_thread_budget(None)
    generate_dataset(spec, tmp_path / "all", progress=False)
    for name in FILES:
        assert (tmp_path / "one" / name).read_bytes() == (tmp_path / "all" / name).read_bytes(), name


def test_camera_noise_is_unbiased_and_scaled_by_exposure(tmp_path):
    from thinfilm.core.io import read_dataset
    from thinfilm.generators.generate import generate_dataset

    exact = tmp_path / "exact"
    noisy = tmp_path / "noisy"
    generate_dataset(small_spec("hemisphere", 32), exact, progress=False)
    generate_dataset(small_spec("hemisphere", 32, noise="camera", seed=3), noisy, progress=False)
    e = read_dataset(exact, need=("ground_truth", "spectral_s", "polarized_rgb"))
    n = read_dataset(noisy, need=("spectral_s", "polarized_rgb"))
    m = e.ground_truth["mask"]
    diff = (n.spectral_s - e.spectral_s)[m]
    rel = diff / e.spectral_s[m]
    # Each I(alpha) image peaks at 90 % of a 10000 e- well: per-image SNR of order 100 at the
    # brightest pixel, lower elsewhere; the noise is there, small and unbiased.
    assert 1e-3 < np.std(rel) < 0.1
    assert abs(np.mean(diff)) < 0.1 * np.std(diff)
    assert not np.array_equal(n.polarized_rgb[0], e.polarized_rgb[0])


# --- mesh specs ----------------------------------------------------------------------------

def test_mesh_spec_renders_with_its_shading_normals(tmp_path):
    import trimesh

    from thinfilm.core.io import read_dataset
    from thinfilm.generators.generate import generate_dataset
    from thinfilm.generators.spec import load_spec

    trimesh.creation.icosphere(subdivisions=4, radius=2.0).export(tmp_path / "ball.ply")
    spec_path = tmp_path / "ball.toml"
    spec_path.write_text(
        '[shape]\nkind = "mesh"\npath = "ball.ply"\nscale = 0.5\n\n'
        '[film]\nior = 1.38\n[film.thickness]\nprofile = "linear"\nstart = 300.0\nend = 500.0\naxis = "y"\n\n'
        '[substrate]\nior = 1.55\n\n[rig]\nresolution = 32\n\n[noise]\nmodel = "none"\n')
    spec = load_spec(spec_path)
    assert spec.shape.params["path"] == str((tmp_path / "ball.ply").resolve())
    generate_dataset(spec, tmp_path / "out", progress=False)
    ds = read_dataset(tmp_path / "out", need=("ground_truth", "spectral_s"))
    gt = ds.ground_truth
    m = gt["mask"]
    assert m.sum() > 0.5 * math.pi * (0.9 * 16) ** 2
    # Smooth shading normals of a subdivided icosphere: close to the sphere's.
    x, y = pixel_centres(ds.meta, m.shape)
    zc = ds.meta["projection"]["camera_z"] - gt["depth"]
    p = np.stack([x, y, zc - 1.0], axis=-1)  # mesh lowered to z >= 0: centre at z = 1
    p /= np.linalg.norm(p, axis=-1, keepdims=True)
    err = _angle_deg(p, gt["normal"])[m]
    assert np.median(err) < 1.0
    # thickness runs bottom (300) to top (500) across the object
    ys = y[m]
    np.testing.assert_allclose(gt["thickness"][m], 300 + 200 * (ys + 1) / 2, atol=0.5)
    # physics at the shading normal the renderer used
    rows, cols = interior_pixels(m & (gt["zenith"] < 60), 5)
    for r, c in zip(rows, cols):
        for b in (0, 40, 80):
            lam = ds.wavelengths_nm[b]
            rs = tmm_band(gt["zenith"][r, c], lam, 4.0, gt["thickness"][r, c], 1.38, 1.55, "s")
            assert ds.spectral_s[r, c, b] == pytest.approx(rs, rel=2e-4, abs=2e-6)


# --- dome with a camera hole ---------------------------------------------------------------

def test_dome_hole_darkens_only_reflections_towards_the_camera(tmp_path):
    from thinfilm.generators.render import render_stokes_cube
    from thinfilm.generators.scene import build_scene

    wl = np.array([450.0, 550.0])
    spec_open = small_spec("hemisphere", 40)
    spec_hole = small_spec("hemisphere", 40, extra=["rig.dome_hole_deg=20"])
    d_open, gt = build_scene(spec_open)
    d_hole, _ = build_scene(spec_hole)
    a = render_stokes_cube(d_open, wl, 0.0)
    b = render_stokes_cube(d_hole, wl, 0.0)
    m = gt["mask"]
    # reflected ray of a view ray along -z leaves at 2 * zenith from the camera direction
    away = 2 * gt["zenith"]
    dark = m & (away < 20 - 0.5)
    lit = m & (away > 20 + 0.5)
    assert dark.sum() > 10 and lit.sum() > 100
    assert np.all(b["S0"][dark] == 0)
    np.testing.assert_allclose(b["S0"][lit], a["S0"][lit], rtol=1e-6)


# --- re-rendering a normal/thickness field -------------------------------------------------

@pytest.mark.parametrize("preset", ["hemisphere", "cylinder", "pyramid"])
def test_normal_map_scene_reproduces_the_dataset(datasets, preset):
    from thinfilm.generators.render import render_stokes_cube
    from thinfilm.generators.scene import normal_map_scene

    ds = datasets[preset]
    gt = ds.ground_truth
    scene = normal_map_scene(gt["normal"], gt["thickness"], gt["mask"], ds.film(),
                             dome_hole_deg=ds.meta["dome_hole_deg"])
    out = render_stokes_cube(scene, ds.wavelengths_nm, ds.meta["band_fwhm_nm"], ds.meta["passband"])
    np.testing.assert_array_equal(out["mask"], gt["mask"])
    for s in ("S0", "S1", "S2"):
        np.testing.assert_allclose(out[s], ds.stokes[s], atol=3e-5)


def test_dataset_meta_and_format(datasets):
    ds = datasets["hemisphere"]
    meta = ds.meta
    assert meta["format"] == "thinfilm-dataset/1"
    assert meta["wavelengths_nm"][0] == 400.0 and meta["wavelengths_nm"][-1] == 720.0
    assert len(meta["wavelengths_nm"]) == 81
    assert meta["polarizer_angles_deg"] == [0, 45, 90, 135]
    assert meta["camera"] == "Nikon 5100 (NPL)" and meta["illuminant"] == "D65"
    assert meta["film_ior"] == 1.37 and meta["substrate_ior"] == 1.6
    assert meta["projection"]["type"] == "orthographic"
    assert meta["noise"]["model"] == "none" and meta["seed"] == 0
    assert set(meta["versions"]) >= {"thinfilm", "mitsuba"}
    assert (ds.path / "preview.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_flat_shaded_rotated_box_mesh_has_exact_face_normals(tmp_path):
    """An .obj box, rotated (x, then y, then z) and flat shaded: every visible pixel's
    ground-truth normal is one of the rotated face normals, and the pixel renders."""
    import trimesh

    from thinfilm.generators.render import render_stokes_cube
    from thinfilm.generators.scene import build_scene
    from thinfilm.generators.spec import load_spec

    trimesh.creation.box(extents=[1.0, 1.5, 0.8]).export(tmp_path / "box.obj")
    spec = load_spec({"shape": {"kind": "mesh", "path": str(tmp_path / "box.obj"), "smooth": False,
                                "rotate_deg": [25.0, -35.0, 10.0]},
                      "rig": {"resolution": 24}, "noise": {"model": "none"}})
    scene_dict, gt = build_scene(spec)
    ax, ay, az = np.radians([25.0, -35.0, 10.0])
    rx = np.array([[1, 0, 0], [0, math.cos(ax), -math.sin(ax)], [0, math.sin(ax), math.cos(ax)]])
    ry = np.array([[math.cos(ay), 0, math.sin(ay)], [0, 1, 0], [-math.sin(ay), 0, math.cos(ay)]])
    rz = np.array([[math.cos(az), -math.sin(az), 0], [math.sin(az), math.cos(az), 0], [0, 0, 1]])
    rot = rz @ ry @ rx
    faces = np.concatenate([rot.T, -rot.T])  # rotated +-x, +-y, +-z
    m = gt["mask"]
    n = gt["normal"][m]
    best = np.min(_angle_deg(n[:, None, :], faces[None, :, :]), axis=1)
    assert m.sum() > 100
    assert best.max() < 1e-3
    seen = {int(i) for i in np.argmin(_angle_deg(n[:, None, :], faces[None, :, :]), axis=1)}
    assert len(seen) == 3  # three faces of a box turned towards the camera
    out = render_stokes_cube(scene_dict, np.array([500.0]), 0.0)
    np.testing.assert_array_equal(out["mask"], m)
    assert np.all(out["S0"][m] > 0)


def test_bitmap_thickness_is_what_the_ground_truth_reads(tmp_path):
    from thinfilm.core.io import write_exr
    from thinfilm.generators.scene import build_scene
    from thinfilm.generators.spec import load_spec

    res = 24
    rng = np.random.default_rng(0)
    tmap = (300 + 400 * rng.random((res, res))).astype(np.float32)
    write_exr(tmp_path / "t.exr", {"thickness": tmap})
    spec = load_spec({"film": {"thickness": {"profile": "bitmap", "path": str(tmp_path / "t.exr")}},
                      "rig": {"resolution": res}, "noise": {"model": "none"}})
    _, gt = build_scene(spec)
    m = gt["mask"]
    # bilinear lookup at float32 pixel-centre coordinates: texel weights exact to ~1e-6
    np.testing.assert_allclose(gt["thickness"][m], tmap[m], rtol=1e-5)
    # a bitmap of another size is stretched over the frame (bilinear at pixel centres)
    np.save(tmp_path / "coarse.npy", np.array([[100.0, 300.0], [500.0, 700.0]]))
    spec = load_spec({"film": {"thickness": {"profile": "bitmap", "path": str(tmp_path / "coarse.npy")}},
                      "rig": {"resolution": res}})
    _, gt = build_scene(spec)
    m = gt["mask"]
    assert 100 <= gt["thickness"][m].min() and gt["thickness"][m].max() <= 700
    left_top = gt["thickness"][: res // 2, : res // 2][m[: res // 2, : res // 2]]
    right_bottom = gt["thickness"][res // 2:, res // 2:][m[res // 2:, res // 2:]]
    assert left_top.mean() < 400 < right_bottom.mean()


# --- film stacks -----------------------------------------------------------------------------

STACK_SPEC = """
[shape]
kind = "hemisphere"
[[film.layers]]
ior = "MgF2"
thickness_nm = 95.0
[[film.layers]]
ior = "2.1+0.01i"
thickness_nm = 62.0
[film.thickness]
profile = "radial"
center = 95.0
edge = 60.0
[substrate]
ior = 1.52
[rig]
resolution = 24
band_fwhm_nm = 0.0
[noise]
model = "none"
"""


def test_stack_dataset_matches_tmm_and_keeps_single_film_keys(tmp_path):
    """A two-layer stack whose top layer thins from 95 to 60 nm towards the rim (every layer
    scaled alike): the rendered Stokes cube against tmm's stack at the ground-truth zenith,
    and meta.json with the whole stack and the single-film keys of older readers."""
    import tmm

    from thinfilm.core.io import read_dataset
    from thinfilm.generators.generate import generate_dataset
    from thinfilm.generators.spec import load_spec

    (tmp_path / "s.toml").write_text(STACK_SPEC)
    generate_dataset(load_spec(tmp_path / "s.toml"), tmp_path / "ds", progress=False)
    ds = read_dataset(tmp_path / "ds", need=("ground_truth", "stokes"))
    assert ds.meta["film"]["layers"] == [{"ior": "MgF2", "thickness_nm": 95.0},
                                         {"ior": {"n": 2.1, "k": 0.01}, "thickness_nm": 62.0}]
    assert ds.meta["film_ior"] == "MgF2" and ds.meta["substrate_ior"] == 1.52
    assert not ds.film().is_single
    gt = ds.ground_truth
    n_mgf2 = np.interp(ds.wavelengths_nm, *_mgf2_table())
    rows, cols = interior_pixels(gt["mask"] & (gt["zenith"] < 70), 4)
    checked = 0
    for r, c in zip(rows, cols):
        scale = gt["thickness"][r, c] / 95.0
        assert 60.0 / 95.0 - 1e-6 <= scale <= 1.0 + 1e-6
        for b in (0, 30, 60, 80):
            lam = ds.wavelengths_nm[b]
            nl = [1.0, n_mgf2[b], complex(2.1, 0.01), 1.52]
            dl = [np.inf, 95.0 * scale, 62.0 * scale, np.inf]
            th = np.radians(gt["zenith"][r, c])
            R = [tmm.coh_tmm(pol, nl, dl, th, lam)["R"] for pol in "sp"]
            assert ds.stokes["S0"][r, c, b] == pytest.approx(0.5 * (R[0] + R[1]), rel=1e-4, abs=1e-6)
            checked += 1
    assert checked == 16


def _mgf2_table():
    from thinfilm.bsdf import named_material

    m = named_material("MgF2")
    grid = m.start_nm + m.step_nm * np.arange(len(m.n_values))
    return grid, np.asarray(m.n_values)


def test_single_film_methods_refuse_a_stack_with_one_line(tmp_path, capsys):
    from thinfilm.cli import main
    from thinfilm.generators.generate import generate_dataset
    from thinfilm.generators.spec import load_spec

    (tmp_path / "s.toml").write_text(STACK_SPEC)
    generate_dataset(load_spec(tmp_path / "s.toml"), tmp_path / "ds", progress=False)
    for kind in ("rgb", "spectral"):
        assert main(["reconstruct", kind, str(tmp_path / "ds"), "--out", str(tmp_path / "est")]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "stack of 2 layers" in err[0] and "single film" in err[0]


def test_stack_ground_truth_re_renders_to_the_captures(tmp_path):
    """The evaluation re-renders a stack dataset's ground truth (top-layer thickness, the
    stack scaled with it) back to its noise-free captures."""
    from thinfilm import evaluation as ev
    from thinfilm.core.io import Estimate, read_dataset, write_estimate
    from thinfilm.generators.generate import generate_dataset
    from thinfilm.generators.spec import load_spec

    (tmp_path / "s.toml").write_text(STACK_SPEC)
    generate_dataset(load_spec(tmp_path / "s.toml"), tmp_path / "ds", progress=False)
    gt = read_dataset(tmp_path / "ds", need=("ground_truth",)).ground_truth
    (tmp_path / "gt").mkdir()
    write_estimate(tmp_path / "gt", Estimate(gt["normal"], gt["thickness"], gt["mask"], "MgF2", 1.52))
    m = ev.evaluate(tmp_path / "ds", tmp_path / "gt")["metrics"]
    assert m["delta_e_ab"]["max"] <= 0.05 and m["spectral_rmse"]["max"] <= 1e-5
