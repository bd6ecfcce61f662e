"""The observation model (thinfilm.core.model): against the generator's noise-free renders,
against tmm, its AD derivatives against finite differences, and its fused normal equations
against the Jacobian it returns."""

import math

import numpy as np
import pytest

from _gen_fixtures import make_dataset, small_spec, tmm_band, tmm_rs_rp

from thinfilm.core.film import Film
from thinfilm.core.model import ObservationModel, Observations, Rig, predict


STACK_TOML = """
seed = 3
[shape]
kind = "hemisphere"
radius = 1.0
[film]
layers = [{ ior = "MgF2", thickness_nm = 95.0 }, { ior = 2.1, thickness_nm = 60.0 },
          { ior = "1.65+0.01i", thickness_nm = 80.0 }]
[film.thickness]
profile = "radial"
center = 110.0
edge = 90.0
[substrate]
ior = 1.52
[rig]
resolution = 32
[noise]
model = "none"
"""


def _stack_spec(folder):
    from thinfilm.generators.spec import load_spec

    path = folder / "stack.toml"
    path.write_text(STACK_TOML)
    return load_spec(str(path))


SCENES = {
    "hemisphere": lambda folder: small_spec("hemisphere", 32),
    "pyramid": lambda folder: small_spec("pyramid", 32, extra=["film.thickness.profile=radial",
                                                        "film.thickness.center=690.0",
                                                        "film.thickness.edge=400.0"]),
    "stack": _stack_spec,
    # a dispersive film on an absorbing substrate under a dome with a hole
    "dome_hole": lambda folder: small_spec("hemisphere", 32, extra=["film.ior=MgF2", "substrate.k=0.5",
                                                             "rig.dome_hole_deg=12.0"]),
}


@pytest.fixture(scope="module", params=sorted(SCENES))
def noise_free(request, tmp_path_factory, render_variant_module):
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        spec = SCENES[request.param](tmp_path_factory.mktemp("spec"))
    return make_dataset(tmp_path_factory, request.param, spec)


def test_predict_from_the_ground_truth_gives_the_noise_free_captures(noise_free):
    ds = noise_free
    gt = ds.ground_truth
    p = predict(ds, gt["normal"], gt["thickness"])
    m = gt["mask"]
    assert m.sum() > 300
    for angle, img in ds.polarized_rgb.items():
        assert np.abs(p["polarized_rgb"][angle] - img)[m].max() <= 1e-4, angle
    assert np.abs(p["spectral_s"] - ds.spectral_s)[m].max() <= 1e-4
    for k in ("S0", "S1", "S2"):
        assert np.abs(p["stokes"][k] - ds.stokes[k])[m].max() <= 1e-4, k
    # the background reflects nothing, in the data and in the prediction of empty normals
    empty = predict(ds, np.zeros_like(gt["normal"]), gt["thickness"])
    assert np.all(empty["spectral_s"] == 0.0) and np.all(ds.spectral_s[~m] == 0.0)


def test_a_pixel_against_tmm_with_the_passband():
    """An oblique pixel of azimuth 30°: S0 = (R_s + R_p)/2 and (S1, S2) = -(R_s - R_p)/2
    (cos 60°, sin 60°), each band the Gaussian-passband average of tmm's R (dense sum)."""
    wl = np.array([420.0, 500.0, 610.0])
    rig = Rig(wavelengths_nm=wl, band_fwhm_nm=6.0)
    model = ObservationModel(rig, Film.single(1.38, None, substrate_ior=1.52))
    zen, az, d = 41.0, 30.0, 720.0
    t, p = math.radians(zen), math.radians(az)
    n = np.array([[math.sin(t) * math.cos(p), math.sin(t) * math.sin(p), math.cos(t)]])
    s = model.stokes(n, np.array([d]))
    Rs = np.array([tmm_band(zen, c, 6.0, d, 1.38, 1.52, "s", dense_nm=0.05) for c in wl])
    Rp = np.array([tmm_band(zen, c, 6.0, d, 1.38, 1.52, "p", dense_nm=0.05) for c in wl])
    assert np.allclose(s["S0"][0], 0.5 * (Rs + Rp), atol=2e-6)
    assert np.allclose(s["S1"][0], -0.5 * (Rs - Rp) * math.cos(2 * p), atol=2e-6)
    assert np.allclose(s["S2"][0], -0.5 * (Rs - Rp) * math.sin(2 * p), atol=2e-6)


