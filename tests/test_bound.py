"""The camera noise model's variance and the per-pixel Cramér-Rao bound (thinfilm.core.noise,
thinfilm.core.bound): the variance against the generator's own noise draws, the parametrization
against the observation model's normals, and the bound against the spread of a maximum-
likelihood fit to noisy images drawn by the generator."""

import numpy as np
import pytest

from thinfilm.core.bound import double_angle_from_normals, normal_jacobian, pixel_bound
from thinfilm.core.film import Film
from thinfilm.core.model import ObservationModel, Rig
from thinfilm.core.noise import capture_variance, exposure_gains
from thinfilm.generators.noise import apply_camera_noise

NOISE = {"model": "camera", "full_well": 6000.0, "read_noise": 6.0, "bits": 10, "exposure": "auto"}


@pytest.mark.parametrize("level", [0.02, 0.3, 1.0])
def test_the_variance_is_that_of_the_generators_noise(level):
    rng = np.random.default_rng(1)
    img = np.full((1, 200, 200), level)
    img[0, 0, 0] = 1.0  # the brightest pixel sets the exposure
    mask = np.ones((200, 200), bool)
    draws = apply_camera_noise(img, mask, NOISE, rng)[0].ravel()[1:]
    predicted = capture_variance(img, exposure_gains(img, mask, NOISE), NOISE)[0, 0, 1]
    assert draws.var() == pytest.approx(predicted, rel=0.03)
    assert draws.mean() == pytest.approx(level, rel=2e-3)


def test_the_parametrization_is_the_observation_models():
    rng = np.random.default_rng(2)
    th, ph = rng.uniform(0.05, 1.3, 20), rng.uniform(-np.pi, np.pi, 20)
    n = np.stack([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)], axis=1)
    model = ObservationModel(Rig(wavelengths_nm=(450.0, 550.0, 650.0)), Film.single(1.38, substrate_ior=1.6))
    d = rng.uniform(200, 800, 20)
    s = model.stokes(n, d)
    v = model.evaluate("stokes", np.concatenate([double_angle_from_normals(n), d[:, None]], axis=1), "double_angle")
    assert np.allclose(v, np.concatenate([s["S0"], s["S1"], s["S2"]], axis=1), atol=1e-12)
    # ∂n/∂v against central differences of the same mapping written out
    x = double_angle_from_normals(n)

    def normal(v):
        u = np.hypot(v[:, 0], v[:, 1])
        phi = 0.5 * np.arctan2(v[:, 1], v[:, 0])
        return np.stack([np.sqrt(u) * np.cos(phi), np.sqrt(u) * np.sin(phi), np.sqrt(1 - u)], axis=1)

    J = normal_jacobian(x)
    for k in range(2):
        h = np.zeros(2)
        h[k] = 1e-7
        fd = (normal(x + h) - normal(x - h)) / 2e-7
        assert np.allclose(J[:, :, k], fd, rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize("capture", ["stokes", "polarized_rgb"])
def test_a_maximum_likelihood_fit_to_generated_noise_reaches_the_bound(capture):
    """400 noisy captures of one pixel (the generator's noise at the exposure of the pixel's
    own images), each fitted by weighted Gauss-Newton from the truth: the spread of the fits is
    the bound (an efficient estimator at this signal-to-noise ratio)."""
    rig = Rig(wavelengths_nm=tuple(np.arange(420.0, 701.0, 20.0)))
    film = Film.single(1.38, substrate_ior=1.6)
    theta, phi, d = 0.7, 0.4, 520.0
    n = np.array([[np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)]])
    bound = pixel_bound(rig, film, n, np.array([d]), NOISE, capture)
    model = ObservationModel(rig, film)
    x0 = np.concatenate([double_angle_from_normals(n), [[d]]], axis=1)
    kind = "polarized_rgb" if capture == "polarized_rgb" else "stokes"
    mean = model.evaluate(kind, x0, "double_angle")[0]
    if capture == "stokes":
        B = len(rig.wavelengths_nm)
        from thinfilm.core.conventions import stokes_design_matrix

        D = stokes_design_matrix(rig.polarizer_angles_deg)
        to_images = lambda v: np.einsum("ak,nkb->nab", D, v.reshape(-1, 3, B)).reshape(v.shape[0], -1)  # noqa: E731
        images = to_images(mean[None])[0].reshape(len(D), B)           # (A, B) one image per angle and band
        stack = images.reshape(-1)[:, None, None]
    else:
        to_images = lambda v: v  # noqa: E731
        stack = mean.reshape(-1, 3)[:, None, None, :]                   # (A, 1, 1, 3)
    count = 400
    rng = np.random.default_rng(3)
    tiled = np.repeat(stack, count, axis=2)                             # the same pixel, count times
    noisy = apply_camera_noise(tiled, np.ones(tiled.shape[1:3], bool), NOISE, rng)
    y = np.moveaxis(noisy, 2, 0).reshape(count, -1)
    var = capture_variance(stack, exposure_gains(stack, np.ones((1, 1), bool), NOISE), NOISE).reshape(-1)
    x = np.repeat(x0, count, axis=0)
    for _ in range(6):
        v, J = model.evaluate(kind, x, "double_angle", derivatives=True)
        r = y - to_images(v)
        Jm = np.stack([to_images(J[:, :, p]) for p in range(3)], axis=2)
        H = np.einsum("nmp,m,nmq->npq", Jm, 1 / var, Jm)
        g = np.einsum("nmp,m,nm->np", Jm, 1 / var, r)
        x = x + np.linalg.solve(H, g[:, :, None])[:, :, 0]
    u = np.hypot(x[:, 0], x[:, 1])
    ph = 0.5 * np.arctan2(x[:, 1], x[:, 0])
    ph = np.where(np.cos(ph - phi) < 0, ph + np.pi, ph)
    nf = np.stack([np.sqrt(u) * np.cos(ph), np.sqrt(u) * np.sin(ph), np.sqrt(1 - u)], axis=1)
    angle = np.degrees(np.arccos(np.clip(nf @ n[0], -1, 1)))
    assert np.sqrt(np.mean(angle ** 2)) == pytest.approx(bound["normal_deg"][0], rel=0.12)
    assert np.std(x[:, 2]) == pytest.approx(bound["thickness_nm"][0, 0], rel=0.12)


