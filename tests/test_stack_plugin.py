"""The ``thinfilm`` plugin with film stacks, absorbing films and ``thickness_scale``, against tmm."""

import numpy as np
import pytest
import tmm
from _plugin_scenes import plane_scene, random_interactions, stokes_images

QW = 550.0
BRAGG = [(2.35, QW / (4 * 2.35)), (1.38, QW / (4 * 1.38))] * 10


def _stack_text(layers):
    return ", ".join(f"{n.real!r}+{n.imag!r}i:{d!r}" if isinstance(n, complex) else f"{n!r}:{d!r}"
                     for n, d in layers)


def _tmm_powers(theta_deg, lam, layers, substrate, n1=1.0):
    n_list = [n1] + [complex(n) for n, _ in layers] + [complex(substrate)]
    d_list = [np.inf] + [d for _, d in layers] + [np.inf]
    return [tmm.coh_tmm(pol, n_list, d_list, np.radians(theta_deg), lam)["R"] for pol in "sp"]


def _check_render(mi, scene, theta, lam, layers, substrate, n1=1.0):
    S0, S1, S2, S3 = stokes_images(mi, scene)
    Rs, Rp = _tmm_powers(theta, lam, layers, substrate, n1)
    # φ = 0: the s-direction is image y, so S1 = I(0°) − I(90°) = −(Rs − Rp)/2 (test_plugin.py).
    np.testing.assert_allclose(S0, 0.5 * (Rs + Rp), atol=1e-4, rtol=0)
    np.testing.assert_allclose(S1, -0.5 * (Rs - Rp), atol=1e-4, rtol=0)
    np.testing.assert_allclose(S2, 0.0, atol=1e-4)
    return S0


CASES = {
    # name: (plugin parameters, layers for tmm, substrate index)
    "absorbing_layer": ({"stack": "1.9+0.05i:300", "substrate_ior": 1.52},
                        [(1.9 + 0.05j, 300.0)], 1.52),
    "absorbing_stack": ({"stack": "1.38:110, 2.0+0.3i:40, 1.46:150", "substrate_ior": 1.6},
                        [(1.38, 110.0), (2.0 + 0.3j, 40.0), (1.46, 150.0)], 1.6),
    "bragg_mirror": ({"stack": _stack_text(BRAGG), "substrate_ior": 1.52}, BRAGG, 1.52),
    "metal_substrate": ({"stack": "1.38:100, 2.1:60", "substrate_ior": 0.27, "substrate_k": 3.4},
                        [(1.38, 100.0), (2.1, 60.0)], 0.27 + 3.4j),
    "film_k": ({"thickness": 260.0, "film_ior": 1.7, "film_k": 0.08, "substrate_ior": 1.5},
               [(1.7 + 0.08j, 260.0)], 1.5),
}


@pytest.mark.parametrize("name", sorted(CASES))
def test_mono_polarized_stack_render_matches_tmm(variant_llvm_ad_mono_polarized, name):
    mi = variant_llvm_ad_mono_polarized
    params_in, layers, substrate = CASES[name]
    theta = 40.0
    scene = plane_scene(mi, {"type": "thinfilm", **params_in}, theta, 0.0)
    params = mi.traverse(scene)
    for lam in (450.0, 550.0, 640.0):
        params["plane.bsdf.wavelength"] = lam
        params.update()
        _check_render(mi, scene, theta, lam, layers, substrate)


def test_bragg_mirror_render_reflects_in_its_stop_band(variant_llvm_ad_mono_polarized):
    mi = variant_llvm_ad_mono_polarized
    scene = plane_scene(mi, {"type": "thinfilm", "stack": _stack_text(BRAGG), "substrate_ior": 1.52,
                              "wavelength": 550.0}, 10.0, 0.0)
    assert np.all(stokes_images(mi, scene)[0] > 0.99)