def test_a_stack_pixel_against_tmm():
    import tmm

    wl = np.array([450.0, 550.0, 650.0])
    film = Film.from_meta({"film": {"layers": [{"ior": 1.38, "thickness_nm": 100.0},
                                               {"ior": {"n": 2.1, "k": 0.02}, "thickness_nm": 60.0}],
                                    "substrate": {"ior": {"n": 0.2, "k": 3.0}}}})
    model = ObservationModel(Rig(wavelengths_nm=wl), film)
    zen = 55.0
    t = math.radians(zen)
    s = model.stokes(np.array([[math.sin(t), 0.0, math.cos(t)]]), np.array([[100.0, 60.0]]))
    for b, lam in enumerate(wl):
        nl = [1.0, 1.38, 2.1 + 0.02j, 0.2 + 3.0j]
        dl = [np.inf, 100.0, 60.0, np.inf]
        Rs, Rp = (tmm.coh_tmm(pol, nl, dl, t, lam)["R"] for pol in "sp")
        assert s["S0"][0, b] == pytest.approx(0.5 * (Rs + Rp), abs=1e-12)
        assert s["S1"][0, b] == pytest.approx(-0.5 * (Rs - Rp), abs=1e-12)


@pytest.mark.parametrize("kind", ["stokes", "spectral_s", "sp", "polarized_rgb"])
def test_derivatives_by_ad_agree_with_finite_differences(kind):
    rng = np.random.default_rng(1)
    wl = np.arange(400.0, 721.0, 16.0)
    model = ObservationModel(Rig(wavelengths_nm=wl, band_fwhm_nm=4.0), Film.single("MgF2", None, 1.6))
    n = 6
    # (v1, v2, thickness, index offset)
    x = np.stack([rng.uniform(-0.5, 0.5, n), rng.uniform(-0.5, 0.5, n), rng.uniform(300, 2500, n),
                  rng.uniform(-0.05, 0.05, n)], 1)
    values, jac = model.evaluate(kind, x, derivatives=True)
    assert np.all(np.isfinite(values)) and jac.shape == values.shape + (4,)
    for q, h in enumerate([1e-6, 1e-6, 1e-4, 1e-6]):
        hi, lo = x.copy(), x.copy()
        hi[:, q] += h
        lo[:, q] -= h
        fd = (model.evaluate(kind, hi) - model.evaluate(kind, lo)) / (2 * h)
        assert np.abs(jac[..., q] - fd).max() <= 1e-6 * max(1.0, np.abs(fd).max()), q


@pytest.mark.parametrize("kind", ["stokes", "spectral_s", "polarized_rgb"])
def test_the_fused_normal_equations_are_those_of_the_jacobian(kind):
    rng = np.random.default_rng(2)
    wl = np.arange(400.0, 721.0, 8.0)
    model = ObservationModel(Rig(wavelengths_nm=wl, band_fwhm_nm=4.0), Film.single(1.37, None, 1.6))
    n = 7
    x = np.stack([rng.uniform(-0.4, 0.4, n), rng.uniform(-0.4, 0.4, n), rng.uniform(300, 900, n)], 1)
    values, jac = model.evaluate(kind, x, derivatives=True)
    data = values + rng.normal(0.0, 1e-3, values.shape)
    b = wl.size
    obs = {"stokes": lambda: Observations("stokes", (data[:, :b], data[:, b:2 * b], data[:, 2 * b:])),
           "spectral_s": lambda: Observations("spectral_s", data),
           "polarized_rgb": lambda: Observations("polarized_rgb", data.reshape(n, 4, 3),
                                                 angles_deg=[0, 45, 90, 135])}[kind]()
    H, g, cost = model.normal_equations(obs, x)
    r = data - values
    assert np.allclose(H, np.einsum("nmp,nmq->npq", jac, jac), rtol=1e-9, atol=0)
    assert np.allclose(g, -np.einsum("nmp,nm->np", jac, r), rtol=1e-9, atol=1e-18)
    assert np.allclose(cost, np.sum(r * r, axis=1), rtol=1e-12)
    _, _, cost_only = model.normal_equations(obs, x, derivatives=False)
    assert np.allclose(cost_only, cost, rtol=1e-12)


