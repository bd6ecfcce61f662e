"""The Mitsuba ``thinfilm`` plugin against tmm and against Mitsuba's own ``conductor``."""

import numpy as np
import pytest

import tmm  # noqa: E402
from _plugin_scenes import orthographic_sensor, plane_scene, random_interactions, stokes_images


def _tmm_R(pol, theta_deg, lam, d, n2, n3, k3=0.0):
    if d == 0:
        return tmm.coh_tmm(pol, [1.0, complex(n3, k3)], [np.inf, np.inf], np.radians(theta_deg), lam)["R"]
    return tmm.coh_tmm(pol, [1.0, n2, complex(n3, k3)], [np.inf, d, np.inf], np.radians(theta_deg), lam)["R"]


# --- rendered against tmm ----------------------------------------------------------------


@pytest.mark.parametrize("theta", [15.0, 45.0, 70.0])
def test_mono_polarized_render_matches_tmm(variant_llvm_ad_mono_polarized, theta):
    mi = variant_llvm_ad_mono_polarized
    scene = plane_scene(mi, {"type": "thinfilm", "film_ior": 1.37, "substrate_ior": 1.6}, theta, 0.0)
    params = mi.traverse(scene)
    for lam in (420.0, 550.0, 690.0):
        for d in (0.0, 250.0, 630.0, 1000.0):
            params["plane.bsdf.wavelength"] = lam
            params["plane.bsdf.thickness"] = d
            params.update()
            S0, S1, S2, S3 = stokes_images(mi, scene)
            Rs, Rp = _tmm_R("s", theta, lam, d, 1.37, 1.6), _tmm_R("p", theta, lam, d, 1.37, 1.6)
            # φ = 0: the s-direction is image y, so S1 = I(0°) − I(90°) = −(Rs − Rp)/2.
            np.testing.assert_allclose(S0, 0.5 * (Rs + Rp), atol=1e-4, rtol=0)
            np.testing.assert_allclose(S1, -0.5 * (Rs - Rp), atol=1e-4, rtol=0)
            np.testing.assert_allclose(S2, 0.0, atol=1e-4)
            np.testing.assert_allclose(S3, 0.0, atol=1e-6)


@pytest.mark.parametrize("phi", [0.0, 30.0, 120.0, 200.0, 315.0])
def test_stokes_frame_peak_at_s_direction(variant_llvm_ad_mono_polarized, phi):
    """The frame of docs/design.md, *Conventions*: behind a polarizer at α the intensity peaks
    at α = φ + 90°."""
    mi = variant_llvm_ad_mono_polarized
    scene = plane_scene(mi, {"type": "thinfilm", "thickness": 300.0, "wavelength": 500.0}, 50.0, phi)
    S0, S1, S2, _ = stokes_images(mi, scene)
    alpha = np.radians(np.arange(0.0, 180.0, 0.25))
    intensity = 0.5 * (S0[1, 1] + S1[1, 1] * np.cos(2 * alpha) + S2[1, 1] * np.sin(2 * alpha))
    peak = np.degrees(alpha[np.argmax(intensity)])
    expected = (phi + 90.0) % 180.0
    assert abs((peak - expected + 90.0) % 180.0 - 90.0) <= 0.25


def test_thickness_texture_varies_over_surface(variant_llvm_ad_mono_polarized):
    mi = variant_llvm_ad_mono_polarized
    tex = mi.Bitmap(np.array([[200.0, 600.0]], dtype=np.float32))
    bsdf = {"type": "thinfilm", "wavelength": 520.0,
            "thickness": {"type": "bitmap", "bitmap": tex, "raw": True, "filter_type": "nearest"}}
    S0 = stokes_images(mi, plane_scene(mi, bsdf, 30.0, 0.0, res=8))[0]
    expected = {d: 0.5 * (_tmm_R("s", 30.0, 520.0, d, 1.37, 1.6) + _tmm_R("p", 30.0, 520.0, d, 1.37, 1.6))
                for d in (200.0, 600.0)}
    left, right = S0[:, :2], S0[:, -2:]
    matches = [d for d, v in expected.items() if np.allclose(left, v, atol=1e-4)]
    matches += [d for d, v in expected.items() if np.allclose(right, v, atol=1e-4)]
    assert sorted(matches) == [200.0, 600.0]


