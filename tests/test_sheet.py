"""The ``thinfilm_sheet`` plugin (a free-standing film, e.g. a soap-bubble wall): reflection and
transmission on both sides against tmm, energy conservation, Mitsuba's thindielectric."""

import numpy as np
import pytest
import tmm
from _plugin_scenes import normal_from_angles, orthographic_sensor, stokes_images

ASYMMETRIC = [(1.38, 120.0), (2.0 + 0.3j, 40.0), (1.46, 90.0)]  # absorbing: sides differ
ASYMMETRIC_TEXT = "1.38:120, 2.0+0.3i:40, 1.46:90"


def _tmm(theta_deg, lam, layers, n1=1.0):
    """tmm's s and p results for light meeting ``layers`` in the order given, n1 on both sides."""
    n_list = [n1] + [complex(n) for n, _ in layers] + [n1]
    d_list = [np.inf] + [d for _, d in layers] + [np.inf]
    return [tmm.coh_tmm(pol, n_list, d_list, np.radians(theta_deg), lam) for pol in "sp"]


SPP = 4096  # stratified, unjittered: see _sheet_scene


def _sheet_scene(mi, bsdf, theta_deg, light, back=False, res=2, spp=SPP):
    """An orthographic camera looking down -z at a sheet tilted by θ about image y (normal towards
    the camera, or away from it with ``back``). ``light``: "behind" (an area emitter behind the sheet,
    nothing in front: the image is the transmitted light), "front" (a uniform sky, a black wall
    behind the sheet: the image is the reflected light) or "all" (a uniform sky all around).

    Each path picks reflection with probability p = R/(R+T) and then weighs it by R/p = R + T
    (transmission likewise). The stratified sampler without jitter puts the ``spp`` values of that
    choice at the centres of ``spp`` strata, so the fraction of reflected paths in a pixel is within
    1/(2 spp) of p, and the pixel within (R + T)/(2 spp) ≤ 1/(2 spp) of R (or T): the tolerance."""
    n = normal_from_angles(theta_deg, 0.0)
    target = list(-n) if back else list(n)
    to_world = mi.ScalarTransform4f().look_at(origin=[0, 0, 0], target=target, up=[0, 1, 0])
    scene = {
        "type": "scene",
        "integrator": {"type": "stokes", "nested": {"type": "path", "max_depth": 3}},
        "sensor": orthographic_sensor(mi, res, spp=spp),
        "sheet": {"type": "rectangle", "to_world": to_world @ mi.ScalarTransform4f().scale(20.0),
                  "bsdf": bsdf},
    }
    wall = mi.ScalarTransform4f().translate([0, 0, -6]) @ mi.ScalarTransform4f().scale(200.0)
    if light == "behind":
        scene["wall"] = {"type": "rectangle", "to_world": wall,
                         "emitter": {"type": "area", "radiance": {"type": "uniform", "value": 1.0}}}
    elif light == "front":
        scene["sky"] = {"type": "constant", "radiance": {"type": "uniform", "value": 1.0}}
        scene["wall"] = {"type": "rectangle", "to_world": wall,
                         "bsdf": {"type": "diffuse", "reflectance": {"type": "uniform", "value": 0.0}}}
    else:
        scene["sky"] = {"type": "constant", "radiance": {"type": "uniform", "value": 1.0}}
    return mi.load_dict(scene)


@pytest.mark.parametrize("back", [False, True])
@pytest.mark.parametrize("theta", [0.0, 25.0, 40.0])
def test_rendered_reflection_and_transmission_match_tmm(variant_llvm_ad_mono_polarized, theta, back):
    """Camera in front of the sheet: the reflected sky and the transmitted area light, S0 and S1,
    from the front and from the back of an asymmetric absorbing stack (the back meets the layers
    in reverse order), at three wavelengths (mono variant)."""
    mi = variant_llvm_ad_mono_polarized
    layers = ASYMMETRIC[::-1] if back else ASYMMETRIC
    bsdf = {"type": "thinfilm_sheet", "stack": ASYMMETRIC_TEXT}
    scenes = {light: _sheet_scene(mi, bsdf, theta, light, back=back) for light in ("front", "behind")}
    for lam in (430.0, 540.0, 670.0):
        ref_s, ref_p = _tmm(theta, lam, layers)
        for light, key in (("front", "R"), ("behind", "T")):
            scene = scenes[light]
            params = mi.traverse(scene)
            params["sheet.bsdf.wavelength"] = lam
            params.update()
            S0, S1, S2, S3 = stokes_images(mi, scene)
            # The plane of incidence is the image's x-z plane, s is image y: S1 = -(X_s - X_p)/2.
            tol = 1 / (2 * SPP) + 1e-5
            np.testing.assert_allclose(S0, 0.5 * (ref_s[key] + ref_p[key]), atol=tol, rtol=0)
            np.testing.assert_allclose(S1, -0.5 * (ref_s[key] - ref_p[key]), atol=tol, rtol=0)
            np.testing.assert_allclose(S2, 0.0, atol=tol)
    # The two sides of this stack really differ in reflection (so the test can tell).
    front, back_ = _tmm(25.0, 540.0, ASYMMETRIC), _tmm(25.0, 540.0, ASYMMETRIC[::-1])
    assert abs(front[0]["R"] - back_[0]["R"]) > 0.05


