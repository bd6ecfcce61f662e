"""The rough ``thinfilm`` (alpha > 0) against Mitsuba's ``roughconductor``, ``mitsuba.chi2`` and tmm."""

import numpy as np
import pytest

import tmm

ROUGH = [
    {"alpha": 0.3, "distribution": "ggx"},
    {"alpha": 0.2, "distribution": "beckmann", "sample_visible": False},
    {"alpha_u": 0.08, "alpha_v": 0.35, "distribution": "ggx", "sample_visible": False},
    {"alpha_u": 0.35, "alpha_v": 0.1, "distribution": "beckmann"},
]
SUBSTRATES = [(1.6, 0.0), (0.27, 3.4)]  # a dielectric and a metal (gold-like)


def _directions(rng, n):
    cos_t = rng.uniform(0.02, 1.0, n)
    phi = rng.uniform(0, 2 * np.pi, n)
    sin_t = np.sqrt(1 - cos_t**2)
    return np.stack([sin_t * np.cos(phi), sin_t * np.sin(phi), cos_t])


def _batches(mi, n, seed):
    """Random (si, wo, sample1, sample2) batches: one of width n (LLVM), n of width 1 (scalar)."""
    import drjit as dr

    rng = np.random.default_rng(seed)
    wi, wo = _directions(rng, n), _directions(rng, n)
    lams = rng.uniform(380, 780, (4, n))
    s1, s2 = rng.uniform(size=n), rng.uniform(size=(2, n))
    vector = mi.variant().startswith("llvm")
    out = []
    for idx in ([slice(None)] if vector else range(n)):
        si = dr.zeros(mi.SurfaceInteraction3f, n) if vector else dr.zeros(mi.SurfaceInteraction3f)
        si.wi = mi.Vector3f(*wi[:, idx])
        si.sh_frame = mi.Frame3f(mi.Vector3f(0, 0, 1))
        si.n = mi.Vector3f(0, 0, 1)
        if mi.is_spectral:
            si.wavelengths = mi.UnpolarizedSpectrum(*[mi.Float(lams[c, idx]) for c in range(4)])
        out.append((si, mi.Vector3f(*wo[:, idx]), mi.Float(s1[idx]), mi.Point2f(*s2[:, idx])))
    return out


def _arrays(*values):
    """NumPy copies (float64) of Dr.Jit values, all computed by one kernel launch."""
    import drjit as dr

    dr.eval(*values)
    return [np.array(v, dtype=np.float64) for v in values]


def _close(a, b, atol=2e-6, rtol=1e-5):
    np.testing.assert_allclose(a, b, atol=atol, rtol=rtol)


def _same(mi, a, b):
    """Equal bit for bit in LLVM variants. In scalar variants Python floats are doubles, so
    the plugin's arithmetic rounds differently from Mitsuba's float32 C++ code (and Mitsuba's
    scalar Python bindings and plugins differ from each other by an ulp)."""
    if mi.variant().startswith("llvm"):
        np.testing.assert_array_equal(a, b)
    else:
        np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-9)


# --- sampling against the density (chi-square) ----------------------------------------------


@pytest.mark.parametrize("distribution", ["ggx", "beckmann"])
@pytest.mark.parametrize("alpha", [0.1, 0.4])
@pytest.mark.parametrize("theta", [10.0, 50.0, 80.0])
def test_chi2_sample_matches_pdf(variant_llvm_ad_mono, distribution, alpha, theta):
    mi = variant_llvm_ad_mono
    from mitsuba.chi2 import BSDFAdapter, ChiSquareTest, SphericalDomain

    t = np.radians(theta)
    xml = (f'<float name="alpha" value="{alpha}"/><string name="distribution" value="{distribution}"/>'
           '<float name="thickness" value="300"/>')
    sample, pdf = BSDFAdapter("thinfilm", xml, wi=mi.ScalarVector3f(float(np.sin(t)), 0.0, float(np.cos(t))))
    chi2 = ChiSquareTest(domain=SphericalDomain(), sample_func=sample, pdf_func=pdf, sample_dim=3,
                         res=101, ires=16, sample_count=200_000)
    assert chi2.run(quiet=True), f"p = {chi2.p_value}"