# --- against Mitsuba's conductor -----------------------------------------------------------


@pytest.mark.parametrize("substrate", [(1.6, 0.0), (0.27, 3.4), (1.2, 7.0)])
@pytest.mark.parametrize("mode", ["Radiance", "Importance"])
def test_thickness_zero_mueller_equals_conductor(polarized_variant, substrate, mode):
    mi = polarized_variant
    n3, k3 = substrate
    ours = mi.load_dict({"type": "thinfilm", "thickness": 0.0, "substrate_ior": n3, "substrate_k": k3})
    ref = mi.load_dict({"type": "conductor", "eta": n3, "k": k3})
    ctx = mi.BSDFContext(getattr(mi.TransportMode, mode))
    for si in random_interactions(mi, 64, seed=3):
        bs_o, v_o = ours.sample(ctx, si, 0.5, mi.Point2f(0.5, 0.5))
        bs_r, v_r = ref.sample(ctx, si, 0.5, mi.Point2f(0.5, 0.5))
        np.testing.assert_allclose(np.array(bs_o.wo), np.array(bs_r.wo), atol=1e-7)
        assert np.all(np.array(bs_o.sampled_type) == np.array(bs_r.sampled_type))
        for i in range(4):
            for j in range(4):
                np.testing.assert_allclose(np.array(v_o[i, j]), np.array(v_r[i, j]), atol=2e-6, rtol=1e-5)


@pytest.mark.parametrize("substrate", [(1.6, 0.0), (0.27, 3.4)])
def test_thickness_zero_render_equals_conductor(variant_llvm_ad_spectral_polarized, substrate):
    """Spectral polarized render, same seed: thinfilm(d=0) and conductor agree pixel by pixel,
    in every Stokes channel (random wavelengths, so the spectral path is exercised)."""
    mi = variant_llvm_ad_spectral_polarized
    n3, k3 = substrate

    def render(bsdf):
        scene = mi.load_dict({
            "type": "scene",
            "integrator": {"type": "stokes", "nested": {"type": "path", "max_depth": 3, "hide_emitters": True}},
            "sensor": orthographic_sensor(mi, 24, spp=4, stratified=False, seed=7),
            "emitter": {"type": "constant"},
            "ball": {"type": "sphere", "radius": 0.8, "bsdf": bsdf},
            "ball2": {"type": "sphere", "radius": 0.4, "center": [0.9, 0.9, -0.5], "bsdf": bsdf},
        })
        return np.array(mi.render(scene, seed=11))

    a = render({"type": "thinfilm", "thickness": 0.0, "substrate_ior": n3, "substrate_k": k3})
    b = render({"type": "conductor", "eta": n3, "k": k3})
    assert np.abs(b).max() > 0.01
    np.testing.assert_allclose(a, b, atol=2e-6, rtol=1e-5)


# --- unpolarized variants, spectral film index ----------------------------------------------


