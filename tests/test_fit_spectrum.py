"""``thinfilm fit-spectrum`` and :mod:`thinfilm.reconstruction.spectrum_fit`.

Synthetic measurements are built from ``tmm`` (an independent transfer-matrix code, not the
project's optics core) times a random smooth instrument response, plus a background and noise.
"""

import json
import os

import numpy as np
import pytest
import tmm

from thinfilm.bsdf.materials import Cauchy
from thinfilm.cli import main
from thinfilm.core.errors import UserError
from thinfilm.fit_spectrum import parse_index, read_spectrum
from thinfilm.reconstruction.spectrum_fit import FilmModel, fit_spectra

LAM = np.linspace(400.0, 850.0, 600)


def _tmm_reflectance(lam, d, n_film, n3, k3=0.0, angle_deg=0.0):
    """Unpolarized (R_s + R_p)/2 of a film in air from tmm, one wavelength at a time."""
    th = np.radians(angle_deg)
    out = np.empty(len(lam))
    for i, wl in enumerate(lam):
        n2 = n_film(wl) if callable(n_film) else n_film
        stack, ds = [1.0, n2, n3 + 1j * k3], [np.inf, d, np.inf]
        out[i] = 0.5 * (tmm.coh_tmm("s", stack, ds, th, wl)["R"] + tmm.coh_tmm("p", stack, ds, th, wl)["R"])
    return out


def _instrument(lam, R, rng, noise=0.005):
    """Raw counts: background + smooth random response × R + Gaussian noise; also the
    background and white-reference readings of the same instrument (with their own noise)."""
    t = (lam - lam.mean()) / (0.5 * np.ptp(lam))
    response = 1000.0 * np.exp(rng.uniform(-0.5, 0.5) * t + rng.uniform(-0.4, 0.4) * t * t)
    background = 20.0 + rng.uniform(-5.0, 5.0) * t
    sigma = noise * np.mean(response * R)
    raw = background + response * R + rng.normal(0.0, sigma, lam.size)
    dark = background + rng.normal(0.0, sigma, lam.size)
    white = background + 0.95 * response + rng.normal(0.0, sigma, lam.size)
    return raw, dark, white


def _check(fits, truth, rel=0.01):
    for f, d in zip(fits, truth):
        assert abs(f.thickness_nm - d) <= rel * d, (d, f.thickness_nm, f.thickness_sigma_nm)
        assert abs(f.thickness_nm - d) <= 3.0 * f.thickness_sigma_nm, (d, f.thickness_nm, f.thickness_sigma_nm)


FILMS = [  # name, film index, substrate n, k, angle
    ("soap film in air", 1.33, 1.0, 0.0, 0.0),
    ("oxide on silicon", 1.46, 3.9, 0.02, 0.0),
    ("high index on glass, 30 deg", 2.0, 1.52, 0.0, 30.0),
]


@pytest.mark.parametrize("name, n2, n3, k3, angle", FILMS)
def test_thick_films_from_raw_counts(name, n2, n3, k3, angle):
    """Films with several fringes need neither a background nor a reference."""
    rng = np.random.default_rng(7)
    truth = [800.0, 1500.0, 3000.0, 5000.0]
    raw = np.stack([_instrument(LAM, _tmm_reflectance(LAM, d, n2, n3, k3, angle), rng)[0] for d in truth])
    fits = fit_spectra(LAM, raw, FilmModel(n2, n3, k3, angle))
    _check(fits, truth)


@pytest.mark.parametrize("name, n2, n3, k3, angle", FILMS)
def test_thin_films_with_background_and_reference(name, n2, n3, k3, angle):
    """50-300 nm (no full fringe below ~150 nm): the background and white reference pin the
    response, and the broad shape of R gives the thickness."""
    rng = np.random.default_rng(11)
    model = FilmModel(n2, n3, k3, angle)
    for d in [50.0, 120.0, 300.0]:
        raw, dark, white = _instrument(LAM, _tmm_reflectance(LAM, d, n2, n3, k3, angle), rng)
        _check(fit_spectra(LAM, raw, model, background=dark, reference=white), [d])