def test_thickness_scale_multiplies_every_layer(variant_llvm_ad_mono_polarized):
    """A float scale (changed through traverse), and a texture scale varying over the plane."""
    mi = variant_llvm_ad_mono_polarized
    layers = [(1.38, 110.0), (2.1, 70.0)]
    theta, lam = 35.0, 520.0
    scene = plane_scene(mi, {"type": "thinfilm", "stack": _stack_text(layers), "substrate_ior": 1.6,
                              "wavelength": lam}, theta, 0.0)
    params = mi.traverse(scene)
    for scale in (0.0, 0.6, 1.7):
        params["plane.bsdf.thickness_scale"] = scale
        params.update()
        _check_render(mi, scene, theta, lam, [(n, d * scale) for n, d in layers], 1.6)

    tex = mi.Bitmap(np.array([[0.5, 2.0]], dtype=np.float32))
    bsdf = {"type": "thinfilm", "thickness": 300.0, "film_ior": 1.45, "substrate_ior": 1.6,
            "wavelength": lam,
            "thickness_scale": {"type": "bitmap", "bitmap": tex, "raw": True, "filter_type": "nearest"}}
    S0 = stokes_images(mi, plane_scene(mi, bsdf, theta, 0.0, res=8))[0]
    expected = {s: 0.5 * sum(_tmm_powers(theta, lam, [(1.45, 300.0 * s)], 1.6)) for s in (0.5, 2.0)}
    halves = (S0[:, :2], S0[:, -2:])
    found = sorted(s for half in halves for s, v in expected.items() if np.allclose(half, v, atol=1e-4))
    assert found == [0.5, 2.0]


def test_named_absorbing_film_keeps_its_extinction(variant_llvm_ad_spectral_polarized):
    """A 25 nm gold film (the Au table's n and k at each ray's wavelength) on glass, spectral."""
    mi = variant_llvm_ad_spectral_polarized
    from thinfilm.bsdf import named_material

    au = named_material("Au")
    for bsdf in ({"type": "thinfilm", "thickness": 25.0, "film_ior": "Au", "substrate_ior": 1.52},
                 {"type": "thinfilm", "stack": "1.38:90, Au:25", "substrate_ior": 1.52}):
        layers_of = (lambda n_au: [(n_au, 25.0)]) if "film_ior" in bsdf else \
            (lambda n_au: [(1.38, 90.0), (n_au, 25.0)])
        plugin = mi.load_dict(bsdf)
        si = random_interactions(mi, 24, seed=9)[0]
        _, value = plugin.sample(mi.BSDFContext(), si, 0.5, mi.Point2f(0.5, 0.5))
        m00, lams, cos_t = np.array(value[0, 0]), np.array(si.wavelengths), np.array(si.wi.z)
        worst = 0.0
        for k in range(cos_t.size):
            for ch in range(4):
                lam = lams[ch, k]
                n_au = complex(float(au(lam)), float(au.extinction(lam)))
                ref = 0.5 * sum(_tmm_powers(np.degrees(np.arccos(cos_t[k])), lam, layers_of(n_au), 1.52))
                worst = max(worst, abs(m00[ch, k] - ref))
        assert worst < 2e-5


@pytest.mark.parametrize("mitsuba_variant", ["llvm_ad_spectral_polarized", "llvm_ad_mono_polarized",
                                             "llvm_ad_spectral"], indirect=True)
def test_one_layer_stack_equals_single_film_bit_for_bit(mitsuba_variant):
    """``stack = "n:d"`` and ``film_ior = n, thickness = d`` give identical Mueller matrices, and
    film_k = 0 changes nothing against a lossless film."""
    mi = mitsuba_variant
    import drjit as dr

    si = random_interactions(mi, 64, seed=11)[0]
    ctx = mi.BSDFContext()
    results = []
    for bsdf in ({"stack": "1.45:380"}, {"film_ior": 1.45, "thickness": 380.0},
                 {"film_ior": 1.45, "thickness": 380.0, "film_k": 0.0},
                 {"stack": "1.45+0i:380", "thickness_scale": 1.0}):
        plugin = mi.load_dict({"type": "thinfilm", "substrate_ior": 0.27, "substrate_k": 3.4,
                               "wavelength": 480.0, **bsdf})
        value = plugin.sample(ctx, si, 0.5, mi.Point2f(0.5, 0.5))[1]
        dr.eval(value)
        results.append(np.array(value) if not mi.is_polarized else
                       np.array([[np.array(value[i, j]) for j in range(4)] for i in range(4)]))
    assert np.abs(results[0]).max() > 0.1
    for other in results[1:]:
        assert np.array_equal(results[0], other)