@pytest.mark.parametrize("back", [False, True])
def test_lossless_sheet_under_uniform_sky_conserves_energy(variant_llvm_ad_mono_polarized, back):
    """A lossless soap film in a uniform sky: reflected plus transmitted light is the sky (R + T = 1),
    while each part alone is coloured (previous test)."""
    mi = variant_llvm_ad_mono_polarized
    scene = _sheet_scene(mi, {"type": "thinfilm_sheet", "thickness": 410.0, "film_ior": 1.33},
                         35.0, "all", back=back, spp=1)
    params = mi.traverse(scene)
    for lam in (450.0, 600.0):
        params["sheet.bsdf.wavelength"] = lam
        params.update()
        # One path per pixel: whichever lobe it takes, S0 = (R + T) = 1 exactly (S1 is not: each lobe
        # alone is polarized, their probability-weighted sum is not).
        S0 = stokes_images(mi, scene)[0]
        np.testing.assert_allclose(S0, 1.0, atol=2e-5)


def _matrix(value):
    """A Mueller matrix as a NumPy array ``(4, 4, ...)``, evaluated in one kernel."""
    import drjit as dr

    dr.eval(value)
    return np.array([[np.array(value[i, j]) for j in range(4)] for i in range(4)])


def _interactions(mi, n, seed, both_sides=True):
    """Random incident directions (half of them on the back side) and wavelengths, one batch."""
    import drjit as dr

    rng = np.random.default_rng(seed)
    cos_t = rng.uniform(0.03, 1.0, n) * (np.where(rng.uniform(size=n) < 0.5, -1, 1) if both_sides else 1)
    phi = rng.uniform(0, 2 * np.pi, n)
    sin_t = np.sqrt(1 - cos_t**2)
    si = dr.zeros(mi.SurfaceInteraction3f, n)
    si.wi = mi.Vector3f(sin_t * np.cos(phi), sin_t * np.sin(phi), cos_t)
    si.sh_frame = mi.Frame3f(mi.Vector3f(0, 0, 1))
    si.n = mi.Vector3f(0, 0, 1)
    if mi.is_spectral:
        si.wavelengths = mi.UnpolarizedSpectrum(*[mi.Float(rng.uniform(380, 780, n)) for _ in range(4)])
    return si, cos_t


def _to_sp_frame(mi, value, wo_hat, wi_hat):
    """Undo the rotation into Mitsuba's Stokes bases: the matrix in the s/p frame (s axis
    perpendicular to the plane of incidence, as in Mitsuba's dielectric)."""
    import drjit as dr

    n = mi.Vector3f(0, 0, 1)
    s_in, s_out = dr.cross(n, -wo_hat), dr.cross(n, wi_hat)
    collinear = dr.all(s_in == mi.Vector3f(0))
    s_in = dr.select(collinear, mi.Vector3f(1, 0, 0), dr.normalize(s_in))
    s_out = dr.select(collinear, mi.Vector3f(1, 0, 0), dr.normalize(s_out))
    return mi.mueller.rotate_mueller_basis(value, -wo_hat, mi.mueller.stokes_basis(-wo_hat), s_in,
                                           wi_hat, mi.mueller.stokes_basis(wi_hat), s_out)