def test_dispersive_cauchy_film():
    """A Cauchy film (λ in µm, in the model and on the command line) on silicon."""
    film = Cauchy(1.45, 0.0040, 0.0001)  # n = A + B/λ² + C/λ⁴, λ in µm
    rng = np.random.default_rng(3)
    truth = [150.0, 700.0, 2500.0]
    data = [_instrument(LAM, _tmm_reflectance(LAM, d, film, 3.9, 0.02), rng) for d in truth]
    model = FilmModel(parse_index("cauchy:1.45,0.004,0.0001"), 3.9, 0.02)
    fits = [fit_spectra(LAM, raw, model, background=dark, reference=white)[0] for raw, dark, white in data]
    _check(fits, truth)


def test_thin_film_without_reference_reports_its_uncertainty():
    """Without background or reference a 60-nm film's thickness is barely determined (a smooth
    response can mimic the broad shape of R): the fit must say so rather than be precise."""
    rng = np.random.default_rng(5)
    raw = _instrument(LAM, _tmm_reflectance(LAM, 60.0, 1.33, 1.0), rng)[0]
    f = fit_spectra(LAM, raw, FilmModel(1.33, 1.0))[0]
    assert f.thickness_sigma_nm > 0.1 * 60.0
    assert abs(f.thickness_nm - 60.0) <= 3.0 * f.thickness_sigma_nm


def test_coarse_bands_near_the_sampling_limit():
    """5-nm bands, each integrating its band: fringes of a 3-µm film only ~4 bands apart at
    400 nm. The model averages R over each band, so the fit is not fooled by the sampling."""
    centers = np.arange(400.0, 851.0, 5.0)
    fine = np.linspace(-2.5, 2.5, 11)
    lam_fine = (centers[:, None] + fine[None, :]).reshape(-1)
    R = _tmm_reflectance(lam_fine, 3000.0, 1.46, 3.9, 0.02).reshape(centers.size, -1).mean(axis=1)
    raw = _instrument(centers, R, np.random.default_rng(2))[0]
    _check(fit_spectra(centers, raw, FilmModel(1.46, 3.9, 0.02)), [3000.0])


def test_fit_film_ior_on_thick_films():
    """With a background and a reference the fringe contrast fixes the index: recovered within
    0.01 (and 3 sigma) on films of 1.5 and 3 µm, starting 3 % off."""
    rng = np.random.default_rng(9)
    for n2, n3, k3, d in [(1.46, 3.9, 0.02, 3000.0), (2.0, 1.52, 0.0, 1500.0)]:
        raw, dark, white = _instrument(LAM, _tmm_reflectance(LAM, d, n2, n3, k3), rng)
        f = fit_spectra(LAM, raw, FilmModel(1.03 * n2, n3, k3), background=dark, reference=white,
                        fit_film_ior=True)[0]
        assert abs(f.film_ior - n2) <= 0.01, (n2, d, f.film_ior)
        assert abs(f.film_ior - n2) <= 3.0 * f.film_ior_sigma, (n2, d, f.film_ior, f.film_ior_sigma)
        assert abs(f.thickness_nm - d) <= 0.01 * d


def test_cauchy_option_is_in_micrometres_and_the_nm_form_has_its_marker():
    lam = np.array([400.0, 550.0, 800.0])
    um = lam / 1000.0
    n = parse_index("cauchy:1.5,0.004,0.0002")(lam)
    np.testing.assert_allclose(n, 1.5 + 0.004 / um**2 + 0.0002 / um**4, rtol=1e-12)
    n_nm = parse_index("CAUCHY-NM:1.5,4000,2e8")(lam)
    np.testing.assert_allclose(n_nm, 1.5 + 4000.0 / lam**2 + 2e8 / lam**4, rtol=1e-12)
    np.testing.assert_allclose(n_nm, n, rtol=1e-12)
    assert parse_index("cauchy:1.5")(lam).tolist() == [1.5] * 3 == parse_index("cauchy-nm:1.5")(lam).tolist()
    assert parse_index("MgF2")(550.0) == pytest.approx(1.3785, abs=1e-4)


