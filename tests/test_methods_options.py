"""Method options, the one thickness range and empty estimates, through the command line.

The 1500 nm film is outside what version 0.2 could reconstruct (its spectral methods stopped at
1000 nm); it is scored at the bars of ``benchmarks/sweep_random_scenes.py`` against the
generator's ground truth (not the estimator's model)."""

from __future__ import annotations

import inspect
import json

import numpy as np
import pytest

from thinfilm.cli import main
from thinfilm.core import registry
from thinfilm.core.io import Estimate


@pytest.fixture(scope="module")
def thick_film(tmp_path_factory):
    out = tmp_path_factory.mktemp("thick") / "h1500"
    assert main(["generate", "hemisphere", "--out", str(out), "--resolution", "64", "--seed", "0",
                 "--set", "film.thickness.value=1500"]) == 0
    return out


def _scores(dataset, out):
    from thinfilm.core.io import read_dataset, read_estimate
    from thinfilm.evaluation import geometry_error_maps

    est = read_estimate(out)
    gt = read_dataset(dataset, need=("ground_truth",), optional=()).ground_truth
    maps = geometry_error_maps(gt, est)
    sel = gt["mask"] & est.valid
    return est, {"coverage": sel.sum() / gt["mask"].sum(),
                 "normal_mean": np.nanmean(maps["normal_error_deg"][sel]),
                 "normal_p95": np.nanpercentile(maps["normal_error_deg"][sel], 95),
                 "thickness_mean": np.nanmean(maps["thickness_error_nm"][sel])}


def test_a_1500_nm_film_passes_the_spectral_bars_with_no_hints(thick_film, tmp_path, recwarn):
    out = tmp_path / "est"
    assert main(["reconstruct", "spectral", str(thick_film), "--out", str(out)]) == 0
    est, s = _scores(thick_film, out)
    # measured (64 px, seed 0): coverage 1.0, normal 0.2 deg, thickness ~2 nm, index error 0.001
    assert s["coverage"] >= 0.90 and s["normal_mean"] <= 3.0 and s["normal_p95"] <= 8.0
    assert s["thickness_mean"] <= 8.0
    assert abs(est.film_ior - 1.37) <= 0.015
    assert est.info["thickness_range_nm"][1] >= 1500.0


def test_a_weak_fringe_film_is_not_taken_for_its_mirrored_index(tmp_path):
    """SiO2 (1.46) on 1.536 gives near normal incidence the spectra of a film of 1.536 / 1.46 =
    1.05 about 1.4 times thicker; with the 20-5000 nm default both lie in range, and only the
    oblique pixels tell them apart. Before the mirrored index got its own order search the
    default took the mirror here (index 1.039, 66 valid pixels): scene 1 of the random sweep
    of seed 7, here at 48 px."""
    ds = tmp_path / "pyramid"
    assert main(["generate", "pyramid", "--out", str(ds), "--resolution", "48", "--seed", "955794088",
                 "--set", "shape.height=0.905", "--set", "film.ior=SiO2", "--set", "substrate.ior=1.536",
                 "--set", "film.thickness.profile=linear", "--set", "film.thickness.start=757.8",
                 "--set", "film.thickness.end=660.5", "--set", "film.thickness.axis=y",
                 "--set", "rig.camera=Sigma SDMerill (NPL)", "--set", "rig.illuminant=D50",
                 "--set", "noise.bits=10"]) == 0
    out = tmp_path / "est"
    assert main(["reconstruct", "spectral", str(ds), "--out", str(out)]) == 0
    est, s = _scores(ds, out)
    assert abs(est.film_ior - 1.459911) <= 0.015  # SiO2 at 550 nm (the shipped table)
    assert s["coverage"] >= 0.90 and s["thickness_mean"] <= 8.0 and s["normal_mean"] <= 3.0


def test_rgb_without_a_range_warns_on_a_1500_nm_film(thick_film, tmp_path, capsys):
    out = tmp_path / "est"
    assert main(["reconstruct", "rgb", str(thick_film), "--out", str(out)]) == 0
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if "outside the default thickness range" in ln]
    assert len(lines) == 1 and "--thickness-range" in lines[0] and "spectral capture" in lines[0]
    # with the range the film is found
    out2 = tmp_path / "est2"
    assert main(["reconstruct", "rgb", str(thick_film), "--out", str(out2), "--thickness-range", "1000", "2000"]) == 0
    assert "outside the default thickness range" not in capsys.readouterr().err
    _, s = _scores(thick_film, out2)
    assert s["thickness_mean"] <= 15.0


def test_a_range_the_bands_cannot_resolve_warns_once(thick_film, tmp_path, capsys):
    out = tmp_path / "est"
    assert main(["reconstruct", "spectral", str(thick_film), "--out", str(out),
                 "--thickness-range", "100", "19000"]) == 0
    err = capsys.readouterr().err
    assert sum("the bands resolve interference fringes" in ln for ln in err.splitlines()) == 1


