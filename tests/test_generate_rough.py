"""Rough films in the capture generator: ``film.roughness`` in the scene spec, the many-sample
rendering path (pixel-centre rays, varying BSDF samples), its noise against the camera's, its
determinism, the macro-surface ground truth, and the estimators on rough data."""

from __future__ import annotations

import numpy as np
import pytest

from thinfilm.core.errors import UserError

FEW_BANDS = "rig.wavelengths_nm={start = 480.0, stop = 560.0, step = 4.0}"


def _spec(preset="hemisphere", alpha=0.1, resolution=32, noise="camera", seed=0, extra=()):
    from thinfilm.generators.spec import load_spec

    overrides = [f"noise.model={noise}", *extra]
    if alpha:
        overrides.append(f"film.roughness={alpha}")
    return load_spec(preset, overrides=overrides, resolution=resolution, seed=seed)


# -- the spec ----------------------------------------------------------------------------------

def test_roughness_and_spp_round_trip_through_scene_toml(tmp_path):
    from thinfilm.generators.spec import load_spec

    spec = _spec(alpha=0.05, extra=["rig.spp=16"])
    assert spec.roughness == 0.05 and spec.rig.spp == 16
    path = tmp_path / "scene.toml"
    path.write_text(spec.to_toml())
    again = load_spec(path)
    assert again == spec and again.roughness == 0.05 and again.rig.spp == 16
    # A stack takes a roughness too.
    stack = load_spec({"film": {"layers": [{"ior": 1.38, "thickness_nm": 100.0}], "roughness": 0.2}})
    assert stack.roughness == 0.2 and load_spec(stack.to_dict()) == stack
    # Smooth specs (and "auto" spp) write neither key: their scene.toml is as before.
    smooth = load_spec("hemisphere")
    assert smooth.roughness == 0.0 and smooth.rig.spp == "auto"
    assert "roughness" not in smooth.to_toml() and "spp" not in smooth.to_toml()


@pytest.mark.parametrize("item, key", [
    ("film.roughness=-0.1", "film.roughness"), ("film.roughness=1.5", "film.roughness"),
    ("film.roughness=rough", "film.roughness"), ("film.roughness=true", "film.roughness"),
    ("film.roughness=nan", "film.roughness"), ("rig.spp=0", "rig.spp"), ("rig.spp=2.5", "rig.spp"),
    ("rig.spp=many", "rig.spp"), ("rig.spp=5000", "rig.spp"),
])
def test_bad_roughness_and_spp_are_one_line_errors(item, key):
    from thinfilm.generators.spec import load_spec

    with pytest.raises(UserError) as e:
        load_spec("hemisphere", overrides=[item])
    message = str(e.value)
    assert f"'{key}'" in message and "\n" not in message


def test_spp_rule():
    from thinfilm.generators.generate import ROUGH_SPP, rough_spp

    assert rough_spp(_spec(alpha=0.0)) == 1
    assert rough_spp(_spec(alpha=0.0, extra=["rig.spp=16"])) == 1  # smooth: one exact ray
    assert rough_spp(_spec(alpha=0.02)) == rough_spp(_spec(alpha=1.0)) == ROUGH_SPP == 64
    assert rough_spp(_spec(alpha=0.1, noise="none")) == ROUGH_SPP
    # Deeper wells have less shot noise: more samples, a power of 4.
    assert rough_spp(_spec(alpha=0.1, extra=["noise.full_well=20000"])) == 256
    assert rough_spp(_spec(alpha=0.1, extra=["noise.full_well=1e6"])) == 1024
    assert rough_spp(_spec(alpha=0.1, extra=["rig.spp=100"])) == 100