@pytest.mark.parametrize("distribution", ["ggx", "beckmann"])
def test_chi2_anisotropic_all_normals(variant_llvm_ad_mono, distribution):
    mi = variant_llvm_ad_mono
    from mitsuba.chi2 import BSDFAdapter, ChiSquareTest, SphericalDomain

    xml = ('<float name="alpha_u" value="0.3"/><float name="alpha_v" value="0.08"/>'
           f'<string name="distribution" value="{distribution}"/><boolean name="sample_visible" value="false"/>')
    wi = mi.ScalarVector3f(0.6, 0.3, float(np.sqrt(1 - 0.45)))
    sample, pdf = BSDFAdapter("thinfilm", xml, wi=wi)
    chi2 = ChiSquareTest(domain=SphericalDomain(), sample_func=sample, pdf_func=pdf, sample_dim=3,
                         res=101, ires=16, sample_count=200_000)
    assert chi2.run(quiet=True), f"p = {chi2.p_value}"


# --- sample, eval, pdf and eval_pdf agree --------------------------------------------------------


@pytest.mark.parametrize("rough", ROUGH[:3])
@pytest.mark.parametrize("mode", ["Radiance", "Importance"])
def test_eval_pdf_sample_agree(polarized_variant, rough, mode):
    _check_agreement(polarized_variant, rough, mode)


@pytest.mark.parametrize("rough", ROUGH[:2])
def test_eval_pdf_sample_agree_unpolarized(unpolarized_variant, rough):
    _check_agreement(unpolarized_variant, rough, "Radiance")


def _check_agreement(mi, rough, mode):
    bsdf = mi.load_dict({"type": "thinfilm", "thickness": 380.0, "film_ior": 1.45, "substrate_ior": 1.6,
                         "wavelength": 560.0, **rough})
    ctx = mi.BSDFContext(getattr(mi.TransportMode, mode))
    valid_count, n = 0, 48 if mi.variant().startswith("llvm") else 12
    for si, wo, s1, s2 in _batches(mi, n, seed=1):
        value, pdf = bsdf.eval_pdf(ctx, si, wo)
        value, pdf, value_e, pdf_p = _arrays(value, pdf, bsdf.eval(ctx, si, wo), bsdf.pdf(ctx, si, wo))
        _same(mi, value_e, value)
        _same(mi, pdf_p, pdf)

        # A valid sample (one above the horizon; as in roughconductor, an invalid one keeps its
        # pdf but has weight 0) has pdf() as its density and eval / pdf as its weight.
        bs, weight = bsdf.sample(ctx, si, s1, s2)
        value, pdf = bsdf.eval_pdf(ctx, si, bs.wo)
        weight, value, pdf, bs_pdf, z = _arrays(weight, value, pdf, bs.pdf, bs.wo.z)
        valid = z > 0
        np.testing.assert_allclose(bs_pdf[valid], pdf[valid], rtol=1e-4)  # float32: m -> wo -> m
        assert np.all(weight[..., ~valid] == 0)
        np.testing.assert_allclose(weight[..., valid], value[..., valid] / pdf[valid], atol=2e-6, rtol=1e-4)
        valid_count += int(np.count_nonzero(valid))
    assert valid_count >= n // 2


# --- thickness 0 is roughconductor ----------------------------------------------------------------


