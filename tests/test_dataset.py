"""Dataset and output-folder I/O: validation messages, safe replacement of output folders."""

import json

import numpy as np
import pytest

from thinfilm.core.conventions import normals_to_angles
from thinfilm.core.errors import UserError
from thinfilm.core.io import (FORMAT, Estimate, band_channel, dataset_meta, read_dataset, read_estimate,
                              write_dataset, write_estimate, write_exr)
from thinfilm.core.outputs import atomic_output_dir


def _tiny_dataset(root, wavelengths=(500.0, 510.0, 520.0), angles=(0, 45, 90, 135)):
    root.mkdir(parents=True)
    img = np.full((4, 5, 3), 0.25, np.float32)
    write_dataset(root, dataset_meta(wavelengths_nm=list(wavelengths), polarizer_angles_deg=list(angles)),
                  polarized_rgb={a: img for a in angles}, spectral_s=np.full((4, 5, len(wavelengths)), 0.25))
    return root


def test_reads_a_valid_dataset(tmp_path):
    ds = read_dataset(_tiny_dataset(tmp_path / "d"), need=("polarized_rgb", "spectral_s"))
    assert sorted(ds.polarized_rgb) == [0, 45, 90, 135]
    assert ds.spectral_s.shape == (4, 5, 3) and ds.shape == (4, 5)


def test_optional_parts_are_not_read(tmp_path):
    root = _tiny_dataset(tmp_path / "d")
    write_exr(root / "spectral_s.exr", {band_channel(0): np.full((4, 5), np.nan, np.float32)})
    ds = read_dataset(root, need=("polarized_rgb",), optional=())
    assert ds.spectral_s is None and len(ds.polarized_rgb) == 4
    with pytest.raises(UserError, match="spectral_s.exr: missing channel 'band001'"):
        read_dataset(root, need=("polarized_rgb",))


def test_nan_names_the_exact_channel(tmp_path):
    root = _tiny_dataset(tmp_path / "d")
    bands = {band_channel(i): np.full((4, 5), 0.1, np.float32) for i in range(3)}
    bands["band001"][2, 3] = np.nan
    write_exr(root / "spectral_s.exr", bands)
    with pytest.raises(UserError, match=r"spectral_s.exr: channel 'band001' contains NaN"):
        read_dataset(root, need=("spectral_s",))


@pytest.mark.parametrize("meta, message", [
    ([], "expected a JSON object, got list"),
    ({"format": FORMAT, "wavelengths_nm": "abc"}, "'wavelengths_nm' must be a list of numbers"),
    ({"format": FORMAT, "wavelengths_nm": [500, 490]}, "'wavelengths_nm' must be increasing"),
    ({"format": "other/2"}, "unknown format 'other/2'"),
])
def test_malformed_meta_is_one_clear_error(tmp_path, meta, message):
    root = _tiny_dataset(tmp_path / "d")
    (root / "meta.json").write_text(json.dumps(meta))
    with pytest.raises(UserError, match=message):
        read_dataset(root)


def test_output_never_replaces_a_folder_of_user_files(tmp_path):
    precious = tmp_path / "precious"
    precious.mkdir()
    (precious / "thesis.tex").write_text("do not delete")
    with pytest.raises(UserError, match="not a thinfilm output; refusing to replace it"):
        with atomic_output_dir(precious) as tmp:
            (tmp / "estimate.json").write_text("{}")
    assert (precious / "thesis.tex").read_text() == "do not delete"
    assert [p.name for p in tmp_path.iterdir()] == ["precious"]  # no temporary folder left


def test_output_replaces_an_earlier_output_only_when_complete(tmp_path):
    out = tmp_path / "est"
    with atomic_output_dir(out) as tmp:
        (tmp / "estimate.json").write_text("1")
    with pytest.raises(RuntimeError):
        with atomic_output_dir(out) as tmp:
            (tmp / "estimate.json").write_text("2")
            raise RuntimeError("interrupted")
    assert (out / "estimate.json").read_text() == "1"
    with atomic_output_dir(out) as tmp:
        (tmp / "estimate.json").write_text("3")
    assert (out / "estimate.json").read_text() == "3"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["est"]


def test_output_path_errors_are_one_line(tmp_path, monkeypatch):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    with pytest.raises(UserError, match="^out .*file/x: cannot create the folder"):
        with atomic_output_dir(blocker / "x"):
            pass
    with pytest.raises(UserError, match="exists and is not a folder"):
        with atomic_output_dir(blocker):
            pass
    # '.' means the current folder, which is replaced like any other output folder.
    work = tmp_path / "work"
    work.mkdir()
    monkeypatch.chdir(work)
    with atomic_output_dir(".") as tmp:
        (tmp / "metrics.json").write_text("{}")
    assert (work / "metrics.json").is_file()