@pytest.mark.parametrize("text, fragment", [
    ("cauchy:1.5,4000", "for λ in nm write cauchy-nm:1.5,4000"),
    ("cauchy:1.45,0.004,1e8", "for λ in nm write cauchy-nm:1.45,0.004,1e8"),
    ("cauchy-nm:1.5,0.004", "for λ in µm write cauchy:1.5,0.004"),
    ("cauchy-nm:1.45,4000,0.0001", "for λ in µm write cauchy:1.45,4000,0.0001"),
    ("cauchy-nm:1.5,5e7", "expected |B| <= 1e+06 nm²"),
])
def test_cauchy_values_plainly_in_the_other_unit_are_refused(text, fragment):
    with pytest.raises(UserError, match="--film-ior: ") as info:
        parse_index(text)
    assert fragment in str(info.value) and "\n" not in str(info.value)


def test_cauchy_in_nm_without_its_marker_is_refused_on_the_command_line(tmp_path, capsys):
    good = _write(tmp_path / "good.csv", np.linspace(400, 800, 50), np.linspace(1.0, 2.0, 50))
    assert main(["fit-spectrum", good, "--film-ior", "cauchy:1.324,3046", "--substrate-ior", "1"]) == 2
    out, err = capsys.readouterr()
    assert out == "" and err.count("\n") == 1 and err.startswith("thinfilm: error: --film-ior: ")
    assert "cauchy-nm:1.324,3046" in err and "Traceback" not in err


def test_both_cauchy_forms_fit_the_same(measured, capsys):
    files, truth, _, _ = measured
    rows = []
    for index in ("cauchy:1.46,0.0035,0.00002", "cauchy-nm:1.46,3500,2e7"):
        assert main(["fit-spectrum", files[0], "--film-ior", index, "--substrate-ior", "3.9",
                     "--substrate-k", "0.02", "--json"]) == 0
        rows.append(json.loads(capsys.readouterr().out))
    # the same model up to the rounding of B nm² · 1e-6 = B µm²: the same fit to 1e-9
    assert sorted(rows[0]) == sorted(rows[1])
    for key, value in rows[0].items():
        assert rows[1][key] == (pytest.approx(value, rel=1e-9) if isinstance(value, (float, list)) else value), key
    assert abs(rows[0]["thickness_nm"] - truth[0]) <= 0.05 * truth[0]


def test_cauchy_in_meta_json_is_in_micrometres():
    from thinfilm.core.film import as_index

    lam = np.array([450.0, 650.0])
    n = as_index({"cauchy": [1.5, 0.004]}, "meta.json: 'film'")(lam)
    np.testing.assert_allclose(n, 1.5 + 0.004 / (lam / 1000.0) ** 2, rtol=1e-12)
    with pytest.raises(UserError, match=r"meta.json: 'film': Cauchy B = 4000 µm², C = 0 µm⁴ are given with "
                                        r"λ in nm, not µm .*divide B by 1e6"):
        as_index({"cauchy": [1.5, 4000.0]}, "meta.json: 'film'")


# ---------------------------------------------------------------------------
# The command
# ---------------------------------------------------------------------------


def _write(path, lam, values, sep=",", header=None, comment=None):
    lines = [] if comment is None else [f"# {comment}"]
    if header:
        lines.append(header)
    lines += [f"{a:.4f}{sep}{b:.6g}" for a, b in zip(lam, values)]
    path.write_text("\n".join(lines) + "\n")
    return str(path)