@pytest.mark.parametrize("mode", ["Radiance", "Importance"])
def test_sampled_mueller_matrices_match_tmm(variant_llvm_ad_spectral_polarized, mode):
    """Both lobes of the sampled Mueller matrix (spectral, polarized), in the s/p frame, against
    tmm's amplitudes: a = mean power, b = half difference, c + i s = conj(x_s) x_p; the sample
    weight is the matrix over the probability R / (R + T) of the chosen lobe."""
    mi = variant_llvm_ad_spectral_polarized
    import drjit as dr

    bsdf = mi.load_dict({"type": "thinfilm_sheet", "stack": ASYMMETRIC_TEXT})
    si, cos_t = _interactions(mi, 16, seed=2)
    ctx = mi.BSDFContext(getattr(mi.TransportMode, mode))
    lams = np.array(si.wavelengths)
    refs = [[_tmm(np.degrees(np.arccos(abs(c))), lams[ch, k], ASYMMETRIC if c > 0 else ASYMMETRIC[::-1])
             for ch in range(4)] for k, c in enumerate(cos_t)]
    for sample1, lobe, power in ((0.0, "r", "R"), (1.0, "t", "T")):
        bs, value = bsdf.sample(ctx, si, sample1, mi.Point2f(0.5, 0.5))
        dr.eval(bs, value)
        wo_hat, wi_hat = (bs.wo, si.wi) if mode == "Radiance" else (si.wi, bs.wo)
        M = _to_sp_frame(mi, value, wo_hat, wi_hat)
        M = _matrix(M)  # (4, 4, 4 λ, lanes)
        pdf, wo, types = np.array(bs.pdf), np.array(bs.wo), np.array(bs.sampled_type)
        worst = 0.0
        for k in range(cos_t.size):
            R = np.mean([0.5 * (r[0]["R"] + r[1]["R"]) for r in refs[k]])
            T = np.mean([0.5 * (r[0]["T"] + r[1]["T"]) for r in refs[k]])
            assert abs(pdf[k] - (R if lobe == "r" else T) / (R + T)) < 2e-6
            wi = np.array(si.wi)[:, k]
            assert np.allclose(wo[:, k], [-wi[0], -wi[1], wi[2]] if lobe == "r" else -wi, atol=1e-7)
            assert types[k] == (+mi.BSDFFlags.DeltaReflection if lobe == "r" else +mi.BSDFFlags.Null)
            for ch in range(4):
                ref_s, ref_p = refs[k][ch]
                x = np.conj(ref_s[lobe]) * ref_p[lobe]
                a, b = ref_s[power] + ref_p[power], ref_s[power] - ref_p[power]
                expected = np.array([[a, b, 0, 0], [b, a, 0, 0], [0, 0, 2 * x.real, 2 * x.imag],
                                     [0, 0, -2 * x.imag, 2 * x.real]]) / 2
                worst = max(worst, np.abs(M[:, :, ch, k] * pdf[k] - expected).max())
        assert worst < 2e-5


def test_thickness_zero_transmits_as_identity_and_reflects_nothing(polarized_variant):
    mi = polarized_variant
    bsdf = mi.load_dict({"type": "thinfilm_sheet", "thickness": 0.0, "film_ior": 1.5})
    if mi.variant().startswith("llvm"):
        batches = [_interactions(mi, 32, seed=6)[0]]
    else:  # scalar: a few directions, one at a time
        import drjit as dr

        batches = []
        for wi in ([0.3, 0.2, 0.93], [0.0, 0.0, 1.0], [-0.5, 0.4, -0.76]):
            si = dr.zeros(mi.SurfaceInteraction3f)
            si.wi = dr.normalize(mi.Vector3f(*wi))
            si.sh_frame = mi.Frame3f(mi.Vector3f(0, 0, 1))
            si.wavelengths = mi.UnpolarizedSpectrum(450.0, 520.0, 610.0, 700.0)
            batches.append(si)
    for si in batches:
        for ctx in (mi.BSDFContext(mi.TransportMode.Radiance), mi.BSDFContext(mi.TransportMode.Importance)):
            bs, value = bsdf.sample(ctx, si, 0.5, mi.Point2f(0.5, 0.5))
            assert np.all(np.array(bs.sampled_type) == +mi.BSDFFlags.Null)
            M = _matrix(value)
            # Float32: near grazing incidence (|r| → 1) the zero-thickness Airy sum 1 = t t' / (1 - r²)
            # loses a few digits.
            np.testing.assert_allclose(M, np.eye(4).reshape(4, 4, *([1] * (M.ndim - 2))) * np.ones_like(M),
                                       atol=1e-5)
            if ctx.mode == mi.TransportMode.Radiance:
                np.testing.assert_allclose(_matrix(bsdf.eval_null_transmission(si)), M, atol=1e-7)