def test_azimuth_stays_below_360_in_float32():
    n = np.array([0.5, -1e-9, 0.8])
    n /= np.linalg.norm(n)
    zenith, azimuth = normals_to_angles(n)
    assert 0.0 <= np.float32(azimuth) < 360.0
    assert abs(zenith - np.degrees(np.arccos(n[2]))) < 1e-12


def test_written_dataset_reads_back(tmp_path):
    root = _tiny_dataset(tmp_path / "d")
    assert (root / "preview.png").is_file()
    ds = read_dataset(root, need=("polarized_rgb", "spectral_s"))
    assert ds.meta["format"] == FORMAT and "versions" in ds.meta
    np.testing.assert_array_equal(ds.polarized_rgb[45], np.full((4, 5, 3), 0.25, np.float32))


def test_estimate_round_trip(tmp_path):
    rng = np.random.default_rng(0)
    n = rng.normal(size=(4, 5, 3))
    n[..., 2] = np.abs(n[..., 2]) + 0.1
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    valid = rng.random((4, 5)) > 0.3
    est = Estimate(n, rng.uniform(100, 900, (4, 5)), valid, "MgF2", 1.6, height=rng.random((4, 5)),
                   info={"method": "m", "timings_s": {"total": 1.0}})
    write_estimate(tmp_path, est)
    back = read_estimate(tmp_path)
    assert back.film_ior == "MgF2" and back.substrate_ior == 1.6 and back.info["method"] == "m"
    np.testing.assert_array_equal(back.valid, valid)
    np.testing.assert_allclose(back.normals[valid], n[valid], atol=1e-7)
    assert np.isnan(back.thickness_nm[~valid]).all()
    assert (tmp_path / "surface.ply").is_file()


def _estimate(seed=1, shape=(6, 7), height=True):
    rng = np.random.default_rng(seed)
    n = rng.normal(size=(*shape, 3))
    n[..., 2] = np.abs(n[..., 2]) + 0.1
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    valid = rng.random(shape) > 0.3
    return Estimate(n, rng.uniform(100, 900, shape), valid, 1.3812, 1.52,
                    height=rng.normal(size=shape) if height else None, pixel_size=0.0125,
                    info={"method": "spectral/eikonal", "timings_s": {"total": 1.5, "read": 0.25},
                          "valid_fraction": 0.7, "notes": ["a", "b"]})


def test_an_estimate_reads_back_whole(tmp_path):
    """Every channel written, the height field and its pixel size, the indices and the
    entries of estimate.json read back (in float32); written and read again, nothing changes."""
    est = _estimate()
    (tmp_path / "a").mkdir()
    write_estimate(tmp_path / "a", est)
    back = read_estimate(tmp_path / "a")
    valid = est.valid
    f32 = np.float32
    np.testing.assert_array_equal(back.valid, valid)
    for got, want in ((back.normals, est.normals), (back.thickness_nm, est.thickness_nm),
                      (back.height, est.height)):
        assert got.dtype == f32 and got.shape == want.shape
        np.testing.assert_array_equal(got[valid], want[valid].astype(f32))
        assert np.isnan(got[~valid]).all()
    assert back.pixel_size == 0.0125 and back.film_ior == 1.3812 and back.substrate_ior == 1.52
    assert back.info == est.info
    # zenith and azimuth in the file are those of the normals
    from thinfilm.core.io import read_exr

    ch = read_exr(tmp_path / "a" / "estimate.exr")
    assert sorted(ch) == sorted(["normal.X", "normal.Y", "normal.Z", "zenith", "azimuth", "thickness", "valid",
                                 "height"])
    zenith, azimuth = normals_to_angles(est.normals)
    np.testing.assert_array_equal(ch["zenith"][valid], zenith[valid].astype(f32))
    np.testing.assert_array_equal(ch["azimuth"][valid], azimuth[valid].astype(f32))
    js = json.loads((tmp_path / "a" / "estimate.json").read_text())
    assert js["format"] == "thinfilm-estimate/1" and js["pixel_size"] == 0.0125
    (tmp_path / "b").mkdir()
    write_estimate(tmp_path / "b", back)
    again = read_estimate(tmp_path / "b")
    for name in ("normals", "thickness_nm", "valid", "height"):
        np.testing.assert_array_equal(getattr(again, name), getattr(back, name))
    assert (again.film_ior, again.substrate_ior, again.pixel_size, again.info) == \
        (back.film_ior, back.substrate_ior, back.pixel_size, back.info)
    assert (tmp_path / "a" / "estimate.json").read_bytes() == (tmp_path / "b" / "estimate.json").read_bytes()


