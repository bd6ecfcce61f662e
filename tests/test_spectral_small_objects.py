"""Spectral reconstruction of small objects: a stage left with no pixel to fit (all of a small
object's pixels are seeds of the Stokes method) runs on zero pixels instead of failing, and a
method that ends with no usable pixel, or no pixel to estimate the film index from, says so."""

import numpy as np
import pytest

from thinfilm.cli import main
from thinfilm.core.errors import UserError
from thinfilm.reconstruction import spectral_fit, spectral_stokes

WL = np.arange(400.0, 721.0, 8.0)


def _hemisphere(tmp_path_factory, name, film_ior, substrate_ior, resolution=16):
    from thinfilm.generators import generate as gen
    from thinfilm.generators.spec import load_spec

    out = tmp_path_factory.mktemp("small") / name
    spec = load_spec("hemisphere", overrides=[f"film.ior={film_ior}", f"substrate.ior={substrate_ior}"],
                     resolution=resolution)
    gen.generate_dataset(spec, out, progress=False)
    return out


@pytest.fixture(scope="module")
def high_index(tmp_path_factory, render_variant_module):
    # 16 px: 164 object pixels, fewer than 50 on the seed grid, so every pixel is a seed and
    # the fit of the other pixels has none
    return _hemisphere(tmp_path_factory, "high", 2.164, 2.4)


@pytest.fixture(scope="module")
def dispersive(tmp_path_factory, render_variant_module):
    return _hemisphere(tmp_path_factory, "tio2", "TiO2", 1.6)


def test_a_small_object_whose_pixels_are_all_seeds_is_reconstructed(high_index, tmp_path, capsys):
    from thinfilm.core.io import read_dataset, read_estimate

    out = tmp_path / "est"
    assert main(["reconstruct", "spectral", str(high_index), "--out", str(out)]) == 0
    assert capsys.readouterr().out.startswith(f"wrote {out} (method auto")
    est = read_estimate(out)
    m = read_dataset(high_index, need=("ground_truth",)).ground_truth["mask"]
    # measured: n2 2.1644, every object pixel valid
    assert abs(est.film_ior - 2.164) <= 0.01
    assert (est.valid & m).sum() >= 0.9 * m.sum()


def test_a_film_the_model_explains_nowhere_is_reported_not_estimated(dispersive, tmp_path, capsys):
    # TiO2's index varies over the bands; the Stokes method's one constant index fits none of
    # the 16 px hemisphere's pixels: one line, exit 1, nothing written
    out = tmp_path / "est"
    assert main(["reconstruct", "spectral", str(dispersive), "--out", str(out)]) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "found no pixel it could reconstruct" in err
    assert "explains none of the" in err and "nothing was written" in err
    assert not out.exists()


def test_a_film_the_model_explains_at_few_pixels_is_warned_of(tmp_path_factory, render_variant_module, tmp_path,
                                                              capsys):
    # at 32 px a few pixels fit: the estimate is written, with one warning line
    data = _hemisphere(tmp_path_factory, "tio2_32", "TiO2", 1.6, resolution=32)
    out = tmp_path / "est"
    assert main(["reconstruct", "spectral", str(data), "--out", str(out)]) == 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("thinfilm: warning: stokes_spectral: one film of a constant index")
    assert "explains only" in err[0]


def test_stages_on_zero_pixels_return_empty_fits():
    empty = np.zeros((0, WL.size))
    fit = spectral_stokes.fit_stokes_pixels(empty, empty, empty, np.zeros((0, 3)), 1.4, 1.6, WL)
    assert fit.x.shape == (0, 3) and fit.H.shape == (0, 3, 3) and fit.cost.shape == (0,)
    th, d, cur = spectral_fit.angle_thickness_lm(empty, np.zeros(0), np.zeros(0), 1.4, 1.6, WL)
    assert th.shape == d.shape == (0,) and cur.shape == (0, 6)


def test_the_film_index_from_no_pixel_is_refused():
    with pytest.raises(UserError, match="cannot be estimated"):
        spectral_fit.joint_film_ior(np.zeros((0, WL.size)), np.zeros(0), np.zeros(0), 1.4, 1.6, WL)
