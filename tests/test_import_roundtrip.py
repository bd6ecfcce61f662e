"""Generate raw sensor data, import it, reconstruct: against the direct path and ground truth.

The generator's ``rig.sensor = "dofp-rgb"`` writes ``raw.tiff`` beside the per-angle captures
(the direct path). ``thinfilm import polarization raw.tiff --layout dofp-rgb`` must give images
that reconstruct within 1.5 degrees and 5 nm of the direct reconstruction; so must a mosaic built
from a dataset's own images.
"""

import json
import warnings

import numpy as np
import pytest

from _import_helpers import IMX250MYR, build_mosaic, write_png
from thinfilm.cli import main
from thinfilm.core.errors import ThinfilmWarning
from thinfilm.core.io import read_dataset


@pytest.fixture(scope="module", autouse=True)
def mono_polarized(render_variant_module):
    return render_variant_module


def _generate(tmp_path_factory, name, resolution, extra=(), seed=0):
    from thinfilm.generators.generate import generate_dataset
    from thinfilm.generators.spec import load_spec

    spec = load_spec("hemisphere", overrides=list(extra), resolution=resolution, seed=seed)
    out = tmp_path_factory.mktemp("gen") / name
    generate_dataset(spec, out, progress=False)
    return out


@pytest.fixture(scope="module")
def raw_dataset(tmp_path_factory):
    """A 128 x 128 hemisphere with camera noise and raw sensor data."""
    return _generate(tmp_path_factory, "hemi", 128, ["rig.sensor=dofp-rgb"])


@pytest.fixture(scope="module")
def direct(raw_dataset):
    from thinfilm.reconstruct import reconstruct

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ThinfilmWarning)
        return reconstruct("rgb", raw_dataset)[0]


def _cli(*argv):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ThinfilmWarning)
        assert main([str(a) for a in argv]) == 0


def _import_raw(ds_path, out):
    sensor = json.loads((ds_path / "meta.json").read_text())["sensor"]
    _cli("import", "polarization", ds_path / sensor["file"], "--layout", "dofp-rgb", "--pattern", sensor["pattern"],
         "--bit-depth", sensor["bits"], "--white-balance", ",".join(repr(g) for g in sensor["white_balance"]),
         "--camera", "Nikon 5100 (NPL)", "--illuminant", "D65", "--film-ior", "1.37", "--substrate-ior", "1.6",
         "--out", out)
    return out


def _compare(direct, through, gt):
    with np.errstate(invalid="ignore", divide="ignore"):    # NaN normals off the valid pixels
        return _compare_(direct, through, gt)


def _compare_(direct, through, gt):
    from thinfilm.evaluation import angular_error_deg

    out = {}
    for name, est in (("direct", direct), ("mosaic", through)):
        v = est.valid & gt["mask"]
        out[name] = (float(angular_error_deg(est.normals, gt["normal"])[v].mean()),
                     float(np.abs(est.thickness_nm - gt["thickness"])[v].mean()), int(v.sum()))
    both = direct.valid & through.valid
    out["between"] = (float(angular_error_deg(direct.normals, through.normals)[both].mean()),
                      float(np.abs(direct.thickness_nm - through.thickness_nm)[both].mean()))
    return out


def test_raw_sensor_round_trip_within_1_5_deg_and_5_nm_of_direct(raw_dataset, direct, tmp_path):
    from thinfilm.reconstruct import reconstruct

    gt = read_dataset(raw_dataset, need=("ground_truth",)).ground_truth
    imported = _import_raw(raw_dataset, tmp_path / "imp")
    ds = read_dataset(imported)
    assert ds.meta["source"] == "imported" and ds.valid is not None
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ThinfilmWarning)
        through = reconstruct("rgb", imported)[0]
    r = _compare(direct, through, gt)
    assert r["mosaic"][0] <= r["direct"][0] + 1.5, r
    assert r["mosaic"][1] <= r["direct"][1] + 5.0, r
    assert r["between"][0] <= 1.5 and r["between"][1] <= 5.0, r
    assert r["mosaic"][2] >= 0.7 * r["direct"][2], r        # the silhouette band aside, all of it