def test_rough_integrator_is_one_bounce_only_for_convex_shapes(tmp_path):
    from thinfilm.generators.scene import BSDF_SAMPLING_INTEGRATOR, rough_integrator
    from thinfilm.generators.spec import load_spec

    for preset in ("hemisphere", "cylinder", "pyramid"):
        assert rough_integrator(_spec(preset)) == BSDF_SAMPLING_INTEGRATOR
    import trimesh

    trimesh.creation.annulus(0.5, 1.0, 0.3).export(tmp_path / "ring.ply")
    mesh = load_spec({"shape": {"kind": "mesh", "path": str(tmp_path / "ring.ply")},
                      "film": {"roughness": 0.1}, "rig": {"max_depth": 4}})
    assert rough_integrator(mesh) == {"type": "path", "max_depth": 4, "hide_emitters": True}


# -- the many-sample path ----------------------------------------------------------------------

@pytest.mark.parametrize("preset, extra", [
    ("hemisphere", ["film.thickness.profile=linear", "rig.dome_hole_deg=5"]),
    ("pyramid", []),
])
def test_many_sample_path_of_a_smooth_film_is_mitsubas_render(render_variant, preset, extra):
    """A smooth film ignores its BSDF samples, so the many-sample loop (pixel-centre rays, the
    nested integrator called directly, the stokes integrator's frame rotation redone, samples
    summed per pixel) must give ``mi.render``'s Stokes images bit for bit, with either
    integrator."""
    mi = render_variant
    from thinfilm.generators.render import render_stokes_cube
    from thinfilm.generators.scene import BSDF_SAMPLING_INTEGRATOR
    from thinfilm.generators.scene import build_scene_dict

    scene = mi.load_dict(build_scene_dict(_spec(preset, alpha=0.0, resolution=24, extra=extra))[0])
    wl = np.array([450.0, 600.0])
    ref = render_stokes_cube(scene, wl, 4.0)
    assert np.abs(ref["S1"]).max() > 0.01
    for integrator in (None, BSDF_SAMPLING_INTEGRATOR):
        out = render_stokes_cube(scene, wl, 4.0, spp=4, seed=3, integrator=integrator)
        for k in ("S0", "S1", "S2", "mask"):
            np.testing.assert_array_equal(out[k], ref[k])


def test_bsdf_sampling_integrator_agrees_with_the_path_tracer_on_convex_shapes(render_variant):
    """The one-bounce, BSDF-only integrator used for convex shapes against Mitsuba's path
    tracer (light and BSDF sampling, several bounces): per pixel and over the image the same
    up to sampling noise, which is measured from four seeds of each."""
    mi = render_variant
    from thinfilm.generators.render import render_stokes_cube
    from thinfilm.generators.scene import build_scene_dict, rough_integrator

    spec = _spec("cylinder", alpha=0.3, resolution=24, extra=["rig.dome_hole_deg=10"])
    scene = mi.load_dict(build_scene_dict(spec)[0])
    path = {"type": "path", "max_depth": 6, "hide_emitters": True}
    wl = np.array([520.0])
    runs = {name: [render_stokes_cube(scene, wl, 0.0, spp=256, seed=s, integrator=integrator)
                   for s in seeds]
            for name, integrator, seeds in (("bsdf", rough_integrator(spec), (1, 2, 3, 4)),
                                            ("path", path, (5, 6, 7, 8)))}
    m = runs["bsdf"][0]["mask"]
    for k in ("S0", "S1", "S2"):
        a, b = (np.stack([r[k][m, 0] for r in runs[name]]) for name in ("bsdf", "path"))
        diff = a.mean(axis=0) - b.mean(axis=0)
        var = (a.var(axis=0, ddof=1) + b.var(axis=0, ddof=1)) / 4  # variance of diff, per pixel
        z = diff / np.sqrt(var.mean())
        assert np.sqrt(np.mean(z ** 2)) < 1.5, k  # measured 0.97-1.10 (1 if noise only)
        # measured 0.5-0.7 standard errors
        assert abs(diff.mean()) < 4 * np.sqrt(var.mean() / m.sum()), k