@pytest.fixture
def measured(tmp_path):
    """Three spectra files of films on silicon (two grids, one file whitespace-separated with
    a header and a comment, one written in decreasing wavelength), plus dark and white."""
    rng = np.random.default_rng(1)
    truth = [2400.0, 900.0, 120.0]
    lam2 = np.linspace(420.0, 840.0, 500)
    files = []
    dark = white = None
    for i, d in enumerate(truth):
        lam = LAM if i != 1 else lam2
        raw, dark_i, white_i = _instrument(lam, _tmm_reflectance(lam, d, 1.46, 3.9, 0.02), rng)
        if i == 0:
            files.append(_write(tmp_path / "a.csv", lam, raw, header="wavelength_nm,counts"))
        elif i == 1:
            files.append(_write(tmp_path / "b.txt", lam[::-1], raw[::-1], sep="  ", header="lambda I",
                                comment="spectrometer export"))
        else:
            files.append(_write(tmp_path / "c.csv", lam, raw))
            dark, white = dark_i, white_i
    # the 120-nm film's instrument readings: background and reference on their own grid
    bg = _write(tmp_path / "dark.csv", LAM, dark)
    ref = _write(tmp_path / "white.csv", LAM, white)
    return files, truth, bg, ref


ARGS = ["--film-ior", "1.46", "--substrate-ior", "3.9", "--substrate-k", "0.02"]


def test_cli_json_lines_in_order(measured, capsys):
    files, truth, _, _ = measured
    assert main(["fit-spectrum", *files[:2], *ARGS, "--json"]) == 0
    rows = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    assert [r["path"] for r in rows] == files[:2]
    for r, d in zip(rows, truth):
        assert abs(r["thickness_nm"] - d) <= 0.01 * d
        assert r["thickness_sigma_nm"] > 0
        assert r["film_ior"] == pytest.approx(1.46)
        assert "film_ior_sigma" not in r
        assert {"chi2", "rms_residual", "fringes", "n_points", "wavelength_range_nm"} <= set(r)
    assert rows[1]["wavelength_range_nm"] == pytest.approx([420.0, 840.0])