@pytest.mark.parametrize("rough", ROUGH)
@pytest.mark.parametrize("substrate", SUBSTRATES)
@pytest.mark.parametrize("mode", ["Radiance", "Importance"])
def test_thickness_zero_equals_roughconductor(polarized_variant, rough, substrate, mode):
    """Same microfacet samples (bit for bit), same Mueller matrices, same eval, pdf and flags."""
    mi = polarized_variant
    n3, k3 = substrate
    ours = mi.load_dict({"type": "thinfilm", "thickness": 0.0, "substrate_ior": n3, "substrate_k": k3, **rough})
    ref = mi.load_dict({"type": "roughconductor", "eta": n3, "k": k3, **rough})
    assert ours.flags() == ref.flags()
    ctx = mi.BSDFContext(getattr(mi.TransportMode, mode))
    for si, wo, s1, s2 in _batches(mi, 64 if mi.variant().startswith("llvm") else 12, seed=2):
        results = []
        for bsdf in (ours, ref):
            bs, weight = bsdf.sample(ctx, si, s1, s2)
            value, pdf = bsdf.eval_pdf(ctx, si, wo)
            results.append(_arrays(bs.wo, bs.pdf, bs.sampled_type, bs.sampled_component, weight,
                                   bsdf.eval(ctx, si, wo), bsdf.pdf(ctx, si, wo), value, pdf))
        (wo_o, bspdf_o, type_o, comp_o, w_o, e_o, p_o, v_o, vp_o), \
            (wo_r, bspdf_r, type_r, comp_r, w_r, e_r, p_r, v_r, vp_r) = results
        _same(mi, wo_o, wo_r)
        np.testing.assert_array_equal(type_o, type_r)
        np.testing.assert_array_equal(comp_o, comp_r)
        _same(mi, bspdf_o, bspdf_r)
        _same(mi, p_o, p_r)
        _same(mi, vp_o, vp_r)
        _close(w_o, w_r)
        _close(e_o, e_r)
        _close(v_o, v_r)


def test_alpha_texture_equals_roughconductor(variant_llvm_ad_mono_polarized):
    mi = variant_llvm_ad_mono_polarized
    rng = np.random.default_rng(8)
    alpha = {"type": "bitmap", "bitmap": mi.Bitmap(rng.uniform(0.05, 0.5, (4, 4, 1)).astype(np.float32)),
             "raw": True}
    ours = mi.load_dict({"type": "thinfilm", "thickness": 0.0, "substrate_ior": 0.27, "substrate_k": 3.4,
                         "alpha": alpha})
    ref = mi.load_dict({"type": "roughconductor", "eta": 0.27, "k": 3.4, "distribution": "ggx", "alpha": alpha})
    ctx = mi.BSDFContext()
    (si, wo, s1, s2), = _batches(mi, 64, seed=6)
    si.uv = mi.Point2f(*rng.uniform(size=(2, 64)))
    bs_o, w_o = ours.sample(ctx, si, s1, s2)
    bs_r, w_r = ref.sample(ctx, si, s1, s2)
    wo_o, wo_r, w_o, w_r, e_o, e_r = _arrays(bs_o.wo, bs_r.wo, w_o, w_r, ours.eval(ctx, si, wo),
                                             ref.eval(ctx, si, wo))
    np.testing.assert_array_equal(wo_o, wo_r)
    assert np.count_nonzero(w_r[0, 0]) > 32
    _close(w_o, w_r)
    _close(e_o, e_r)


@pytest.mark.parametrize("film", [
    {"thickness": 480.0, "film_ior": 1.45},
    {"stack": "1.38:95, 2.1:62, 1.65+0.01i:80"},
])
@pytest.mark.parametrize("rough", [ROUGH[0], ROUGH[3]])
def test_rough_film_is_roughconductor_times_film_reflectance(variant_llvm_ad_mono, film, rough):
    """Unpolarized: eval(film) / eval(roughconductor on the bare substrate) is the film's
    reflectance over the bare substrate's (both from tmm) at the microfacet angle wi·h."""
    mi = variant_llvm_ad_mono
    lam, n3 = 550.0, 1.52
    ours = mi.load_dict({"type": "thinfilm", "substrate_ior": n3, "wavelength": lam, **film, **rough})
    ref = mi.load_dict({"type": "roughconductor", "eta": n3, "k": 0.0, **rough})
    ctx = mi.BSDFContext()
    (si, wo, _, _), = _batches(mi, 512, seed=12)
    e_o, e_r, wi, wo = _arrays(ours.eval(ctx, si, wo), ref.eval(ctx, si, wo), si.wi, wo)
    e_o, e_r = e_o.ravel(), e_r.ravel()
    h = (wi + wo) / np.linalg.norm(wi + wo, axis=0)
    theta_h = np.degrees(np.arccos(np.clip((wi * h).sum(axis=0), -1, 1)))
    if "stack" in film:
        layers = [(1.38, 95.0), (2.1, 62.0), (1.65 + 0.01j, 80.0)]
    else:
        layers = [(film["film_ior"], film["thickness"])]
    ns = [1.0] + [n for n, _ in layers] + [n3]
    ds = [np.inf] + [d for _, d in layers] + [np.inf]
    lit = e_r > 1e-4
    assert lit.sum() > 100
    for k in np.flatnonzero(lit):
        th = np.radians(theta_h[k])
        R_film = 0.5 * sum(tmm.coh_tmm(p, ns, ds, th, lam)["R"] for p in "sp")
        R_bare = 0.5 * sum(tmm.coh_tmm(p, [1.0, n3], [np.inf, np.inf], th, lam)["R"] for p in "sp")
        assert e_o[k] / e_r[k] == pytest.approx(R_film / R_bare, rel=2e-4, abs=1e-5)