def test_stack_layers_are_exposed_and_differentiable(variant_llvm_ad_mono_polarized):
    mi = variant_llvm_ad_mono_polarized
    import drjit as dr

    bsdf = mi.load_dict({"type": "thinfilm", "stack": "MgF2:95, 2.1:62, 1.65+0.01i:80",
                         "substrate_ior": 1.52, "wavelength": 530.0})
    params = mi.traverse(bsdf)
    keys = set(params.keys())
    assert {"layer_0.thickness", "layer_1.thickness", "layer_2.thickness", "layer_1.ior",
            "layer_1.k", "layer_2.ior", "layer_2.k", "thickness_scale", "substrate_ior"} <= keys
    assert "layer_0.ior" not in keys and "thickness" not in keys and "film_ior" not in keys
    assert abs(params["layer_2.k"][0] - 0.01) < 1e-7

    si = random_interactions(mi, 8, seed=4)[0]
    ctx = mi.BSDFContext()

    def m00(d):
        params["layer_1.thickness"] = d
        params.update()
        return np.array(bsdf.sample(ctx, si, 0.5, mi.Point2f(0.5, 0.5))[1][0, 0]).ravel()

    # The value after an update is tmm's.
    from thinfilm.bsdf import named_material

    n_mgf2 = float(named_material("MgF2")(530.0))
    got = m00(140.0)
    for k, c in enumerate(np.array(si.wi.z)):
        ref = 0.5 * sum(_tmm_powers(np.degrees(np.arccos(c)), 530.0,
                                    [(n_mgf2, 95.0), (2.1, 140.0), (1.65 + 0.01j, 80.0)], 1.52))
        assert abs(got[k] - ref) < 2e-5

    h = 0.05
    fd = (m00(62.0 + h) - m00(62.0 - h)) / (2 * h)
    params["layer_1.thickness"] = mi.Float(62.0)
    dr.enable_grad(params["layer_1.thickness"])
    params.update()
    value = bsdf.sample(ctx, si, 0.5, mi.Point2f(0.5, 0.5))[1][0, 0]
    dr.forward(params["layer_1.thickness"])
    grad = np.array(dr.grad(value)).ravel()
    assert np.abs(fd).max() > 1e-5
    np.testing.assert_allclose(grad, fd, rtol=2e-2, atol=2e-6)


@pytest.mark.parametrize("bad, message", [
    ({"stack": "1.5:100", "film_ior": 1.4}, "thinfilm: parameter 'stack' cannot be combined with 'film_ior'"),
    ({"stack": "1.5:100", "thickness": 50.0}, "thinfilm: parameter 'stack' cannot be combined with 'thickness'"),
    ({"stack": "1.5:100", "film_k": 0.1}, "thinfilm: parameter 'stack' cannot be combined with 'film_k'"),
    ({"stack": "1.5:100, Unobtainium:20"}, "thinfilm: parameter 'stack': stack item 'Unobtainium:20': "
                                           "unknown material 'Unobtainium'"),
    ({"stack": "1.5 100"}, "thinfilm: parameter 'stack': stack item '1.5 100': expected INDEX:THICKNESS_NM"),
    ({"stack": 3.0}, "thinfilm: parameter 'stack' must be a string"),
    ({"film_ior": "Au", "film_k": 0.1}, "thinfilm: parameter 'film_k' cannot be combined with film_ior 'Au'"),
    ({"film_k": -0.1}, "thinfilm: parameter 'film_k' must be a finite number from 0 to 100, got -0.1"),
    ({"thickness_scale": -1.0}, "thinfilm: parameter 'thickness_scale' must be a finite number from 0 to 100000, got -1.0"),
])
def test_bad_stack_parameters_raise_one_clear_error(variant_llvm_ad_mono_polarized, bad, message):
    mi = variant_llvm_ad_mono_polarized
    with pytest.raises(Exception, match=message.replace("(", r"\(")):
        mi.load_dict({"type": "thinfilm", **bad})


def test_bad_layer_update_is_refused(variant_llvm_ad_mono_polarized):
    mi = variant_llvm_ad_mono_polarized
    bsdf = mi.load_dict({"type": "thinfilm", "stack": "1.5:100, 2.0:50"})
    params = mi.traverse(bsdf)
    params["layer_1.thickness"] = -1.0
    with pytest.raises(ValueError, match="'layer_1.thickness' must be a finite number from 0 to 100000"):
        params.update()


def test_stack_loads_from_xml(variant_llvm_ad_spectral_polarized):
    mi = variant_llvm_ad_spectral_polarized
    bsdf = mi.load_string(
        '<bsdf version="3.0.0" type="thinfilm">'
        '<string name="stack" value="MgF2:95, 2.1:62, 1.65+0.01i:80"/>'
        '<float name="thickness_scale" value="1.1"/><float name="substrate_ior" value="1.52"/></bsdf>')
    text = str(bsdf)
    assert "MgF2:[95" in text and "[1.65]+[0.01]i:[80" in text