def test_evaluate_reports_the_bound_of_the_capture_the_estimate_used(tmp_path):
    """metrics.json holds the bound beside the errors: for the spectral default (the Stokes
    cube) and the RGB default (the polarization camera), and nothing without camera noise."""
    import json

    from thinfilm.cli import main

    ds = tmp_path / "h"
    assert main(["generate", "hemisphere", "--out", str(ds), "--resolution", "40"]) == 0
    seen = {}
    for kind in ("spectral", "rgb"):
        assert main(["reconstruct", kind, str(ds), "--out", str(tmp_path / kind)]) == 0
        assert main(["evaluate", str(ds), str(tmp_path / kind), "--out", str(tmp_path / f"ev_{kind}")]) == 0
        m = json.loads((tmp_path / f"ev_{kind}" / "metrics.json").read_text())
        info = json.loads((tmp_path / f"ev_{kind}" / "evaluation.json").read_text())["bound"]
        assert set(m["crlb_normal_deg"]) == {"mean", "median", "p95", "max", "rms"}
        assert 0 < m["crlb_normal_deg"]["rms"] < m["crlb_normal_deg"]["max"] < 10
        assert 0 < m["crlb_thickness_nm"]["rms"] < 10 and info["pixels"] > 100
        assert m["efficiency_normal"] == pytest.approx(m["crlb_normal_deg"]["rms"] / m["normal_error_rms_deg"])
        seen[kind] = (info["capture"], m["crlb_thickness_nm"]["rms"])
        # the default reports its σ, and evaluate scores it: the share of pixels within 2 σ,
        # recomputed here from the error maps and the estimate's channels
        from thinfilm.core.io import read_estimate, read_exr

        est = read_estimate(tmp_path / kind)
        err = read_exr(tmp_path / f"ev_{kind}" / "errors.exr")
        sel = err["mask"] > 0.5
        want = np.mean(err["thickness_error_nm"][sel] <= 2 * est.thickness_sigma_nm[sel])
        assert m["thickness_within_2sigma"] == pytest.approx(want, abs=1e-6)
        assert 0.0 < m["normal_within_2sigma"] <= 1.0
    assert seen["spectral"][0] == "stokes" and seen["rgb"][0] == "polarized_rgb"
    assert seen["spectral"][1] < seen["rgb"][1]  # 81 bands know the thickness better than 3 colours
    clean = tmp_path / "clean"
    assert main(["generate", "hemisphere", "--out", str(clean), "--resolution", "24", "--set", "noise.model=none"]) == 0
    assert main(["reconstruct", "spectral", str(clean), "--out", str(tmp_path / "ec")]) == 0
    assert main(["evaluate", str(clean), str(tmp_path / "ec"), "--out", str(tmp_path / "evc")]) == 0
    m = json.loads((tmp_path / "evc" / "metrics.json").read_text())
    assert m["efficiency_normal"] is None and m["crlb_normal_deg"]["rms"] is None