def test_unpolarized_value_is_mean_reflectance(unpolarized_variant):
    mi = unpolarized_variant
    bsdf = mi.load_dict({"type": "thinfilm", "thickness": 480.0, "film_ior": 1.37, "substrate_ior": 1.6,
                         "wavelength": 610.0})
    ctx = mi.BSDFContext()
    for si in random_interactions(mi, 16, seed=5):
        _, value = bsdf.sample(ctx, si, 0.5, mi.Point2f(0.5, 0.5))
        cos_t = np.atleast_1d(np.array(si.wi.z if mi.variant().startswith("llvm") else [si.wi.z]))
        vals = np.atleast_2d(np.array(value))
        lams = np.atleast_2d(np.array(si.wavelengths)) if mi.is_spectral else None
        for k, c in enumerate(cos_t):
            theta = np.degrees(np.arccos(c))
            for ch in range(4 if mi.is_spectral else 1):
                lam = (lams[ch, k] if lams.shape[0] == 4 and lams.ndim == 2 and lams.shape[1] == cos_t.size
                       else lams.ravel()[ch]) if mi.is_spectral else 610.0
                v = (vals[ch, k] if vals.shape[0] == (4 if mi.is_spectral else 1) and vals.shape[-1] == cos_t.size
                     else vals.ravel()[ch])
                ref = 0.5 * (_tmm_R("s", theta, lam, 480.0, 1.37, 1.6) + _tmm_R("p", theta, lam, 480.0, 1.37, 1.6))
                assert abs(v - ref) < 2e-5


def test_named_film_material_uses_its_dispersion(variant_llvm_ad_spectral_polarized):
    mi = variant_llvm_ad_spectral_polarized
    from thinfilm.bsdf import named_material

    bsdf = mi.load_dict({"type": "thinfilm", "thickness": 350.0, "film_ior": "MgF2", "substrate_ior": 1.6})
    si = random_interactions(mi, 32, seed=9)[0]
    _, value = bsdf.sample(mi.BSDFContext(), si, 0.5, mi.Point2f(0.5, 0.5))
    m00 = np.array(value[0, 0])
    lams = np.array(si.wavelengths)
    cos_t = np.array(si.wi.z)
    for k in range(cos_t.size):
        for ch in range(4):
            lam = lams[ch, k]
            n2 = float(named_material("MgF2")(lam))
            theta = np.degrees(np.arccos(cos_t[k]))
            ref = 0.5 * (_tmm_R("s", theta, lam, 350.0, n2, 1.6) + _tmm_R("p", theta, lam, 350.0, n2, 1.6))
            assert abs(m00[ch, k] - ref) < 2e-5


# --- parameters, kernels, errors ---------------------------------------------------------------


def test_wavelength_sweep_reuses_compiled_kernel(variant_llvm_ad_mono_polarized):
    mi = variant_llvm_ad_mono_polarized
    import drjit as dr

    scene = plane_scene(mi, {"type": "thinfilm"}, 40.0, 10.0, res=16)
    params = mi.traverse(scene)
    for key in ("plane.bsdf.thickness", "plane.bsdf.film_ior", "plane.bsdf.wavelength"):
        assert key in params
    old = dr.flag(dr.JitFlag.KernelHistory)
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    try:
        results = []
        for i, lam in enumerate([450.0, 500.0, 550.0, 600.0, 650.0]):
            params["plane.bsdf.wavelength"] = lam
            params.update()
            results.append(stokes_images(mi, scene)[0][8, 8])
            history = [k for k in dr.kernel_history() if k["type"] == dr.KernelType.JIT]
            if i >= 2:  # after a warm-up band, no band compiles a new kernel
                assert history and all(k["cache_hit"] for k in history)
    finally:
        dr.set_flag(dr.JitFlag.KernelHistory, old)
    assert len(set(np.round(results, 6))) == 5  # the wavelength really changed the result


@pytest.mark.parametrize("bad, message", [
    ({"thickness": -5.0}, "'thickness' must be a finite number from 0 to 100000 nm, got -5.0"),
    ({"film_ior": 0.0}, "'film_ior' must be a finite number from 0.01 to 100, got 0.0"),
    ({"substrate_ior": -1.6}, "'substrate_ior' must be a finite number from 0.01 to 100, got -1.6"),
    ({"substrate_k": -0.1}, "'substrate_k' must be a finite number from 0 to 1000000, got -0.1"),
    ({"film_ior": "unobtainium"}, "unknown material 'unobtainium'"),
    ({"wavelength": 0.0}, "'wavelength' must be a finite number from 1 to 100000 nm, got 0.0"),
])
def test_bad_parameters_raise_one_clear_error(variant_llvm_ad_mono_polarized, bad, message):
    mi = variant_llvm_ad_mono_polarized
    with pytest.raises(Exception, match=message):
        mi.load_dict({"type": "thinfilm", **bad})


