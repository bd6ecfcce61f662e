"""The command line: version, render, and one-line errors with exit code 2."""

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from thinfilm import __version__
from thinfilm.cli import main

ROOT = Path(__file__).resolve().parents[1]


def test_version(capsys):
    with pytest.raises(SystemExit) as e:
        main(["--version"])
    assert e.value.code == 0
    assert __version__ in capsys.readouterr().out


def test_help_is_instant_and_imports_no_renderer():
    code = ("import sys, thinfilm.cli as c\n"
            "try:\n    c.main(['--help'])\nexcept SystemExit:\n    pass\n"
            "assert 'mitsuba' not in sys.modules and 'matplotlib' not in sys.modules, sorted(sys.modules)\n")
    subprocess.run([sys.executable, "-c", code], check=True, capture_output=True)


def _small_scene(tmp_path, thickness=300.0):
    scene = tmp_path / "scene.toml"
    scene.write_text(f"""
type = "scene"
[integrator]
type = "stokes"
nested = {{ type = "path", max_depth = 2, hide_emitters = true }}
[sensor]
type = "orthographic"
to_world = {{ look_at = {{ origin = [0, 0, 5], target = [0, 0, 0], up = [0, 1, 0] }} }}
film = {{ type = "hdrfilm", width = 16, height = 16, rfilter = {{ type = "box" }} }}
sampler = {{ type = "stratified", sample_count = 1, jitter = false }}
[emitter]
type = "constant"
[ball]
type = "sphere"
bsdf = {{ type = "thinfilm", thickness = {thickness}, film_ior = 1.37, substrate_ior = 1.6, wavelength = 550.0 }}
""")
    return scene


def test_render_toml_scene_writes_exr_and_png(tmp_path, capsys):
    import OpenEXR
    import tmm

    rc = main(["render", str(_small_scene(tmp_path)), "--out", str(tmp_path / "img"),
               "--variant", "llvm_ad_mono_polarized"])
    assert rc == 0
    assert (tmp_path / "img.png").stat().st_size > 0
    with OpenEXR.File(str(tmp_path / "img.exr"), separate_channels=True) as f:
        ch = {k: v.pixels for k, v in f.channels().items()}
    assert {"S0.R", "S1.R", "S2.R", "S3.R"} <= set(ch)
    # The centre pixel sees the sphere head on: S0 = (Rs + Rp)/2 at normal incidence.
    R = tmm.coh_tmm("s", [1, 1.37, 1.6], [np.inf, 300.0, np.inf], 0.0, 550.0)["R"]
    centre = ch["S0.R"][7:9, 7:9]
    assert np.all(np.abs(centre - R) < 2e-3)  # pixel centres are 1/16 of the radius off axis


def test_render_xml_example(tmp_path):
    rc = main(["render", str(ROOT / "examples" / "hemisphere_dome.xml"), "--out", str(tmp_path / "h"),
               "--spp", "1", "--variant", "llvm_ad_spectral_polarized"])
    assert rc == 0 and (tmp_path / "h.exr").is_file() and (tmp_path / "h.png").is_file()


@pytest.mark.parametrize("argv, message", [
    (["render", "missing.xml", "--out", "x"], "missing.xml: scene file not found"),
    (["render", "{scene}", "--out", "x", "--variant", "nope"], "unknown Mitsuba variant 'nope'"),
    (["render", "{scene}", "--out", "x", "--exposure", "-2"], "--exposure: expected 'auto' or a positive number"),
    (["render", "{bad}", "--out", "x", "--variant", "llvm_ad_mono_polarized"], "'thickness' must be a finite number from 0 to 100000 nm, got -1.0"),
])
def test_bad_input_one_line_exit_2(tmp_path, capsys, argv, message):
    scene = _small_scene(tmp_path)
    (tmp_path / "bad").mkdir()
    bad = _small_scene(tmp_path / "bad", thickness=-1.0)
    argv = [a.format(scene=scene, bad=bad) for a in argv]
    argv[argv.index("--out") + 1] = str(tmp_path / "out" / "x")
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and len(err.splitlines()) == 1
    assert not (tmp_path / "out" / "x.exr").exists()