def test_unpolarized_weights_and_single_lobe_contexts(unpolarized_variant):
    """Unpolarized variants: the weight of either lobe is R + T (1 for a lossless film); with only one
    lobe enabled it is that lobe's R or T with probability 1 (tmm)."""
    mi = unpolarized_variant
    bsdf = mi.load_dict({"type": "thinfilm_sheet", "thickness": 520.0, "film_ior": 1.33,
                         "wavelength": 560.0})
    import drjit as dr

    si = dr.zeros(mi.SurfaceInteraction3f)
    si.wi = dr.normalize(mi.Vector3f(0.4, -0.1, -0.8))  # from the back
    si.sh_frame = mi.Frame3f(mi.Vector3f(0, 0, 1))
    lam = 560.0
    if mi.is_spectral:
        si.wavelengths = mi.UnpolarizedSpectrum(lam)
    theta = np.degrees(np.arccos(0.8 / np.sqrt(0.4**2 + 0.1**2 + 0.8**2)))
    ref_s, ref_p = _tmm(theta, lam, [(1.33, 520.0)])
    R, T = 0.5 * (ref_s["R"] + ref_p["R"]), 0.5 * (ref_s["T"] + ref_p["T"])
    for sample1 in (0.0, 0.999):
        bs, value = bsdf.sample(mi.BSDFContext(), si, sample1, mi.Point2f(0.5, 0.5))
        assert abs(np.ravel(np.array(bs.pdf))[0] - (R if sample1 == 0.0 else T)) < 2e-6
        np.testing.assert_allclose(np.ravel(np.array(value)), 1.0, atol=2e-6)
    for component, expected in ((0, R), (1, T)):
        ctx = mi.BSDFContext()
        ctx.component = component
        bs, value = bsdf.sample(ctx, si, 0.5, mi.Point2f(0.5, 0.5))
        assert abs(np.ravel(np.array(bs.pdf))[0] - 1.0) < 1e-7
        np.testing.assert_allclose(np.ravel(np.array(value)), expected, atol=2e-6)
    np.testing.assert_allclose(np.ravel(np.array(bsdf.eval_null_transmission(si))), T, atol=2e-6)


def test_thickness_average_at_normal_incidence_equals_thindielectric(variant_llvm_ad_mono):
    """Mitsuba's thindielectric sums the multiple reflections incoherently: r' = 2r / (1 + r). Averaged
    over one period of thickness (a full turn of the round-trip phase), the coherent reflectance of a
    lossless film is exactly that sum; at normal incidence (where s and p agree) compare the two."""
    mi = variant_llvm_ad_mono
    import drjit as dr

    n_film, lam = 1.5, 550.0
    period = lam / (2 * n_film)
    thicknesses = 300.0 + period * np.arange(64) / 64
    sheet = mi.load_dict({"type": "thinfilm_sheet", "film_ior": n_film, "wavelength": lam})
    params = mi.traverse(sheet)
    si = dr.zeros(mi.SurfaceInteraction3f, 1)
    si.wi = mi.Vector3f(0, 0, 1)
    si.sh_frame = mi.Frame3f(mi.Vector3f(0, 0, 1))
    reflect = []
    for d in thicknesses:
        params["thickness"] = float(d)
        params.update()
        reflect.append(float(np.ravel(np.array(sheet.sample(mi.BSDFContext(), si, 0.0, mi.Point2f(0.5, 0.5))[0].pdf))[0]))
    ref = mi.load_dict({"type": "thindielectric", "int_ior": n_film, "ext_ior": 1.0})
    bs, _ = ref.sample(mi.BSDFContext(), si, 0.0, mi.Point2f(0.5, 0.5))
    assert abs(np.mean(reflect) - float(np.ravel(np.array(bs.pdf))[0])) < 1e-6
    assert np.ptp(reflect) > 0.1  # the coherent film really oscillates