def test_bad_parameter_update_is_refused(variant_llvm_ad_mono_polarized):
    mi = variant_llvm_ad_mono_polarized
    scene = plane_scene(mi, {"type": "thinfilm"}, 30.0, 0.0)
    params = mi.traverse(scene)
    params["plane.bsdf.thickness"] = -1.0
    with pytest.raises(ValueError, match="'thickness' must be a finite number from 0 to 100000"):
        params.update()


def test_loads_from_xml(variant_llvm_ad_spectral_polarized):
    mi = variant_llvm_ad_spectral_polarized
    bsdf = mi.load_string(
        '<bsdf version="3.0.0" type="thinfilm">'
        '<float name="thickness" value="420"/><string name="film_ior" value="MgF2"/>'
        '<float name="substrate_ior" value="1.5"/></bsdf>')
    assert "thickness=[420" in str(bsdf) and "MgF2" in str(bsdf)


def test_spectrum_film_index(variant_llvm_ad_spectral_polarized):
    """film_ior given as a Mitsuba spectrum is evaluated at each ray's wavelengths."""
    mi = variant_llvm_ad_spectral_polarized
    bsdf = mi.load_dict({"type": "thinfilm", "thickness": 500.0, "substrate_ior": 1.6,
                         "film_ior": {"type": "spectrum", "value": [(360.0, 1.42), (830.0, 1.34)]}})
    si = random_interactions(mi, 16, seed=2)[0]
    _, value = bsdf.sample(mi.BSDFContext(), si, 0.5, mi.Point2f(0.5, 0.5))
    m00, lams, cos_t = np.array(value[0, 0]), np.array(si.wavelengths), np.array(si.wi.z)
    for k in range(cos_t.size):
        for ch in range(4):
            lam = lams[ch, k]
            n2 = 1.42 + (1.34 - 1.42) * (lam - 360.0) / (830.0 - 360.0)
            theta = np.degrees(np.arccos(cos_t[k]))
            ref = 0.5 * (_tmm_R("s", theta, lam, 500.0, n2, 1.6) + _tmm_R("p", theta, lam, 500.0, n2, 1.6))
            assert abs(m00[ch, k] - ref) < 2e-5


def test_thickness_gradient_matches_finite_differences(variant_llvm_ad_mono_polarized):
    """Dr.Jit AD through the plugin (as the reconstruction forward models use it)."""
    mi = variant_llvm_ad_mono_polarized
    import drjit as dr

    bsdf = mi.load_dict({"type": "thinfilm", "thickness": 420.0, "wavelength": 530.0})
    params = mi.traverse(bsdf)
    si = random_interactions(mi, 8, seed=4)[0]
    ctx = mi.BSDFContext()

    def m00(thickness):
        params["thickness"] = thickness
        params.update()
        return np.array(bsdf.sample(ctx, si, 0.5, mi.Point2f(0.5, 0.5))[1][0, 0]).ravel()

    h = 0.05
    fd = (m00(420.0 + h) - m00(420.0 - h)) / (2 * h)
    params["thickness"] = mi.Float(420.0)
    dr.enable_grad(params["thickness"])
    params.update()
    value = bsdf.sample(ctx, si, 0.5, mi.Point2f(0.5, 0.5))[1][0, 0]
    dr.forward(params["thickness"])
    grad = np.array(dr.grad(value)).ravel()
    assert np.abs(fd).max() > 1e-5
    np.testing.assert_allclose(grad, fd, rtol=2e-2, atol=2e-6)