def test_an_estimate_without_height_reads_back_without_one(tmp_path):
    write_estimate(tmp_path, _estimate(height=False))
    back = read_estimate(tmp_path)
    assert back.height is None and back.pixel_size == 0.0125
    assert not (tmp_path / "surface.ply").exists()


def test_an_older_estimate_json_without_format_still_reads(tmp_path):
    write_estimate(tmp_path, _estimate())
    js = json.loads((tmp_path / "estimate.json").read_text())
    del js["format"], js["pixel_size"]
    (tmp_path / "estimate.json").write_text(json.dumps(js))
    back = read_estimate(tmp_path)
    assert back.pixel_size == 1.0 and back.film_ior == 1.3812 and "format" not in back.info


@pytest.mark.parametrize("change, message", [
    ({"format": "thinfilm-estimate/9"}, "unknown format 'thinfilm-estimate/9', expected 'thinfilm-estimate/1'"),
    ({"pixel_size": -1.0}, "field 'pixel_size' must be a positive number, got -1.0"),
    ({"pixel_size": "1"}, "field 'pixel_size' must be a positive number"),
])
def test_a_bad_format_or_pixel_size_is_one_line(tmp_path, change, message):
    write_estimate(tmp_path, _estimate())
    js = json.loads((tmp_path / "estimate.json").read_text())
    js.update(change)
    (tmp_path / "estimate.json").write_text(json.dumps(js))
    with pytest.raises(UserError, match=message):
        read_estimate(tmp_path)


def test_exr_bytes_do_not_depend_on_the_thread_count(tmp_path):
    """OpenEXR compresses ZIP blocks on a thread pool; the file must be the same bytes with
    one thread as with several (the same spec and seed give the same dataset anywhere)."""
    import OpenEXR

    from thinfilm.core.io import read_exr

    rng = np.random.default_rng(3)
    channels = {f"band{b:03d}": rng.random((97, 61)).astype(np.float32) for b in range(5)}
    before = OpenEXR.global_thread_count()
    paths = []
    try:
        for threads in (0, 1, 4):
            OpenEXR.set_global_thread_count(threads)
            paths.append(tmp_path / f"t{threads}.exr")
            write_exr(paths[-1], channels)
    finally:
        OpenEXR.set_global_thread_count(before)
    data = [p.read_bytes() for p in paths]
    assert data[0] == data[1] == data[2]
    back = read_exr(paths[0])
    assert all(np.array_equal(back[k], v) for k, v in channels.items())


def test_an_estimates_uncertainty_channels_read_back(tmp_path):
    """normal_sigma_deg and thickness_sigma_nm are written when the estimate has them, NaN off
    the valid pixels, and read back; one without the other is refused."""
    import dataclasses

    from thinfilm.core.errors import UserError
    from thinfilm.core.io import SIGMA_CHANNELS, read_exr, write_exr

    est = _estimate()
    rng = np.random.default_rng(3)
    est = dataclasses.replace(est, normal_sigma_deg=rng.uniform(0.1, 2.0, est.valid.shape),
                              thickness_sigma_nm=rng.uniform(0.5, 9.0, est.valid.shape))
    write_estimate(tmp_path, est)
    back = read_estimate(tmp_path)
    for name in ("normal_sigma_deg", "thickness_sigma_nm"):
        got, want = getattr(back, name), getattr(est, name)
        np.testing.assert_array_equal(got[est.valid], want[est.valid].astype(np.float32))
        assert np.isnan(got[~est.valid]).all()
    ch = read_exr(tmp_path / "estimate.exr")
    assert set(SIGMA_CHANNELS) <= set(ch)
    del ch["thickness_sigma_nm"]
    write_exr(tmp_path / "estimate.exr", ch)
    with pytest.raises(UserError, match="normal_sigma_deg.*thickness_sigma_nm"):
        read_estimate(tmp_path)
    with pytest.raises(ValueError, match="both"):
        write_estimate(tmp_path, dataclasses.replace(est, thickness_sigma_nm=None))
    # an estimate without them reads back without them
    write_estimate(tmp_path, _estimate())
    assert read_estimate(tmp_path).normal_sigma_deg is None