def test_rows_grouping_does_not_change_the_image(render_variant, monkeypatch):
    mi = render_variant
    from thinfilm.generators import render
    from thinfilm.generators.scene import build_scene_dict

    scene = mi.load_dict(build_scene_dict(_spec(resolution=20))[0])
    wl = np.array([500.0])
    whole = render.render_stokes_cube(scene, wl, 0.0, spp=16, seed=7)
    monkeypatch.setattr(render, "MAX_LANES", 3 * 20 * 16)  # three rows per launch
    grouped = render.render_stokes_cube(scene, wl, 0.0, spp=16, seed=7)
    for k in ("S0", "S1", "S2"):
        np.testing.assert_array_equal(grouped[k], whole[k])
    other = render.render_stokes_cube(scene, wl, 0.0, spp=16, seed=8)
    assert not np.array_equal(other["S0"], whole["S0"])


# -- rough datasets ------------------------------------------------------------------------------

def _folder_bytes(folder):
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir())}


def test_rough_dataset_is_deterministic_and_keeps_the_macro_ground_truth(render_variant_module, tmp_path):
    from thinfilm.core.io import read_dataset, read_json
    from thinfilm.generators.generate import generate_dataset
    from thinfilm.generators.spec import load_spec

    spec = _spec("pyramid", alpha=0.1, resolution=24, extra=[FEW_BANDS, "film.thickness.profile=radial"])
    for name in ("a", "b"):
        generate_dataset(spec, tmp_path / name, progress=False)
    assert _folder_bytes(tmp_path / "a") == _folder_bytes(tmp_path / "b")
    meta = read_json(tmp_path / "a" / "meta.json")
    assert meta["film_roughness"] == 0.1 and meta["spp"] == 64
    assert load_spec(tmp_path / "a" / "scene.toml") == spec
    # The ground truth is the macro surface's: the smooth film's, exactly.
    generate_dataset(spec.replace(roughness=0.0), tmp_path / "smooth", progress=False)
    assert "film_roughness" not in read_json(tmp_path / "smooth" / "meta.json")
    rough, smooth = (read_dataset(tmp_path / n, need=("ground_truth",)).ground_truth for n in ("a", "smooth"))
    for k in smooth:
        np.testing.assert_array_equal(rough[k], smooth[k])
    # Another seed: other sampling (and camera) noise.
    generate_dataset(spec.replace(seed=1), tmp_path / "c", progress=False)
    other = _folder_bytes(tmp_path / "c")
    assert other["stokes_spectral.exr"] != _folder_bytes(tmp_path / "a")["stokes_spectral.exr"]


def test_small_roughness_approaches_the_smooth_dataset(render_variant_module):
    from thinfilm.generators.generate import simulate

    smooth = simulate(_spec(alpha=0.0, noise="none", extra=[FEW_BANDS]))
    m = smooth["ground_truth"]["mask"]
    scale = smooth["stokes_exact"]["S0"][m].max()
    errors = []
    for alpha in (0.1, 0.01, 0.001):
        rough = simulate(_spec(alpha=alpha, noise="none", extra=[FEW_BANDS]))
        diff = max(np.abs(rough["stokes_exact"][k] - smooth["stokes_exact"][k])[m].mean()
                   for k in ("S0", "S1", "S2"))
        errors.append(diff / scale)
    # measured: mean differences 2.1e-2, 6.3e-4, 4.1e-5 of the brightest S0
    assert errors[0] > errors[1] > errors[2]
    assert errors[2] < 2e-4
    rough = simulate(_spec(alpha=0.001, noise="none", extra=[FEW_BANDS]))
    for k in ("S0", "S1", "S2"):
        assert np.abs(rough["stokes_exact"][k] - smooth["stokes_exact"][k])[m].max() < 0.01 * scale