def test_cli_table(measured, capsys):
    files, truth, _, _ = measured
    assert main(["fit-spectrum", *files[:2], *ARGS]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[0].split()[:3] == ["spectrum", "thickness_nm", "sigma_nm"]
    for line, path, d in zip(out[1:], files, truth):
        cells = line.split()
        assert cells[0] == path
        assert abs(float(cells[1]) - d) <= 0.01 * d


def test_cli_background_and_reference_are_used(measured, capsys):
    files, truth, bg, ref = measured
    assert main(["fit-spectrum", files[2], *ARGS, "--json", "--background", bg, "--reference", ref]) == 0
    with_files = json.loads(capsys.readouterr().out)
    assert abs(with_files["thickness_nm"] - truth[2]) <= 0.01 * truth[2]
    assert main(["fit-spectrum", files[2], *ARGS, "--json"]) == 0
    without = json.loads(capsys.readouterr().out)
    # without them the 120-nm film is far less certain
    assert without["thickness_sigma_nm"] > 5 * with_files["thickness_sigma_nm"]


def test_cli_fit_film_ior_and_ranges(measured, capsys):
    files, truth, _, _ = measured
    assert main(["fit-spectrum", files[0], "--film-ior", "1.5", "--substrate-ior", "3.9", "--substrate-k", "0.02",
                 "--fit-film-ior", "--json", "--wavelength-range", "450", "800",
                 "--thickness-range", "1000", "4000"]) == 0
    row = json.loads(capsys.readouterr().out)
    assert row["wavelength_range_nm"][0] >= 450 and row["wavelength_range_nm"][1] <= 800
    assert row["film_ior_sigma"] > 0
    assert abs(row["thickness_nm"] * row["film_ior"] - truth[0] * 1.46) <= 0.01 * truth[0] * 1.46


def _bad_files(tmp_path):
    ok = np.linspace(400, 800, 50)
    vals = np.linspace(1.0, 2.0, 50)
    cases = {
        "missing.csv": None,
        "letters.csv": "400,1.0\n401,abc\n",
        "short.csv": "\n".join(f"{400 + i},{1.0}" for i in range(5)),
        "repeat.csv": "\n".join(f"{w:.1f},1.0" for w in [400, 401, 401, 402] + list(range(403, 430))),
        "unordered.csv": "\n".join(f"{w:.1f},1.0" for w in [400, 402, 401] + list(range(403, 430))),
        "three.csv": "400,1,2\n401,1,2\n",
        "nan.csv": "\n".join(f"{w:.1f},{'nan' if w == 420 else 1.0}" for w in range(400, 460)),
        "binary.csv": b"\xff\xfe\x00\x01",
    }
    paths = {}
    for name, text in cases.items():
        p = tmp_path / name
        if isinstance(text, bytes):
            p.write_bytes(text)
        elif text is not None:
            p.write_text(text)
        paths[name] = str(p)
    good = _write(tmp_path / "good.csv", ok, vals)
    return paths, good


def test_cli_every_bad_file_one_line_exit_2(tmp_path, capsys):
    paths, good = _bad_files(tmp_path)
    code = main(["fit-spectrum", good, *paths.values(), "--film-ior", "1.33", "--substrate-ior", "1"])
    out, err = capsys.readouterr()
    assert code == 2 and out == ""  # nothing fitted when an input is bad
    lines = err.strip().splitlines()
    assert len(lines) == len(paths)
    assert "Traceback" not in err
    for line, name in zip(lines, paths):
        assert line.startswith("thinfilm: error: ") and name in line
    expect = {"missing.csv": "missing.csv: spectrum file (two columns: wavelength in nm, value) not found",
              "letters.csv": "line 2: 'abc' is not a number",
              "short.csv": "5 samples", "repeat.csv": "repeats", "unordered.csv": "out of order",
              "three.csv": "expected two columns", "nan.csv": "not a finite number",
              "binary.csv": "not a UTF-8 text file"}
    for line, name in zip(lines, paths):
        assert expect[name] in line, line


@pytest.mark.parametrize("options, message", [
    (["--film-ior", "-1.3", "--substrate-ior", "1"], "--film-ior"),
    (["--film-ior", "unobtainium", "--substrate-ior", "1"], "--film-ior"),
    (["--film-ior", "cauchy:1.4,x", "--substrate-ior", "1"], "cauchy"),
    (["--film-ior", "1.33", "--substrate-ior", "0"], "--substrate-ior"),
    (["--film-ior", "1.33", "--substrate-ior", "1", "--substrate-k", "-1"], "--substrate-k"),
    (["--film-ior", "1.33", "--substrate-ior", "1", "--angle", "95"], "--angle"),
    (["--film-ior", "1.33", "--substrate-ior", "1", "--thickness-range", "500", "500"], "--thickness-range"),
    (["--film-ior", "1.33", "--substrate-ior", "1", "--wavelength-range", "900", "950"], "no samples"),
    (["--film-ior", "1.33", "--substrate-ior", "1", "--wavelength-range", "700", "600"], "--wavelength-range"),
])
def test_cli_bad_options_one_line(tmp_path, capsys, options, message):
    good = _write(tmp_path / "good.csv", np.linspace(400, 800, 50), np.linspace(1.0, 2.0, 50))
    assert main(["fit-spectrum", good, *options]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and message in err and "Traceback" not in err


def test_cli_reference_must_cover_and_exceed_background(measured, tmp_path, capsys):
    files, _, bg, _ = measured
    narrow = _write(tmp_path / "narrow.csv", np.linspace(500, 700, 50), np.full(50, 1e4))
    assert main(["fit-spectrum", files[2], *ARGS, "--reference", narrow]) == 2
    assert "covers 500-700 nm" in capsys.readouterr().err
    dim = _write(tmp_path / "dim.csv", LAM, np.zeros(LAM.size))
    assert main(["fit-spectrum", files[2], *ARGS, "--background", bg, "--reference", dim]) == 2
    assert "not above the background" in capsys.readouterr().err


def test_reader_accepts_header_comments_whitespace_and_decreasing(tmp_path):
    p = tmp_path / "s.txt"
    p.write_text("# exported\nwavelength value\n800 1.0  # last\n700\t2.0\n600 3.0\n")
    s = read_spectrum(p)
    np.testing.assert_array_equal(s.wavelengths_nm, [600.0, 700.0, 800.0])
    np.testing.assert_array_equal(s.values, [3.0, 2.0, 1.0])
    np.testing.assert_array_equal(s.lines, [5, 4, 3])
    p.write_text("600,1\nabc,def\n")
    with pytest.raises(UserError, match="line 2"):
        read_spectrum(p)


def test_nan_outside_the_fitted_range_is_ignored(tmp_path, capsys):
    lam = np.linspace(400, 850, 600)
    raw = _instrument(lam, _tmm_reflectance(lam, 2000.0, 1.46, 3.9, 0.02), np.random.default_rng(4))[0]
    raw[:10] = np.nan
    path = _write(tmp_path / "s.csv", lam, raw)
    assert main(["fit-spectrum", path, *ARGS, "--json"]) == 2
    assert "not a finite number" in capsys.readouterr().err
    assert main(["fit-spectrum", path, *ARGS, "--json", "--wavelength-range", "420", "850"]) == 0
    assert abs(json.loads(capsys.readouterr().out)["thickness_nm"] - 2000.0) <= 20.0


def _run_capped(args, cwd, limit_bytes):
    """``thinfilm ARGS`` in a subprocess whose address space is capped at ``limit_bytes``."""
    import resource
    import subprocess
    import sys

    def cap():
        resource.setrlimit(resource.RLIMIT_AS, (limit_bytes, limit_bytes))

    return subprocess.run([sys.executable, "-m", "thinfilm.cli", *map(str, args)], cwd=cwd, capture_output=True,
                          text=True, preexec_fn=cap, timeout=300)


@pytest.mark.parametrize("make, fragment", [
    # 3 million lines, 45 MB (sparse: the size alone refuses it, before a byte is read)
    (lambda p: os.truncate(p, 45_000_000), "is 45000000 bytes, at most"),
    # 2 million short lines under the size limit: refused while counting, before parsing
    (lambda p: p.write_bytes(b"1 2\n" * 2_000_000), "has more than 100000 lines"),
])
def test_a_huge_spectrum_is_refused_before_parsing_under_a_memory_cap(tmp_path, make, fragment):
    path = tmp_path / "huge.txt"
    path.touch()
    make(path)
    run = _run_capped(["fit-spectrum", path, "--film-ior", "1.38", "--substrate-ior", "1.52"], tmp_path,
                      4 * 2**30)
    lines = run.stderr.strip().splitlines()
    assert run.returncode == 2 and len(lines) == 1, run.stderr[-2000:]
    assert "huge.txt" in lines[0] and fragment in lines[0] and "Traceback" not in run.stderr


def test_the_memory_estimate_grows_with_the_samples():
    """The thickness tables of every instrument setting grow with the samples: a 3-million
    sample fit needs far more than any machine has, and is refused before it starts."""
    from thinfilm.reconstruction.spectrum_fit import FilmModel, estimated_memory_bytes

    model = FilmModel(1.38, 1.52)
    small = estimated_memory_bytes(np.linspace(400, 700, 20_000), model)
    large = estimated_memory_bytes(np.linspace(400, 700, 3_000_000), model)
    assert 2e9 < small < 3e10  # tables of 1135 thicknesses x 20 000 samples, for 25 settings
    assert large > 1e12 and large > 100 * small


@pytest.mark.parametrize("values, message", [
    (np.zeros(40), "does not vary"),
    (np.full(40, 0.05), "does not vary"),
    (np.where(np.arange(40) == 3, 1e308, 0.05), r"beyond 1e\+100"),
])
def test_fit_spectra_refuses_spectra_without_information(values, message):
    from thinfilm.reconstruction.spectrum_fit import FilmModel, fit_spectra

    with pytest.raises(ValueError, match=message):
        fit_spectra(np.linspace(400, 700, 40), values, FilmModel(1.38, 1.52))
