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
    code = ("import sys; sys.modules['distributed'] = None\n"
            "from thinfilm.cluster import auto_workers, executor\n"
            "assert auto_workers() == 0\n"
            "with executor(0) as ex: assert ex.describe() == {'mode': 'in-process', 'workers': 0}\n"
            "print('ok')")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0 and proc.stdout.strip() == "ok", proc.stderr


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
