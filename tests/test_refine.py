"""Refinement by analysis by synthesis (``thinfilm refine``, ``reconstruct … --refine``):
without priors it is the per-pixel maximum-likelihood fit and reaches the Cramér-Rao bound;
with them it improves on its start and its σ is calibrated; the command is careful."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from thinfilm.cli import main


@pytest.fixture(scope="module")
def hemisphere(tmp_path_factory):
    """The hemisphere preset (a uniform film, camera noise) at 40 px, the defaults' estimates."""
    root = tmp_path_factory.mktemp("refine")
    ds = root / "ds"
    assert main(["generate", "hemisphere", "--out", str(ds), "--resolution", "40"]) == 0
    for kind in ("rgb", "spectral"):
        assert main(["reconstruct", kind, str(ds), "--out", str(root / kind)]) == 0
    return root


def _errors(ds, est):
    from thinfilm.core.io import read_dataset
    from thinfilm.evaluation import geometry_error_maps

    gt = read_dataset(ds, need=("ground_truth",), optional=()).ground_truth
    maps = geometry_error_maps(gt, est)
    zen = np.degrees(np.arccos(np.clip(gt["normal"][..., 2], -1.0, 1.0)))
    sel = gt["mask"] & est.valid & (zen >= 15.0) & (zen <= 75.0)
    return gt, maps, sel


def _rms(x):
    return float(np.sqrt(np.mean(np.asarray(x) ** 2)))


@pytest.mark.slow
@pytest.mark.parametrize("kind", ["rgb", "spectral"])
def test_without_priors_the_refined_errors_are_the_bound(hemisphere, kind):
    """``--prior none`` fits every pixel on its own in the noise model's likelihood: its RMS
    errors (true zenith 15-75°) are 0.8-1.3 times the per-pixel Cramér-Rao bound
    (:func:`thinfilm.core.bound.pixel_bound`, computed from the ground truth), and for the
    spectral capture the film index is found again."""
    from thinfilm.core.bound import pixel_bound
    from thinfilm.core.io import read_dataset, read_estimate
    from thinfilm.core.model import Rig
    from thinfilm.refine import refine

    ds = hemisphere / "ds"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        est = refine(ds, read_estimate(hemisphere / kind), prior="none")
    assert est.info["refine"]["capture"] == ("polarized_rgb" if kind == "rgb" else "stokes")
    gt, maps, sel = _errors(ds, est)
    dataset = read_dataset(ds, need=(), optional=())
    obj = gt["mask"]  # all of the object's pixels: the auto exposure looks at the brightest
    b = pixel_bound(Rig.of_dataset(dataset), dataset.film(), gt["normal"][obj], gt["thickness"][obj],
                    dataset.meta["noise"], est.info["refine"]["capture"])
    crlb_n, crlb_d = np.full(obj.shape, np.nan), np.full(obj.shape, np.nan)
    crlb_n[obj], crlb_d[obj] = b["normal_deg"], b["thickness_nm"][:, 0]
    ratio_n = _rms(maps["normal_error_deg"][sel]) / _rms(crlb_n[sel])
    ratio_d = _rms(maps["thickness_error_nm"][sel]) / _rms(crlb_d[sel])
    assert 0.8 <= ratio_n <= 1.3, ratio_n
    assert 0.8 <= ratio_d <= 1.3, ratio_d
    if kind == "spectral":
        assert abs(est.film_ior - 1.37) < 2e-3


@pytest.mark.slow
def test_the_default_refinement_improves_its_start_and_its_sigma_is_calibrated(hemisphere):
    """With the priors (a curl-free gradient field, smooth thickness) the RGB default's errors
    fall, and the true error lies within 2 σ for 88-99.5 % of the pixels for the normals, and
    for at least 88 % for the thickness: this film is uniform, smoother than the prior says a
    film is, so its thickness errors fall further inside the posterior's σ (measured: 99.7 %;
    the standard suite's pooled figures are those of ``benchmarks/standard_suite.py --refine``)."""
    from thinfilm.core.io import read_estimate
    from thinfilm.refine import refine

    ds = hemisphere / "ds"
    start = read_estimate(hemisphere / "rgb")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        est = refine(ds, start)
    _, m0, s0 = _errors(ds, start)
    gt, m1, s1 = _errors(ds, est)
    assert _rms(m1["normal_error_deg"][s1]) < _rms(m0["normal_error_deg"][s0])
    assert _rms(m1["thickness_error_nm"][s1]) < 0.7 * _rms(m0["thickness_error_nm"][s0])
    sel = gt["mask"] & est.valid
    assert sel.sum() >= 0.95 * (gt["mask"] & start.valid).sum()
    within_n = np.mean(m1["normal_error_deg"][sel] <= 2 * est.normal_sigma_deg[sel])
    within_d = np.mean(m1["thickness_error_nm"][sel] <= 2 * est.thickness_sigma_nm[sel])
    assert 0.88 <= within_n <= 0.995, within_n
    assert 0.88 <= within_d, within_d


def test_the_refine_command_writes_a_new_estimate_and_leaves_its_inputs(hemisphere, tmp_path, capsys):
    """``thinfilm refine`` writes an estimate folder with the σ channels and ``method``
    ``coherent+refine``; its inputs are byte-identical afterwards; an estimate of another size
    is one line and exit 2."""
    from thinfilm.core.io import read_estimate

    ds = hemisphere / "ds"
    before = {p: p.read_bytes() for p in sorted((hemisphere / "rgb").iterdir())}
    out = tmp_path / "r"
    assert main(["refine", str(ds), str(hemisphere / "rgb"), "--out", str(out), "--iterations", "2"]) == 0
    est = read_estimate(out)
    assert est.info["method"] == "coherent+refine" and est.info["refine"]["iterations"] >= 1
    assert est.normal_sigma_deg is not None and np.isfinite(est.thickness_sigma_nm[est.valid]).all()
    assert {p: p.read_bytes() for p in sorted((hemisphere / "rgb").iterdir())} == before
    small = tmp_path / "small"
    assert main(["generate", "hemisphere", "--out", str(small), "--resolution", "16"]) == 0
    capsys.readouterr()
    assert main(["refine", str(small), str(hemisphere / "rgb"), "--out", str(tmp_path / "x")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "40x40" in err[0] and "16x16" in err[0]
    assert not (tmp_path / "x").exists()


def test_refine_says_so_when_the_model_explains_nothing(hemisphere, tmp_path, capsys):
    """An estimate refined on the captures of another film (here the hemisphere's captures
    scaled tenfold, which no film reflects) ends with one line and exit 1, nothing written."""
    import shutil

    from thinfilm.core.io import read_exr, write_exr

    ds = tmp_path / "ds"
    shutil.copytree(hemisphere / "ds", ds)
    ch = read_exr(ds / "polarized_rgb.exr")
    write_exr(ds / "polarized_rgb.exr", {k: v * 10.0 for k, v in ch.items()})
    capsys.readouterr()
    assert main(["refine", str(ds), str(hemisphere / "rgb"), "--out", str(tmp_path / "r"), "--iterations", "2"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "explains none" in err[0]
    assert not (tmp_path / "r").exists()