@pytest.mark.parametrize("preset", ["hemisphere", "pyramid"])
def test_rendering_noise_is_below_the_camera_noise(render_variant_module, preset):
    """At the spp the generator picks, the sampling noise of every band image I(α) of the
    hyperspectral camera (its standard deviation over render seeds) is below the camera noise
    of that image (measured by drawing the noise model on the mean image). The pyramid is
    the hard case: its flat faces are all at full exposure, where camera noise is relatively
    smallest."""
    from thinfilm.core.conventions import malus_intensity
    from thinfilm.generators.generate import simulate
    from thinfilm.generators.noise import apply_camera_noise

    seeds = range(6)
    sims = [simulate(_spec(preset, alpha=0.1, seed=s, extra=[FEW_BANDS])) for s in seeds]
    assert sims[0]["spp"] == 64
    mask = sims[0]["ground_truth"]["mask"]
    angles = [0, 45, 90, 135]
    images = np.stack([np.stack(malus_intensity(*(s["stokes_exact"][k] for k in ("S0", "S1", "S2")), angles))
                       for s in sims])  # (seed, angle, H, W, band)
    mean = images.mean(axis=0)
    render_var = images.var(axis=0, ddof=1)[:, mask]
    rng = np.random.default_rng(0)
    noise = _spec(preset).noise.as_dict()
    camera_var = []
    for a in range(len(angles)):
        frames = np.moveaxis(mean[a], -1, 0)  # (band, H, W): one exposure per image, as captured
        draws = np.stack([apply_camera_noise(frames, mask, noise, rng) for _ in range(12)])
        camera_var.append(np.moveaxis(draws.var(axis=0, ddof=1), 0, -1)[mask])
    camera_var = np.stack(camera_var)
    ratio = np.sqrt(render_var.mean() / camera_var.mean())
    # measured (root mean square ratio of standard deviations): hemisphere 0.43 (median over
    # pixels 0.31), pyramid 0.75 (median 0.72)
    assert ratio < 1.0, ratio
    assert np.median(np.sqrt(render_var / camera_var)) < 1.0


def test_estimators_run_on_rough_data(render_variant_module, tmp_path, capsys):
    from thinfilm.cli import main
    from thinfilm.core.io import read_estimate
    from thinfilm.generators.generate import generate_dataset

    ds = tmp_path / "rough"
    generate_dataset(_spec("hemisphere", alpha=0.1, resolution=32), ds, progress=False)
    for kind, methods in (("rgb", ("coherent", "kobayashi2023")), ("spectral", ("eikonal", "kobayashi"))):
        for method in methods:
            out = tmp_path / f"{kind}_{method}"
            assert main(["reconstruct", kind, str(ds), "--out", str(out), "--method", method]) == 0, method
            est = read_estimate(out)
            assert est.valid.any(), method
            v = est.valid
            assert np.all(np.isfinite(est.normals[v])) and np.all(np.isfinite(est.thickness_nm[v])), method
            if est.film_ior is not None:
                assert np.isfinite(est.film_ior), method


def test_evaluation_re_renders_a_rough_dataset_as_a_rough_film(render_variant_module, tmp_path):
    """The ground truth of a rough dataset, re-rendered by ``evaluate`` with the dataset's
    roughness and samples per pixel, reproduces the (noise-free) captures up to the rendering
    noise; re-rendered smooth, it would not."""
    import json

    from thinfilm import evaluation as ev
    from thinfilm.core.io import Estimate, read_dataset, write_estimate
    from thinfilm.generators.generate import generate_dataset

    ds = tmp_path / "rough"
    generate_dataset(_spec("hemisphere", alpha=0.1, resolution=24, noise="none", seed=3, extra=[FEW_BANDS]), ds,
                     progress=False)
    gt = read_dataset(ds, need=("ground_truth",)).ground_truth
    (tmp_path / "gt").mkdir()
    write_estimate(tmp_path / "gt", Estimate(gt["normal"], gt["thickness"], gt["mask"], 1.37, 1.6))
    rough = ev.evaluate(ds, tmp_path / "gt")["metrics"]["delta_e_ab"]["mean"]
    meta = json.loads((ds / "meta.json").read_text())
    del meta["film_roughness"], meta["spp"]
    (ds / "meta.json").write_text(json.dumps(meta))
    smooth = ev.evaluate(ds, tmp_path / "gt")["metrics"]["delta_e_ab"]["mean"]
    assert rough < 0.5 and rough < 0.5 * smooth, (rough, smooth)