def test_single_precision_agrees_with_double():
    wl = np.arange(400.0, 721.0, 4.0)
    rig = Rig(wavelengths_nm=wl, band_fwhm_nm=4.0)
    film = Film.single(1.37, None, 1.6)
    rng = np.random.default_rng(3)
    x = np.stack([rng.uniform(-0.6, 0.6, 50), rng.uniform(-0.6, 0.6, 50), rng.uniform(50, 5000, 50)], 1)
    a = ObservationModel(rig, film, precision="double").evaluate("stokes", x)
    b = ObservationModel(rig, film, precision="single").evaluate("stokes", x)
    assert np.abs(a - b).max() <= 2e-5


def test_cuda_gives_what_llvm_gives():
    import drjit as dr

    if not dr.has_backend(dr.JitBackend.CUDA):
        pytest.skip("no CUDA GPU on this machine")
    wl = np.arange(400.0, 721.0, 4.0)
    rig = Rig(wavelengths_nm=wl, band_fwhm_nm=4.0)
    film = Film.single(1.37, None, 1.6)
    rng = np.random.default_rng(4)
    x = np.stack([rng.uniform(-0.6, 0.6, 100), rng.uniform(-0.6, 0.6, 100), rng.uniform(50, 5000, 100)], 1)
    a = ObservationModel(rig, film, backend="llvm").evaluate("stokes", x)
    b = ObservationModel(rig, film, backend="cuda").evaluate("stokes", x)
    assert np.abs(a - b).max() <= 1e-10


def test_bad_arguments_are_refused():
    rig = Rig(wavelengths_nm=[500.0, 600.0])
    with pytest.raises(ValueError):
        Rig(wavelengths_nm=[600.0, 500.0])
    with pytest.raises(ValueError):
        ObservationModel(rig, Film.single(1.37, None, 1.6), backend="opencl").types
    with pytest.raises(ValueError):
        ObservationModel(rig, Film.single(1.37, None, 1.6)).stokes(np.zeros((2, 3)), np.zeros(3))


@pytest.mark.parametrize("angle, n_film, n_sub, k_sub", [(0.0, 1.33, 1.0, 0.0), (35.0, 1.46, 3.9, 0.02),
                                                         (60.0, 1.38, 1.52, 0.0)])
def test_the_spectrometer_reading_and_its_derivatives_against_tmm(angle, n_film, n_sub, k_sub):
    """fit-spectrum's forward model: (R_s + R_p)/2 at one angle, and its AD derivatives by the
    thickness and by an index offset, against tmm and central differences of tmm."""
    from thinfilm.core.model import Spectrometer

    lam = np.linspace(420.0, 820.0, 9)
    d, delta = 1234.5, 0.01
    film = Film.single(n_film, substrate_ior=n_sub, substrate_k=k_sub)
    R, J = Spectrometer(film, lam, angle).reflectance([d], [delta], derivatives=True)

    def ref(dd, nn):
        return np.array([0.5 * sum(tmm_rs_rp(angle, x, dd, nn, n_sub, k_sub)) for x in lam])

    assert np.allclose(R[0], ref(d, n_film + delta), rtol=0, atol=1e-10)
    h_d, h_n = 1e-3, 1e-6
    dd = (ref(d + h_d, n_film + delta) - ref(d - h_d, n_film + delta)) / (2 * h_d)
    dn = (ref(d, n_film + delta + h_n) - ref(d, n_film + delta - h_n)) / (2 * h_n)
    assert np.allclose(J[0, :, 0], dd, rtol=1e-5, atol=1e-9)
    assert np.allclose(J[0, :, 1], dn, rtol=1e-5, atol=1e-7)


