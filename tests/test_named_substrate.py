"""A scene spec's ``substrate.ior`` as a material name: rendered as tmm with the material's
own index, recorded by name in meta.json, reconstructed and evaluated from the command line;
an unknown name or a name with ``substrate.k`` is one line with exit status 2."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from _gen_fixtures import interior_pixels, small_spec, tmm_rs_rp

pytestmark = pytest.mark.slow


def _bk7_sellmeier(wavelength_nm):
    """Schott N-BK7 from its data sheet's Sellmeier formula (not from the shipped table)."""
    b = (1.03961212, 0.231792344, 1.01046945)
    c = (0.00600069867, 0.0200179144, 103.560653)
    l2 = (np.asarray(wavelength_nm, dtype=np.float64) / 1000.0) ** 2
    return np.sqrt(1.0 + sum(bi * l2 / (l2 - ci) for bi, ci in zip(b, c)))


def test_a_bk7_substrate_renders_as_tmm_with_the_sellmeier_index(tmp_path, render_variant_module):
    """Noise-free, point bands (no passband): R_s of air | film 1.37 | N-BK7 at the ground-truth
    zenith and thickness, the substrate index at each band from the Sellmeier formula; the spec
    echo and meta.json keep the name, and the echo loads back to an equal spec."""
    from thinfilm.core.io import read_dataset
    from thinfilm.generators.generate import generate_dataset
    from thinfilm.generators.spec import load_spec

    spec = small_spec("hemisphere", 12, extra=("substrate.ior=BK7", "rig.band_fwhm_nm=0"))
    generate_dataset(spec, tmp_path / "ds", progress=False)
    ds = read_dataset(tmp_path / "ds", need=("ground_truth", "spectral_s"))
    assert ds.meta["substrate_ior"] == "BK7" and ds.meta["film"]["substrate"] == {"ior": "BK7"}
    assert ds.film().effective_substrate_index() == pytest.approx(_bk7_sellmeier(550.0), abs=1e-5)
    assert load_spec(str(tmp_path / "ds" / "scene.toml")) == spec
    gt = ds.ground_truth
    wl = ds.wavelengths_nm
    rows, cols = interior_pixels(gt["mask"] & (gt["zenith"] < 60), 4)
    assert len(rows) == 4
    for r, c in zip(rows, cols):
        ref = np.array([tmm_rs_rp(gt["zenith"][r, c], lam, gt["thickness"][r, c], ds.meta["film_ior"],
                                  _bk7_sellmeier(lam))[0] for lam in wl])
        np.testing.assert_allclose(ds.spectral_s[r, c], ref, rtol=2e-4, atol=2e-6)


def test_a_database_substrate_is_recorded_with_its_page(render_variant_module):
    from thinfilm.core.errors import ThinfilmWarning

    with pytest.warns(ThinfilmWarning, match=r"substrate k up to \d+(\.\d+)? > 0 \(absorbing\)"):
        spec = small_spec("hemisphere", 8, extra=("substrate.ior=main/Ag/Johnson",))
    meta = spec.film.to_meta()
    assert meta["substrate_ior"] == "main/Ag/Johnson"
    assert "refractiveindex.info database" in meta["film"]["material_sources"]["main/Ag/Johnson"]
    assert 'ior = "main/Ag/Johnson"' in spec.to_toml()


def _cli(*argv):
    return subprocess.run([sys.executable, "-m", "thinfilm.cli", *map(str, argv)], capture_output=True,
                          text=True, timeout=600)


def test_named_substrates_from_generate_to_evaluate(tmp_path):
    """BK7: generate, reconstruct rgb and spectral, evaluate. Au: the spectral methods refuse
    the absorbing substrate in one line, as they do for a numeric n + ki."""
    d, e, v = tmp_path / "D", tmp_path / "E", tmp_path / "V"
    proc = _cli("generate", "hemisphere", "--out", d, "--resolution", 16, "--set", "substrate.ior=BK7")
    assert proc.returncode == 0, proc.stderr
    assert json.loads((d / "meta.json").read_text())["substrate_ior"] == "BK7"
    for kind in ("rgb", "spectral"):
        proc = _cli("reconstruct", kind, d, "--out", e / kind)
        assert proc.returncode == 0, proc.stderr
        proc = _cli("evaluate", d, e / kind, "--out", v / kind)
        assert proc.returncode == 0, proc.stderr
        metrics = json.loads((v / kind / "metrics.json").read_text())
        assert metrics["normal_error_deg"]["mean"] < 3.0, metrics

    au = tmp_path / "Au"
    proc = _cli("generate", "hemisphere", "--out", au, "--resolution", 8, "--set", "substrate.ior=Au")
    assert proc.returncode == 0, proc.stderr
    proc = _cli("reconstruct", "spectral", au, "--out", tmp_path / "AuE")
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode == 2 and len(lines) == 1, proc.stderr
    assert "absorbing substrate" in lines[0] and "dielectric" in lines[0]
    assert not (tmp_path / "AuE").exists()


@pytest.mark.parametrize("sets, message", [
    (["substrate.ior=Unobtanium"], "unknown material 'Unobtanium'"),
    (["substrate.ior=BK7", "substrate.k=0.1"], "'substrate.k' adds an extinction to a numeric 'substrate.ior' only"),
    (["substrate.ior=1.5+0.2i", "substrate.k=0.1"], "'substrate.k' adds an extinction to a numeric"),
])
def test_a_bad_substrate_is_one_line_with_exit_2(tmp_path, sets, message):
    argv = ["generate", "hemisphere", "--out", tmp_path / "o", "--resolution", 8]
    for item in sets:
        argv += ["--set", item]
    proc = _cli(*argv)
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode == 2 and len(lines) == 1, proc.stderr
    assert lines[0].startswith("thinfilm: error: ") and message in lines[0] and "'substrate.ior'" in lines[0]
    assert not (tmp_path / "o").exists()