def test_exterior_index_in_plugin_matches_tmm(variant_llvm_ad_mono_polarized):
    mi = variant_llvm_ad_mono_polarized
    theta = 35.0
    scene = plane_scene(mi, {"type": "thinfilm", "thickness": 300.0, "film_ior": 1.45,
                              "substrate_ior": 1.7, "ext_ior": 1.33, "wavelength": 600.0}, theta, 0.0)
    S0 = stokes_images(mi, scene)[0]
    args = ([1.33, 1.45, 1.7], [np.inf, 300.0, np.inf], np.radians(theta), 600.0)
    ref = 0.5 * (tmm.coh_tmm("s", *args)["R"] + tmm.coh_tmm("p", *args)["R"])
    np.testing.assert_allclose(S0, ref, atol=1e-4, rtol=0)


def _bitmap(mi, value, fill=300.0):
    data = np.full((2, 2, 1), fill, np.float32)
    data[0, 0, 0] = value
    return {"type": "bitmap", "bitmap": mi.Bitmap(data), "raw": True, "filter_type": "nearest"}


def _last_line(error):
    """The one line a user reads: Mitsuba wraps a Python plugin's error, traceback and all."""
    return str(error).strip().splitlines()[-1]


@pytest.mark.parametrize("plugin", ["thinfilm", "thinfilm_sheet"])
@pytest.mark.parametrize("bad, message", [
    ({"thickness": float("inf")}, "parameter 'thickness' must be a finite number from 0 to 100000 nm, got inf"),
    ({"thickness": 1e6}, "parameter 'thickness' must be a finite number from 0 to 100000 nm, got 1000000.0"),
    ({"film_ior": float("nan")}, "parameter 'film_ior' must be a finite number from 0.01 to 100, got nan"),
    ({"film_k": float("inf")}, "parameter 'film_k' must be a finite number from 0 to 100, got inf"),
    ({"ext_ior": 1e9}, "parameter 'ext_ior' must be a finite number from 0.01 to 100, got 1000000000.0"),
    ({"film_ior": "1.5+200i"}, "parameter 'film_ior' extinction k must be a finite number from 0 to 100, got 200.0"),
    ({"thickness_scale": float("nan")}, "parameter 'thickness_scale' must be a finite number from 0 to 100000, got nan"),
    ({"stack": "1.5:100, 2.1:1e7"}, "parameter 'layer_1.thickness' must be a finite number from 0 to 100000 nm, "
                                    "got 10000000.0"),
    ({"stack": "1.5:100, 150:80"}, "parameter 'layer_1.ior' must be a finite number from 0.01 to 100, got 150.0"),
    ({"stack": ", ".join(["1.5:100"] * 201)}, "parameter 'stack' holds 201 layers, at most 200 in llvm_ad_mono_polarized"),
    ({"stack": ", ".join(["1.5:100"] * 10000)}, "parameter 'stack' holds 10000 layers, at most 200 in llvm_ad_mono_polarized"),
])
def test_out_of_range_parameters_are_one_line_naming_them(variant_llvm_ad_mono_polarized, plugin, bad, message):
    mi = variant_llvm_ad_mono_polarized
    with pytest.raises(RuntimeError) as info:
        mi.load_dict({"type": plugin, **bad})
    line = _last_line(info.value)
    assert line == f"ParameterError: {plugin}: {message}" or line.startswith(f"ParameterError: {plugin}: {message} ("), line


@pytest.mark.parametrize("bad, message", [
    ({"alpha": 5.0}, "parameter 'alpha' must be a finite number from 0 to 1, got 5.0"),
    ({"alpha": float("inf")}, "parameter 'alpha' must be a finite number from 0 to 1, got inf"),
    ({"alpha_u": 0.1, "alpha_v": float("nan")}, "parameter 'alpha_v' must be a finite number from 0 to 1, got nan"),
    ({"substrate_ior": float("inf")}, "parameter 'substrate_ior' must be a finite number from 0.01 to 100, got inf"),
    ({"substrate_k": 1e7}, "parameter 'substrate_k' must be a finite number from 0 to 1000000, got 10000000.0"),
    ({"wavelength": float("nan")}, "parameter 'wavelength' must be a finite number from 1 to 100000 nm, got nan"),
])
def test_out_of_range_surface_parameters_are_one_line_naming_them(variant_llvm_ad_mono_polarized, bad, message):
    mi = variant_llvm_ad_mono_polarized
    with pytest.raises(RuntimeError) as info:
        mi.load_dict({"type": "thinfilm", **bad})
    assert _last_line(info.value) == f"ParameterError: thinfilm: {message}"