def test_dataset_images_through_a_colour_mosaic(raw_dataset, direct, tmp_path):
    """The check of the issue: a mosaic built from a dataset's own images (16-bit PNG)."""
    from thinfilm.reconstruct import reconstruct

    src = read_dataset(raw_dataset, need=("ground_truth", "polarized_rgb"))
    mosaic = build_mosaic(src.polarized_rgb)
    scale = float(mosaic.max())
    codes = np.rint(np.clip(mosaic, 0, None) / scale * 65535).astype(np.uint16)
    write_png(tmp_path / "mosaic.png", codes)
    _cli("import", "polarization", tmp_path / "mosaic.png", "--layout", "dofp-rgb", "--white-balance",
         f"{scale!r},{scale!r},{scale!r}", "--film-ior", "1.37", "--substrate-ior", "1.6", "--out", tmp_path / "imp")
    imp = read_dataset(tmp_path / "imp")
    # every sampled pixel matches its source to the 16-bit quantization
    h, w = codes.shape
    for r in range(h):
        for c in range(w):
            cell = IMX250MYR[r % 4][c % 4]
            a, ch = int(cell[1:]), "RGB".index(cell[0])
            assert abs(imp.polarized_rgb[a][r, c, ch] - src.polarized_rgb[a][r, c, ch]) <= 0.51 * scale / 65535 + 1e-7
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ThinfilmWarning)
        through = reconstruct("rgb", tmp_path / "imp")[0]
    r = _compare(direct, through, src.ground_truth)
    assert r["between"][0] <= 1.5 and r["between"][1] <= 5.0, r
    assert r["mosaic"][0] <= r["direct"][0] + 1.5 and r["mosaic"][1] <= r["direct"][1] + 5.0, r


def test_noise_free_mosaic_images_match_their_source(tmp_path_factory, tmp_path):
    """Without noise, the demosaiced images match the source to 1 % (median over the valid
    object pixels), and the raw file's white balance brings every sample back to the exact
    camera RGB to the 12-bit quantization."""
    ds_path = _generate(tmp_path_factory, "clean", 64, ["rig.sensor=dofp-rgb", "noise.model=none"])
    src = read_dataset(ds_path, need=("ground_truth", "polarized_rgb"))
    imp = read_dataset(_import_raw(ds_path, tmp_path / "imp"))
    sensor = src.meta["sensor"]
    step = np.asarray(sensor["white_balance"]) / (2 ** sensor["bits"] - 1)
    got, want = build_mosaic(imp.polarized_rgb), build_mosaic(src.polarized_rgb)
    colour = np.array([["RGB".index(IMX250MYR[r % 4][c % 4][0]) for c in range(64)] for r in range(64)])
    assert np.all(np.abs(got - want) <= 0.5 * step[colour] + 1e-6)
    sel = src.ground_truth["mask"] & imp.valid
    with np.errstate(divide="ignore", invalid="ignore"):   # a sample may be exactly 0 (extinction)
        rel = np.concatenate([np.abs(imp.polarized_rgb[a] - src.polarized_rgb[a])[sel] / src.polarized_rgb[a][sel]
                              for a in src.polarized_rgb])
    assert np.median(rel) < 0.01


def test_raw_sensor_is_deterministic_and_leaves_the_other_captures_unchanged(tmp_path_factory):
    a = _generate(tmp_path_factory, "a", 24, ["rig.sensor=dofp-rgb"], seed=5)
    b = _generate(tmp_path_factory, "b", 24, ["rig.sensor=dofp-rgb"], seed=5)
    ideal = _generate(tmp_path_factory, "i", 24, [], seed=5)
    assert (a / "raw.tiff").read_bytes() == (b / "raw.tiff").read_bytes()
    assert not (ideal / "raw.tiff").exists()
    for name in ("polarized_rgb.exr", "spectral_s.exr", "stokes_spectral.exr", "ground_truth.exr"):
        assert (a / name).read_bytes() == (ideal / name).read_bytes(), name
    import tifffile

    raw = tifffile.imread(a / "raw.tiff")
    meta = json.loads((a / "meta.json").read_text())
    assert raw.dtype == np.uint16 and raw.shape == (24, 24) and raw.max() <= 2 ** meta["sensor"]["bits"] - 1
    assert meta["sensor"]["pattern"] == "RGGB:90,45,135,0" and 'sensor = "dofp-rgb"' in (a / "scene.toml").read_text()


def test_raw_sensor_needs_at_most_16_bits():
    from thinfilm.core.errors import UserError
    from thinfilm.generators.spec import load_spec

    with pytest.raises(UserError, match="noise.bits"):
        load_spec("hemisphere", overrides=["rig.sensor=dofp-rgb", "noise.bits=20"])
    with pytest.raises(UserError, match="rig.sensor"):
        load_spec("hemisphere", overrides=["rig.sensor=bayer"])