def _sphere_scene(mi, bsdf, res=24, spp=4):
    return mi.load_dict({
        "type": "scene",
        "integrator": {"type": "stokes", "nested": {"type": "path", "max_depth": 4, "hide_emitters": True}},
        "sensor": {
            "type": "orthographic",
            "to_world": mi.ScalarTransform4f().look_at(origin=[0, 0, 5], target=[0, 0, 0], up=[0, 1, 0]),
            "film": {"type": "hdrfilm", "width": res, "height": res, "rfilter": {"type": "box"},
                     "pixel_format": "luminance" if mi.is_monochromatic else "rgb"},
            "sampler": {"type": "independent", "sample_count": spp, "seed": 7},
        },
        "emitter": {"type": "constant"},
        "light": {"type": "point", "position": [2.0, 2.0, 3.0], "intensity": 5.0},
        "ball": {"type": "sphere", "radius": 0.8, "bsdf": bsdf},
        "ball2": {"type": "sphere", "radius": 0.4, "center": [0.9, 0.9, -0.5], "bsdf": bsdf},
    })


@pytest.mark.parametrize("rough", [ROUGH[0], ROUGH[1], ROUGH[3]])
@pytest.mark.parametrize("substrate", SUBSTRATES)
def test_thickness_zero_render_equals_roughconductor(variant_llvm_ad_spectral_polarized, rough, substrate):
    """Spectral polarized render, same seed, every Stokes channel, pixel by pixel."""
    mi = variant_llvm_ad_spectral_polarized
    n3, k3 = substrate
    ours = np.array(mi.render(_sphere_scene(mi, {"type": "thinfilm", "thickness": 0.0, "substrate_ior": n3,
                                                 "substrate_k": k3, **rough}), seed=11))
    ref = np.array(mi.render(_sphere_scene(mi, {"type": "roughconductor", "eta": n3, "k": k3, **rough}), seed=11))
    assert np.abs(ref[..., 3:]).max() > 0.05 and np.abs(ref[..., 6:9]).max() > 1e-3  # S0 and S1 are lit
    np.testing.assert_allclose(ours, ref, atol=1e-4, rtol=0)


# --- energy, the smooth limit, gradients -----------------------------------------------------------


@pytest.mark.parametrize("alpha", [0.05, 0.3, 0.8])
def test_white_furnace_energy_at_most_one(variant_llvm_ad_mono_polarized, alpha):
    """Directional albedo (mean of the sampled weights' M00, i.e. unpolarized light in) of a
    high-reflectance film on silver: at most 1, equal to the hemisphere integral of eval, and
    every sampled Mueller matrix is passive (M00 >= the norm of its first row and column)."""
    mi = variant_llvm_ad_mono_polarized
    import drjit as dr

    n = 200_000
    bsdf = mi.load_dict({"type": "thinfilm", "thickness": 100.0, "film_ior": 1.38, "substrate_ior": 0.05,
                         "substrate_k": 4.2, "wavelength": 600.0, "alpha": alpha})
    ctx = mi.BSDFContext()
    sampler = mi.load_dict({"type": "independent"})
    for theta in (0.0, 45.0, 80.0):
        sampler.seed(int(theta), n)
        si = dr.zeros(mi.SurfaceInteraction3f, n)
        si.wi = mi.Vector3f(float(np.sin(np.radians(theta))), 0.0, float(np.cos(np.radians(theta))))
        si.sh_frame = mi.Frame3f(mi.Vector3f(0, 0, 1))
        _, w = bsdf.sample(ctx, si, sampler.next_1d(), sampler.next_2d())
        m00 = np.array(w[0, 0]).ravel()
        row = np.sqrt(sum(np.array(w[0, j]).ravel() ** 2 for j in (1, 2, 3)))
        col = np.sqrt(sum(np.array(w[i, 0]).ravel() ** 2 for i in (1, 2, 3)))
        assert np.all(m00 <= 1.0 + 1e-6) and np.all(row <= m00 + 1e-6) and np.all(col <= m00 + 1e-6)
        albedo = m00.mean()
        wo = mi.warp.square_to_uniform_hemisphere(sampler.next_2d())
        integral = np.array(bsdf.eval(ctx, si, wo)[0, 0]).ravel() * (2 * np.pi)
        err = 4 * integral.std() / np.sqrt(n)
        assert 0.2 < albedo <= 1.0
        assert abs(albedo - integral.mean()) < err + 1e-3