@pytest.mark.parametrize("kind", ["stokes", "spectral_s", "sp", "polarized_rgb"])
def test_zero_lanes_give_empty_results_of_the_right_shape(kind):
    # a stage of a method with no pixel left to fit calls the model with zero rows
    wl = np.arange(400.0, 721.0, 8.0)
    b = wl.size
    model = ObservationModel(Rig(wavelengths_nm=wl, band_fwhm_nm=4.0), Film.single(1.37, None, 1.6))
    x = np.zeros((0, 3))
    fixed = {"index_offset.0": np.zeros(0)}
    width = {"stokes": 3 * b, "spectral_s": b, "sp": 2 * b, "polarized_rgb": 3 * 4}[kind]
    values = model.evaluate(kind, x, fixed=fixed)
    assert values.shape == (0, width)
    values, jac = model.evaluate(kind, x, fixed=fixed, derivatives=True, wrt=[2])
    assert values.shape == (0, width) and jac.shape == (0, width, 1)
    if kind == "polarized_rgb":
        assert model.evaluate(kind, x, angles_deg=[0.0, 90.0]).shape == (0, 6)
    data = {"stokes": (np.zeros((5, b)),) * 3, "spectral_s": np.zeros((5, b)), "sp": np.zeros((5, 2 * b)),
            "polarized_rgb": np.zeros((5, 4, 3))}[kind]
    obs = Observations(kind, data, angles_deg=[0, 45, 90, 135] if kind == "polarized_rgb" else None)
    H, g, cost = model.normal_equations(obs, x, fixed=fixed, rows=np.zeros(0, dtype=np.int64))
    assert H.shape == (0, 3, 3) and g.shape == (0, 3) and cost.shape == (0,)
    H, g, cost = model.normal_equations(obs, x, wrt=[0, 2])
    assert H.shape == (0, 2, 2) and g.shape == (0, 2)
    assert model.normal_equations(obs, x, derivatives=False)[2].shape == (0,)
    # the same model then evaluates lanes as before
    full = model.evaluate(kind, np.array([[0.1, -0.2, 450.0]]))
    assert full.shape == (1, width) and np.all(np.isfinite(full)) and np.any(full > 0)
    with pytest.raises(ValueError, match="x must be"):
        model.evaluate(kind, np.zeros(0))


def test_zero_pixels_through_the_stokes_cube_the_spectrometer_and_the_solver():
    from thinfilm.core.model import Spectrometer
    from thinfilm.reconstruction.lm import levenberg_marquardt

    wl = np.arange(400.0, 721.0, 8.0)
    model = ObservationModel(Rig(wavelengths_nm=wl, band_fwhm_nm=4.0), Film.single(1.37, None, 1.6))
    s = model.stokes(np.zeros((0, 3)), np.zeros(0))
    assert all(s[k].shape == (0, wl.size) for k in ("S0", "S1", "S2"))
    spot = Spectrometer(Film.single(1.37, None, 1.6), wl)
    assert spot.reflectance([]).shape == (0, wl.size)
    R, dR = spot.reflectance([], index_offset=[], derivatives=True)
    assert R.shape == (0, wl.size) and dR.shape == (0, wl.size, 2)
    obs = Observations("spectral_s", np.zeros((0, wl.size)))

    def normal_equations(x, idx):
        H, g, cost = model.normal_equations(obs, x, rows=idx)
        return H, g, cost, None

    fit = levenberg_marquardt(np.zeros((0, 3)), normal_equations, iterations=5)
    assert fit.x.shape == (0, 3) and fit.H.shape == (0, 3, 3) and fit.cost.shape == (0,) and fit.iterations == 0