@pytest.mark.parametrize("argv", [
    ["generate", "hemisphere", "--out", "x", "--resolution", "0"],
    ["generate", "hemisphere", "--out", "x", "--seed", "abc"],
    ["reconstruct", "rgb", "data", "--out", "x", "--film-ior", "abc"],
    ["reconstruct", "spectral"],
    ["frobnicate"],
])
def test_usage_errors_are_one_line_exit_2(capsys, argv):
    with pytest.raises(SystemExit) as e:
        main(argv)
    assert e.value.code == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "error:" in err


# --- refractive indices of the reconstruct commands ----------------------------------------------

@pytest.fixture(scope="module")
def small_hemisphere(tmp_path_factory, render_variant_module):
    from thinfilm.generators import generate as gen
    from thinfilm.generators.spec import load_spec

    out = tmp_path_factory.mktemp("cli_index") / "hemi"
    gen.generate_dataset(load_spec("hemisphere", resolution=16), out, progress=False)
    return out


@pytest.mark.parametrize("kind,argv,film,substrate", [
    # a shipped table and 'n+ki' text (the dataset's film 1.37 on 1.6)
    ("rgb", ["--film-ior", "MgF2", "--substrate-ior", "1.6+0i"], "MgF2", 1.6),
    ("rgb", ["--film-ior", "1.37+0i", "--substrate-ior", "1.6"], 1.37, 1.6),
    # a refractiveindex.info book (its default page)
    ("spectral", ["--substrate-ior", "Al2O3"], None, "Al2O3"),
], ids=["rgb_table_and_complex", "rgb_complex_film", "spectral_database"])
def test_reconstruct_takes_material_names_and_complex_indices(small_hemisphere, tmp_path, capsys, kind, argv,
                                                             film, substrate):
    from thinfilm.core.film import Film
    from thinfilm.core.io import read_estimate

    out = tmp_path / "est"
    assert main(["reconstruct", kind, str(small_hemisphere), "--out", str(out)] + argv) == 0
    assert capsys.readouterr().out.startswith(f"wrote {out}")
    est = read_estimate(out)
    # the indices the estimate records (a material by its name) are those given
    expected = Film.single(1.0 if film is None else film, None, substrate)
    got = Film.single(est.film_ior, None, est.substrate_ior)
    assert got.effective_substrate_index() == pytest.approx(expected.effective_substrate_index(), abs=1e-9)
    if film is not None:
        assert got.effective_index() == pytest.approx(expected.effective_index(), abs=1e-9)


@pytest.mark.parametrize("argv,message", [
    (["rgb", "--film-ior", "MgF3"], "argument --film-ior: unknown material 'MgF3' (closest: MgF2"),
    (["rgb", "--substrate-ior", "BK8"], "argument --substrate-ior: unknown material 'BK8' (closest:"),
    (["spectral", "--substrate-ior", "TiO2x"], "argument --substrate-ior: unknown material 'TiO2x' (closest: TiO2"),
    (["spectral", "--substrate-ior", "1.6+200i"], "argument --substrate-ior: expected an index n from 0.01 to 100"),
    (["rgb", "--film-ior", "200"], "argument --film-ior: expected a refractive index from 0.01 to 100"),
    (["rgb", "--film-ior", "nan"], "argument --film-ior: expected a refractive index from 0.01 to 100"),
], ids=["film_table", "substrate_table", "database_book", "complex_range", "number_range", "nan"])
def test_reconstruct_refuses_an_unknown_index_in_one_line(tmp_path, capsys, argv, message):
    kind, rest = argv[0], argv[1:]
    with pytest.raises(SystemExit) as e:
        main(["reconstruct", kind, str(tmp_path / "data"), "--out", str(tmp_path / "est")] + rest)
    assert e.value.code == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith(f"thinfilm reconstruct {kind}: error: {message}")
    assert not (tmp_path / "est").exists()
