"""Dataset and output-folder I/O: validation messages, safe replacement of output folders."""

import json

import numpy as np
import pytest

from thinfilm.dataset import (FORMAT, atomic_output_dir, band_channel, pol_layer, read_dataset,
                              write_exr, write_json)
from thinfilm.errors import UserError
from thinfilm.reconstruction.estimate import normals_to_angles


def _tiny_dataset(root, wavelengths=(500.0, 510.0, 520.0), angles=(0, 45, 90, 135)):
    root.mkdir(parents=True)
    write_json(root / "meta.json", {"format": FORMAT, "wavelengths_nm": list(wavelengths),
                                    "polarizer_angles_deg": list(angles)})
    img = np.full((4, 5), 0.25, np.float32)
    write_exr(root / "polarized_rgb.exr",
              {f"{pol_layer(a)}.{c}": img for a in angles for c in "RGB"})
    write_exr(root / "spectral_s.exr", {band_channel(i): img for i in range(len(wavelengths))})
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
    with pytest.raises(UserError, match="--out .*file/x: cannot create the folder"):
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