def _tmm_R(pol, theta_deg, lam, d, n2, n3):
    return tmm.coh_tmm(pol, [1.0, n2, n3], [np.inf, d, np.inf], np.radians(theta_deg), lam)["R"]


def _plane_scene(mi, bsdf, theta_deg, res=4):
    """A plane tilted by θ about the camera's x axis under a uniform dome (stokes + path)."""
    t = np.radians(theta_deg)
    n = [0.0, float(np.sin(t)), float(np.cos(t))]
    return mi.load_dict({
        "type": "scene",
        "integrator": {"type": "stokes", "nested": {"type": "path", "max_depth": 2, "hide_emitters": True}},
        "sensor": {
            "type": "orthographic",
            "to_world": mi.ScalarTransform4f().look_at(origin=[0, 0, 5], target=[0, 0, 0], up=[0, 1, 0]),
            "film": {"type": "hdrfilm", "width": res, "height": res, "rfilter": {"type": "box"},
                     "pixel_format": "luminance" if mi.is_monochromatic else "rgb"},
            "sampler": {"type": "independent", "sample_count": 64},
        },
        "emitter": {"type": "constant", "radiance": {"type": "uniform", "value": 1.0}},
        "plane": {"type": "rectangle", "bsdf": bsdf,
                  "to_world": mi.ScalarTransform4f().look_at(origin=[0, 0, 0], target=n, up=[1, 0, 0])
                  @ mi.ScalarTransform4f().scale(20.0)},
    })


@pytest.mark.parametrize("theta", [15.0, 45.0, 70.0])
def test_small_alpha_approaches_smooth_film(variant_llvm_ad_mono_polarized, theta):
    """alpha = 1e-3 against the smooth film (itself against tmm): the Stokes image means agree
    to 2e-4; pixel by pixel (64 spp) only for Beckmann, as GGX's long tail sends about one
    sample in a thousand far from the mirror direction."""
    mi = variant_llvm_ad_mono_polarized
    film = {"type": "thinfilm", "thickness": 520.0, "film_ior": 1.37, "substrate_ior": 1.6, "wavelength": 480.0}

    def stokes(bsdf):
        img = np.array(mi.render(_plane_scene(mi, bsdf, theta), seed=2), dtype=np.float64)
        return img[..., -12::3]  # S0, S1, S2, S3

    smooth = stokes(film)
    Rs, Rp = _tmm_R("s", theta, 480.0, 520.0, 1.37, 1.6), _tmm_R("p", theta, 480.0, 520.0, 1.37, 1.6)
    np.testing.assert_allclose(smooth[..., 0], 0.5 * (Rs + Rp), atol=1e-4)
    np.testing.assert_allclose(np.abs(smooth[..., 1]), 0.5 * abs(Rs - Rp), atol=1e-4)
    for distribution in ("ggx", "beckmann"):
        rough = stokes({**film, "alpha": 1e-3, "distribution": distribution})
        np.testing.assert_allclose(rough.mean(axis=(0, 1)), smooth.mean(axis=(0, 1)), atol=2e-4, rtol=0)
        if distribution == "beckmann":
            np.testing.assert_allclose(rough, smooth, atol=5e-4, rtol=0)