def test_named_water_film_and_thickness_texture(variant_llvm_ad_spectral_polarized):
    """Spectral: an H2O film whose thickness is a texture (thin at the top, thick at the bottom, like a
    draining bubble), reflection of the front side against tmm at each ray's wavelengths."""
    mi = variant_llvm_ad_spectral_polarized
    import drjit as dr

    from thinfilm.bsdf import named_material

    tex = mi.Bitmap(np.array([[150.0], [800.0]], dtype=np.float32))  # row 0: v = 0 (top)
    bsdf = mi.load_dict({"type": "thinfilm_sheet", "film_ior": "H2O",
                         "thickness": {"type": "bitmap", "bitmap": tex, "raw": True,
                                       "filter_type": "nearest"}})
    si, cos_t = _interactions(mi, 32, seed=8, both_sides=False)
    v = np.where(np.arange(32) < 16, 0.25, 0.75)
    si.uv = mi.Point2f(dr.zeros(mi.Float, 32) + 0.5, mi.Float(v))
    bs, value = bsdf.sample(mi.BSDFContext(), si, 0.0, mi.Point2f(0.5, 0.5))
    M = _to_sp_frame(mi, value, bs.wo, si.wi)
    dr.eval(M, bs)
    m00 = np.array(M[0, 0]) * np.array(bs.pdf)
    lams = np.array(si.wavelengths)
    water = named_material("H2O")
    for k, c in enumerate(cos_t):
        d = 150.0 if v[k] < 0.5 else 800.0
        for ch in range(4):
            ref_s, ref_p = _tmm(np.degrees(np.arccos(c)), lams[ch, k], [(float(water(lams[ch, k])), d)])
            assert abs(m00[ch, k] - 0.5 * (ref_s["R"] + ref_p["R"])) < 2e-5


def test_sheet_parameters(variant_llvm_ad_mono_polarized):
    mi = variant_llvm_ad_mono_polarized
    params = mi.traverse(mi.load_dict({"type": "thinfilm_sheet", "stack": "1.38:100, Au:10"}))
    assert {"layer_0.thickness", "layer_1.thickness", "layer_0.ior", "layer_0.k", "thickness_scale",
            "ext_ior", "wavelength"} <= set(params.keys())
    params = mi.traverse(mi.load_dict({"type": "thinfilm_sheet"}))
    assert {"thickness", "film_ior", "film_k", "thickness_scale"} <= set(params.keys())
    assert abs(params["film_ior"][0] - 1.33) < 1e-7 and abs(params["thickness"][0] - 400.0) < 1e-4
    for bad, message in [
        ({"stack": "1.4:100", "thickness": 20.0}, "thinfilm_sheet: parameter 'stack' cannot be combined with 'thickness'"),
        ({"thickness": -1.0}, "thinfilm_sheet: parameter 'thickness' must be a finite number from 0 to 100000 nm"),
        ({"ext_ior": 0.0}, "thinfilm_sheet: parameter 'ext_ior' must be a finite number from 0.01 to 100"),
        ({"film_ior": "Unobtainium"}, "thinfilm_sheet: parameter 'film_ior': unknown material 'Unobtainium'"),
    ]:
        with pytest.raises(Exception, match=message):
            mi.load_dict({"type": "thinfilm_sheet", **bad})


def test_sheet_loads_from_xml(variant_llvm_ad_spectral_polarized):
    mi = variant_llvm_ad_spectral_polarized
    bsdf = mi.load_string('<bsdf version="3.0.0" type="thinfilm_sheet">'
                          '<float name="thickness" value="350"/><string name="film_ior" value="H2O"/></bsdf>')
    assert "thickness=[350" in str(bsdf) and "H2O" in str(bsdf)
    assert bsdf.flags() & +mi.BSDFFlags.Null and bsdf.flags() & +mi.BSDFFlags.BackSide


def test_soap_bubble_example_renders(tmp_path):
    """examples/soap_bubble.xml through `thinfilm render` (one sample per pixel): the bubble shows in
    front of the dark backdrop."""
    from pathlib import Path

    from thinfilm.cli import main

    example = Path(__file__).resolve().parents[1] / "examples" / "soap_bubble.xml"
    rc = main(["render", str(example), "--out", str(tmp_path / "bubble"), "--spp", "1",
               "--variant", "llvm_ad_spectral"])
    assert rc == 0 and (tmp_path / "bubble.png").is_file()
    import mitsuba as mi

    image = np.array(mi.Bitmap(str(tmp_path / "bubble.exr")), dtype=np.float64)[..., :3]
    corner, centre = image[:40, :40].mean(), image[150:250, 150:250].mean()
    assert corner < 0.02 and centre > 5 * corner