@pytest.mark.parametrize("plugin", ["thinfilm", "thinfilm_sheet"])
@pytest.mark.parametrize("name, value, shown, expected", [
    ("thickness", float("nan"), "nan", "a finite number from 0 to 100000 nm"),
    ("thickness", -100.0, "-100", "a finite number from 0 to 100000 nm"),
    ("thickness_scale", float("inf"), "inf", "a finite number from 0 to 100000"),
])
def test_bitmap_textures_holding_bad_values_are_refused(variant_llvm_ad_mono_polarized, plugin, name, value, shown,
                                                        expected):
    mi = variant_llvm_ad_mono_polarized
    with pytest.raises(RuntimeError) as info:
        mi.load_dict({"type": plugin, name: _bitmap(mi, value)})
    assert _last_line(info.value) == (f"ParameterError: {plugin}: parameter '{name}': the texture holds {shown} "
                                      f"(1 of the 4 values of its 'data' out of range); expected {expected}")


def test_bad_roughness_and_nested_textures_are_refused(variant_llvm_ad_mono_polarized):
    mi = variant_llvm_ad_mono_polarized
    with pytest.raises(RuntimeError, match=r"parameter 'alpha': the texture holds 3 \(4 of the 4 values of its "
                                           r"'data' out of range\); expected a finite number from 0 to 1$"):
        mi.load_dict({"type": "thinfilm", "alpha": _bitmap(mi, 3.0, fill=3.0)})
    with pytest.raises(RuntimeError, match=r"parameter 'thickness': the texture holds -5 \(1 of the 1 values of "
                                           r"its 'color0.value' out of range\)"):
        mi.load_dict({"type": "thinfilm", "thickness": {"type": "checkerboard", "color0": -5.0, "color1": 300.0}})


def test_a_good_bitmap_texture_loads_and_bad_updates_are_refused(variant_llvm_ad_mono_polarized):
    mi = variant_llvm_ad_mono_polarized
    bsdf = mi.load_dict({"type": "thinfilm", "thickness": _bitmap(mi, 250.0), "alpha": 0.2})
    params = mi.traverse(bsdf)
    params["alpha"] = 5.0
    with pytest.raises(ValueError, match=r"'alpha' must be a finite number from 0 to 1, got \[5\]"):
        params.update()
    params["alpha"] = 0.2
    params["substrate_ior"] = float("inf")
    with pytest.raises(RuntimeError, match=r"'substrate_ior' must be a finite number from 0.01 to 100, got \[inf\]"):
        params.update()


def test_the_rgb_variants_allow_fewer_layers(variant_llvm_ad_rgb):
    mi = variant_llvm_ad_rgb
    from thinfilm.bsdf.limits import MAX_STACK_LAYERS_RGB

    mi.load_dict({"type": "thinfilm", "stack": ", ".join(["1.5:100"] * MAX_STACK_LAYERS_RGB)})  # loads, no render
    with pytest.raises(RuntimeError) as info:
        mi.load_dict({"type": "thinfilm", "stack": ", ".join(["1.5:100"] * (MAX_STACK_LAYERS_RGB + 1))})
    assert _last_line(info.value).startswith(f"ParameterError: thinfilm: parameter 'stack' holds "
                                             f"{MAX_STACK_LAYERS_RGB + 1} layers, at most {MAX_STACK_LAYERS_RGB} "
                                             f"in llvm_ad_rgb")