def test_thickness_gradient_through_rough_render(variant_llvm_ad_mono_polarized):
    """Reverse-mode AD through a tiny stokes/path render (evaluated loops) against central
    differences of the same-seed render (thickness does not move the sampled directions)."""
    mi = variant_llvm_ad_mono_polarized
    import drjit as dr

    scene = _sphere_scene(mi, {"type": "thinfilm", "thickness": 420.0, "wavelength": 530.0, "alpha": 0.25},
                          res=8, spp=4)
    params = mi.traverse(scene)
    key = "ball.bsdf.thickness"
    integrator = scene.integrator()
    weights = np.random.default_rng(0).uniform(size=8 * 8 * 13)

    def loss(thickness):
        params[key] = thickness
        params.update()
        img = integrator.render(scene, 0, seed=3)
        return dr.sum(dr.ravel(img) * mi.Float(weights))

    h = 0.05
    fd = (float(loss(420.0 + h)[0]) - float(loss(420.0 - h)[0])) / (2 * h)
    old = dr.flag(dr.JitFlag.SymbolicLoops)
    dr.set_flag(dr.JitFlag.SymbolicLoops, False)
    try:
        params[key] = mi.Float(420.0)
        dr.enable_grad(params[key])
        params.update()
        dr.backward(loss(params[key]))
        grad = float(dr.grad(params[key])[0])
    finally:
        dr.set_flag(dr.JitFlag.SymbolicLoops, old)
    assert abs(fd) > 1e-3
    assert grad == pytest.approx(fd, rel=1e-2)


# --- parameters ---------------------------------------------------------------------------------------


def test_alpha_is_exposed_and_updates(variant_llvm_ad_mono_polarized):
    mi = variant_llvm_ad_mono_polarized
    smooth = mi.traverse(mi.load_dict({"type": "thinfilm"}))
    assert "alpha" not in smooth
    bsdf = mi.load_dict({"type": "thinfilm", "alpha": 0.2})
    assert mi.has_flag(bsdf.flags(), mi.BSDFFlags.GlossyReflection)
    assert not mi.has_flag(bsdf.flags(), mi.BSDFFlags.DeltaReflection)
    params = mi.traverse(bsdf)
    (si, wo, _, _), = _batches(mi, 16, seed=3)
    before, = _arrays(bsdf.eval(mi.BSDFContext(), si, wo))
    params["alpha"] = 0.4
    params.update()
    after, = _arrays(bsdf.eval(mi.BSDFContext(), si, wo))
    ref = mi.load_dict({"type": "thinfilm", "alpha": 0.4})
    np.testing.assert_array_equal(after, _arrays(ref.eval(mi.BSDFContext(), si, wo))[0])
    assert np.abs(after - before).max() > 1e-3
    params["alpha"] = -0.1
    with pytest.raises(ValueError, match="'alpha' must be a finite number from 0 to 1, got \\[-0.1\\]"):
        params.update()
    aniso = mi.traverse(mi.load_dict({"type": "thinfilm", "alpha_u": 0.1, "alpha_v": 0.3}))
    assert "alpha_u" in aniso and "alpha_v" in aniso


@pytest.mark.parametrize("bad, message", [
    ({"alpha": -0.1}, "'alpha' must be a finite number from 0 to 1, got -0.1"),
    ({"alpha": 5.0}, "'alpha' must be a finite number from 0 to 1, got 5.0"),
    ({"alpha_u": 0.1}, "'alpha_u' and 'alpha_v' must be given together"),
    ({"alpha": 0.1, "alpha_u": 0.1, "alpha_v": 0.2}, "either 'alpha' or 'alpha_u' and 'alpha_v'"),
    ({"alpha": 0.1, "distribution": "phong"}, "'distribution' must be 'ggx' or 'beckmann'"),
    ({"alpha": 0.1, "sample_visible": "yes"}, "'sample_visible' must be a boolean"),
])
def test_bad_rough_parameters_raise_one_clear_error(variant_llvm_ad_mono_polarized, bad, message):
    mi = variant_llvm_ad_mono_polarized
    with pytest.raises(Exception, match=message):
        mi.load_dict({"type": "thinfilm", **bad})