@registry.estimator("empty-test", kind="rgb", needs=("polarized_rgb",))
def empty_method(dataset, options):
    """A method that resolves nothing (for the test below)."""
    shape = dataset.shape
    return Estimate(np.zeros(shape + (3,)), np.zeros(shape), np.zeros(shape, dtype=bool), 1.37, 1.6)


def test_an_empty_estimate_exits_1_with_one_line(thick_film, tmp_path, capsys):
    out = tmp_path / "est"
    rc = main(["reconstruct", "rgb", str(thick_film), "--out", str(out), "--method",
               "test_methods_options:empty_method"])
    err = capsys.readouterr().err.strip()
    assert rc == 1 and "\n" not in err and err.startswith("thinfilm: error:") and "no pixel" in err
    assert not out.exists()


@pytest.mark.parametrize("item, words", [("nope=1", "has no option 'nope'"), ("rounds", "expected NAME=VALUE"),
                                         ("rounds=x", "expected a whole number"), ("rounds=0", "from 1 to 10")])
def test_bad_options_give_one_line_and_exit_2(thick_film, tmp_path, capsys, item, words):
    out = tmp_path / "est"
    assert main(["reconstruct", "rgb", str(thick_film), "--out", str(out), "--option", item]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and err.startswith("thinfilm: error: --option") and words in err
    assert not out.exists()


def test_every_builtin_method_lists_its_options_with_the_functions_defaults(capsys):
    from thinfilm.reconstruction import rgb_coherent, spectral_eikonal, spectral_stokes

    assert main(["methods", "--json"]) == 0
    listed = {(d["kind"], d["name"]): d for d in map(json.loads, capsys.readouterr().out.splitlines())}
    functions = {("rgb", "coherent"): rgb_coherent.reconstruct_coherent,
                 ("spectral", "stokes"): spectral_stokes.reconstruct_stokes,
                 ("spectral", "eikonal-s"): spectral_eikonal.reconstruct_eikonal}
    for key, fn in functions.items():
        opts = listed[key]["options"]
        assert opts and all(o["help"] and o["type"] in ("int", "float", "bool", "str") for o in opts)
        params = inspect.signature(fn).parameters
        for o in opts:
            assert params[o["name"]].default == o["default"], (key, o["name"])
    auto = {o["name"] for o in listed[("spectral", "auto")]["options"]}
    assert auto == {f"stokes_{o['name']}" for o in listed[("spectral", "stokes")]["options"]} | \
        {f"s_{o['name']}" for o in listed[("spectral", "eikonal-s")]["options"]}


def test_an_option_set_on_the_command_line_reaches_the_method(thick_film, tmp_path, monkeypatch):
    from thinfilm.reconstruction import rgb_coherent, spectral_stokes

    seen = {}
    real_rgb, real_stokes = rgb_coherent.reconstruct_coherent, spectral_stokes.reconstruct_stokes

    def rgb_spy(capture, **kw):
        seen["coherent"] = kw
        return real_rgb(capture, **kw)

    def stokes_spy(*a, **kw):
        seen["stokes"] = kw
        return real_stokes(*a, **kw)

    monkeypatch.setattr(rgb_coherent, "reconstruct_coherent", rgb_spy)
    monkeypatch.setattr(spectral_stokes, "reconstruct_stokes", stokes_spy)
    assert main(["reconstruct", "rgb", str(thick_film), "--out", str(tmp_path / "a"), "--thickness-range",
                 "1000", "2000", "--option", "median_window=7", "--option", "robust_prior=false"]) == 0
    assert seen["coherent"]["median_window"] == 7 and seen["coherent"]["robust_prior"] is False
    assert seen["coherent"]["rounds"] == 1  # the default, filled in
    assert main(["reconstruct", "spectral", str(thick_film), "--out", str(tmp_path / "b"),
                 "--option", "stokes_smoothness=3"]) == 0
    assert seen["stokes"]["smoothness"] == 3.0
    assert json.loads((tmp_path / "b" / "estimate.json").read_text())["smoothness"] == 3.0


def test_library_errors_name_arguments_and_the_cli_names_flags():
    from thinfilm.cli import cli_message
    from thinfilm.core.errors import UserError

    e = UserError("exists and is not a folder", argument="out", value="/x")
    assert str(e) == "out /x: exists and is not a folder"
    assert cli_message(e) == "--out /x: exists and is not a folder"
    assert cli_message(UserError("bad", argument="thickness_range_nm")) == "--thickness-range: bad"
    with pytest.raises(UserError) as info:
        registry.get("spectral", "no-such-method")
    assert info.value.argument == "method" and not str(info.value).startswith("--")
