"""The hostile-input corpus: every subcommand, fed what a demanding new user feeds it.

Each case of :data:`CASES` (``tests/_hostile.py`` builds the inputs) must end with exit
code 2, exactly one line on stderr that starts ``thinfilm: error:`` and holds the expected
fragment, no traceback, nothing on stdout, and every file and folder that existed before
the call byte-identical (and of the same mode) after it — nothing half written, nothing of
the user's destroyed. The commands run in-process (fast); signals, locks between real
processes and start-up interrupts run ``thinfilm`` as a subprocess.
"""

from __future__ import annotations

import contextlib
import errno
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from _hostile import (BOX_OBJ, RENDER_SCENE, SMALL, Case, Ctx, build_base, copy_base, diff, has_gpu, run_cli,
                      snapshot)


# -- building blocks of the cases ----------------------------------------------------------------

def _json_edit(path, **changes):
    def setup(c):
        p = Path(c.p(path))
        data = json.loads(p.read_text())
        data.update(changes)
        p.write_text(json.dumps(data))
    return setup


def _exr_edit(path, fn):
    """Rewrite an EXR of the base with ``fn(channels)`` applied."""
    def setup(c):
        from thinfilm.core.io import read_exr, write_exr

        p = Path(c.p(path))
        ch = read_exr(p)
        fn(ch)
        write_exr(p, ch)
    return setup


def _set(ch, names, value, where=None):
    for n in names:
        a = ch[n].copy()
        if where is None:
            a[...] = value
        else:
            a[where(ch)] = value
        ch[n] = a


def _valid(ch):
    return ch["valid"] > 0.5


def _lock(rel):
    """Hold the lock of output ``rel`` as another writer would (a context manager)."""
    def setup(c):
        from thinfilm.core.outputs import output_lock

        target = Path(c.p(rel))
        target.parent.mkdir(parents=True, exist_ok=True)
        return output_lock(target)
    return setup


def _csv(rel, text):
    return lambda c: c.write(rel, text)


def _mesh(rel, text):
    return lambda c: c.write(rel, text)


def _dir_with(rel, files):
    def setup(c):
        for name, data in files.items():
            c.write(f"{rel}/{name}", data)
    return setup


def _copy_of(src, dst, extra=None):
    def setup(c):
        import shutil

        shutil.copytree(c.p(src), c.p(dst), symlinks=True)
        for name, data in (extra or {}).items():
            c.write(f"{dst}/{name}", data)
    return setup


def _full_disk(monkeypatch, c):
    import thinfilm.core.dataset as dataset

    def full(path, channels):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))

    monkeypatch.setattr(dataset, "write_exr", full)


def _full_disk_render(monkeypatch, c):
    import thinfilm.render as render_module

    def full(mi, bitmap, path, file_format):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))

    monkeypatch.setattr(render_module, "write_bitmap", full)


def _fifo(rel):
    """A named pipe where a file is expected (nobody ever writes to it: a read would block)."""
    def setup(c):
        path = Path(c.p(rel))
        path.parent.mkdir(parents=True, exist_ok=True)
        if path.exists():
            path.unlink()
        os.mkfifo(path)
    return setup


@contextlib.contextmanager
def _peer(answer):
    """A loopback server that accepts connections and sends ``answer`` (bytes, or None for
    nothing) to each; its address is set as ``c.peer``."""
    import socket
    import threading

    srv = socket.socket()
    srv.bind(("127.0.0.1", 0))
    srv.listen(8)
    held = []

    def serve():
        while True:
            try:
                conn, _ = srv.accept()
            except OSError:
                return
            held.append(conn)
            if answer is not None:
                with contextlib.suppress(OSError):
                    conn.sendall(answer)

    threading.Thread(target=serve, daemon=True).start()
    try:
        yield f"tcp://127.0.0.1:{srv.getsockname()[1]}"
    finally:
        srv.close()
        for conn in held:
            conn.close()


def _serving(answer):
    def hold(c):
        @contextlib.contextmanager
        def cm():
            with _peer(answer) as address:
                c.peer = address
                yield
        return cm()
    return hold


def _closed_port(c):
    import socket

    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    c.peer = f"tcp://127.0.0.1:{s.getsockname()[1]}"
    s.close()


def _short_connect_timeout(monkeypatch, c):
    import thinfilm.cluster as cluster

    monkeypatch.setattr(cluster, "CONNECT_TIMEOUT_S", 1.0)


def bench_at(scheduler):
    return lambda c: ["benchmark", "--quick", "--scheduler", scheduler(c), "--out", c.p("b")]


def _group_spec(parts):
    body = "".join(f"[[shape.parts]]\nkind = 'hemisphere'\nradius = 0.1\noffset = [{i % 50 * 0.01}, 0, 0]\n"
                   for i in range(parts))
    return "[shape]\nkind = 'group'\n" + body


def _stack_spec(layers):
    return "[film]\n" + "".join(f"[[film.layers]]\nior = 1.4\nthickness_nm = 100\n" for _ in range(layers))


def _few_faces(monkeypatch, c):
    import thinfilm.generators.shapes as shapes

    monkeypatch.setattr(shapes, "MAX_MESH_FACES", 10)


def _decoys(*setups):
    """A decoy file and a decoy folder beside ``--out`` (and ``thesis.txt``, the target of the
    links the cases plant), then ``setups``: the runner checks them all byte-identical after."""
    def setup(c):
        c.write("decoy.txt", "a file of the user's")
        c.write("decoy/inner.txt", "a folder of the user's")
        c.write("thesis.txt", "four years of work")
        for s in setups:
            s(c)
    return setup


def _link(rel, target):
    return lambda c: os.symlink(c.p(target), c.p(rel))


def _xml_scene(bsdf_body: str, size: int) -> str:
    """A Mitsuba XML scene: a sphere with a ``thinfilm`` BSDF holding ``bsdf_body``, seen by a
    ``size``-pixel orthographic sensor under a constant emitter."""
    return ('<scene version="3.0.0"><sensor type="orthographic"><film type="hdrfilm">'
            f'<integer name="width" value="{size}"/><integer name="height" value="{size}"/></film></sensor>'
            f'<shape type="sphere"><bsdf type="thinfilm">{bsdf_body}</bsdf></shape>'
            '<emitter type="constant"/></scene>')


def _thickness_bitmap(c, value):
    """A render scene whose film thickness is a 2 x 2 PFM bitmap holding ``value`` in one pixel."""
    pixels = np.full(4, 300.0, dtype="<f4")
    pixels[0] = value
    c.write("t.pfm", b"Pf\n2 2\n-1.0\n" + pixels.tobytes())
    c.write("tex.toml", RENDER_SCENE.replace("THICKNESS", "{ type = 'bitmap', filename = 't.pfm', raw = true }"))


def gen(*extra, out="out"):
    return lambda c: ["generate", "hemisphere", *SMALL, *extra, "--out", c.p(out) if out else "/"]


def gen_spec(spec_rel, *extra, out="out"):
    return lambda c: ["generate", c.p(spec_rel), *extra, "--out", c.p(out)]


def render(*extra, scene="scene.toml", out="img"):
    return lambda c: ["render", c.p(scene), "--variant", "llvm_ad_mono_polarized", *extra, "--out", c.p(out)]


def rec(kind="rgb", *extra, ds="ds", out="out"):
    return lambda c: ["reconstruct", kind, c.p(ds), *extra, "--out", c.p(out)]


def ev(ds="ds", est="est", out="out"):
    return lambda c: ["evaluate", c.p(ds), c.p(est), "--out", c.p(out)]


def ref(*extra, ds="ds", est="est", out="out"):
    return lambda c: ["refine", c.p(ds), c.p(est), *extra, "--out", c.p(out)]


def _images(c):
    from PIL import Image

    for a in (0, 45, 90, 135):
        path = c.root / "imgs" / f"a{a:03d}.png"
        path.parent.mkdir(exist_ok=True)
        Image.fromarray(np.full((8, 8, 3), 60 + a // 3, np.uint8)).save(path)


def imp(*extra, out="out"):
    return lambda c: ["import", "polarization", *[c.p("imgs", f"a{a:03d}.png") for a in (0, 45, 90, 135)],
                      "--layout", "separate", "--angles", "0,45,90,135", *extra, "--out", c.p(out)]


def _spectrum(c, values=None):
    wl = np.arange(400.0, 701.0, 10.0)
    r = 0.04 + 0.02 * np.cos(wl / 30.0) if values is None else values(wl)
    c.write("s.txt", "".join(f"{w:g},{v!r}\n" for w, v in zip(wl, r)))


def fit(*extra, spectrum="s.txt"):
    return lambda c: ["fit-spectrum", c.p(spectrum), "--film-ior", "1.38", "--substrate-ior", "1.52", *extra]


CSV_OK = "wavelength_nm,r,g,b\n400,0.1,0.2,0.3\n500,0.4,0.5,0.6\n600,0.7,0.5,0.2\n700,0.3,0.2,0.1\n"
NOT_UTF8 = b"\xff\xfe\x00 not text \x81"

CASES = [
    # --- render -----------------------------------------------------------------------------------
    Case("render/missing-scene", lambda c: ["render", c.p("nope.xml"), "--out", c.p("img")],
         "nope.xml: scene file not found"),
    Case("render/scene-is-a-folder", lambda c: ["render", c.ds, "--out", c.p("img")], "scene file not found"),
    Case("render/unknown-extension", render(scene="scene.txt"), "expected a .xml, .toml or .json scene file",
         setup=lambda c: c.write("scene.txt", "type = 'scene'")),
    Case("render/invalid-toml", render(scene="bad.toml"), "not valid TOML",
         setup=lambda c: c.write("bad.toml", "type = [scene")),
    Case("render/invalid-json", render(scene="bad.json"), "not valid JSON",
         setup=lambda c: c.write("bad.json", "{'type': 'scene'")),
    Case("render/json-not-a-table", render(scene="list.json"), "expected a table",
         setup=lambda c: c.write("list.json", "[1, 2, 3]")),
    Case("render/not-a-scene", render(scene="sphere.json"), 'expected type = "scene"',
         setup=lambda c: c.write("sphere.json", '{"type": "sphere"}')),
    Case("render/not-utf8", render(scene="bin.toml"), "not a UTF-8 text file",
         setup=lambda c: c.write("bin.toml", NOT_UTF8)),
    Case("render/unknown-variant", render("--variant", "nope"), "unknown Mitsuba variant 'nope'"),
    Case("render/overwrite-an-output-that-is-a-link", render("--overwrite"), "img.exr: is a symbolic link",
         setup=_decoys(_link("img.exr", "thesis.txt"))),
    Case("render/output-a-dangling-link", render(), "is a symbolic link that points nowhere",
         setup=_decoys(_link("img.png", "gone/zzz"))),
    Case("render/overwrite-a-fifo", render("--overwrite"), "is not a regular file",
         setup=_decoys(lambda c: os.mkfifo(c.p("img.exr")))),
    Case("render/lock-path-a-link-to-a-user-file", render(), "'.img.exr.lock' beside it is a symbolic link",
         setup=_decoys(_link(".img.exr.lock", "thesis.txt"))),
    Case("render/cuda-without-gpu", render("--variant", "cuda_ad_mono_polarized"), "cannot run on this machine",
         absent=("libLLVM",), skip=lambda: "a GPU is present" if has_gpu() else None),
    Case("render/exposure-negative", render("--exposure", "-2"), "--exposure: expected 'auto' or a positive number"),
    Case("render/exposure-nan", render("--exposure", "nan"), "--exposure"),
    Case("render/seed-negative", render("--seed", "-5"), "argument --seed"),
    Case("render/seed-2^32", render("--seed", str(2**32)), "argument --seed"),
    Case("render/spp-2^32", render("--spp", "4294967296"), "argument --spp"),
    Case("render/spp-zero", render("--spp", "0"), "argument --spp"),
    Case("render/negative-thickness", render(scene="neg.toml"), "'thickness' must be a finite number from 0 to 100000 nm, got -1.0",
         setup=lambda c: c.write("neg.toml", RENDER_SCENE.replace("THICKNESS", "-1.0"))),
    Case("render/thickness-inf", render(scene="inf.toml"), "'thickness' must be a finite number from 0 to 100000 nm, "
         "got inf", setup=lambda c: c.write("inf.toml", RENDER_SCENE.replace("THICKNESS", "inf"))),
    Case("render/alpha-5", render(scene="rough.toml"), "'alpha' must be a finite number from 0 to 1, got 5.0",
         setup=lambda c: c.write("rough.toml", RENDER_SCENE.replace("THICKNESS", "300.0")
                                 .replace("substrate_ior = 1.6 }", "substrate_ior = 1.6, alpha = 5.0 }"))),
    Case("render/thickness-bitmap-nan", render(scene="tex.toml"), "'thickness': the texture holds nan",
         setup=lambda c: _thickness_bitmap(c, float("nan"))),
    Case("render/thickness-bitmap-negative", render(scene="tex.toml"), "'thickness': the texture holds -100 (1 of "
         "the 4 values of its 'data' out of range); expected a finite number from 0 to 100000 nm",
         setup=lambda c: _thickness_bitmap(c, -100.0)),
    Case("render/stack-10000-layers", render(scene="stack.toml"), "'stack' holds 10000 layers, at most 200 in "
         "llvm_ad_mono_polarized", setup=lambda c: c.write("stack.toml", RENDER_SCENE.replace(
             "thickness = THICKNESS, film_ior = 1.37,", "stack = '" + ", ".join(["1.5:100"] * 10000) + "',"))),
    Case("render/sheet-negative-thickness", render(scene="sheet.toml"), "thinfilm_sheet: parameter 'thickness' must "
         "be a finite number from 0 to 100000 nm, got -3.0", absent=("Traceback", "instantiate"),
         setup=lambda c: c.write("sheet.toml", RENDER_SCENE.replace("THICKNESS", "-3.0")
                                 .replace('"thinfilm"', '"thinfilm_sheet"').replace(", substrate_ior = 1.6", ""))),
    Case("render/xml-alpha-nan", render(scene="rough.xml"), "'alpha' must be a finite number from 0 to 1, got nan",
         setup=lambda c: c.write("rough.xml", _xml_scene('<float name="alpha" value="nan"/>', 4))),
    Case("render/unknown-dict-parameter", render(scene="typo.toml"), '"film_iorr"',
         setup=lambda c: c.write("typo.toml", RENDER_SCENE.replace("THICKNESS", "300.0")
                                 .replace("film_ior =", "film_iorr ="))),
    Case("render/unknown-xml-parameter", render(scene="typo.xml"), '"thickness_of_the_film_in_nanometres"',
         setup=lambda c: c.write("typo.xml", _xml_scene('<float name="thickness_of_the_film_in_nanometres" '
                                                        'value="3"/>', 8))),
    Case("render/unknown-transform-step", render(scene="tw.toml"), "unknown transform step 'shear'",
         setup=lambda c: c.write("tw.toml", RENDER_SCENE.replace("THICKNESS", "300.0")
                                 .replace("to_world = { look_at", "to_world = { shear = 1, look_at"))),
    Case("render/bad-look-at", render(scene="la.toml"), "to_world.look_at: expected",
         setup=lambda c: c.write("la.toml", RENDER_SCENE.replace("THICKNESS", "300.0")
                                 .replace("origin = [0, 0, 5], ", ""))),
    Case("render/exr-exists", render(), "img.exr: file exists; pass --overwrite",
         setup=lambda c: c.write("img.exr", b"someone's picture")),
    Case("render/png-exists", render(), "img.png: file exists; pass --overwrite",
         setup=lambda c: c.write("img.png", b"someone's picture")),
    Case("render/out-stem-with-extension-exists", render(out="img.png"), "file exists",
         setup=lambda c: c.write("img.exr", b"someone's picture")),
    Case("render/exr-is-a-folder", render("--overwrite"), "is a folder, expected a file path",
         setup=lambda c: c.write("img.exr/keep.txt", "mine")),
    Case("render/overwrite-never-replaces-an-input", render("--overwrite", scene="tex.json", out="wood"),
         "is the input",
         setup=lambda c: (c.write("wood.png", b"\x89PNG the scene's own texture"),
                          c.write("tex.json", json.dumps({"type": "scene", "s": {"type": "sphere", "bsdf": {
                              "type": "diffuse", "reflectance": {"type": "bitmap", "filename": "wood.png"}}}})))),
    Case("render/out-under-a-file", render(out="blocker/img"), "cannot create the folder",
         setup=lambda c: c.write("blocker", "a file")),
    Case("render/lock-held", render(), "another thinfilm command", hold=_lock("img.exr")),
    Case("render/full-disk", render(out="new/img"), "cannot write the output (No space left on device)",
         patch=_full_disk_render),

    # --- generate ---------------------------------------------------------------------------------
    Case("generate/unknown-preset", lambda c: ["generate", "hemisfear", "--out", c.p("out")], "unknown preset"),
    Case("generate/spec-missing", gen_spec("missing.toml"), "scene spec not found"),
    Case("generate/invalid-toml", gen_spec("bad.toml"), "not valid TOML",
         setup=lambda c: c.write("bad.toml", "[shape\nkind = 1")),
    Case("generate/not-utf8", gen_spec("bin.toml"), "not a UTF-8 text file",
         setup=lambda c: c.write("bin.toml", NOT_UTF8)),
    Case("generate/resolution-0", gen("--resolution", "0"), "argument --resolution"),
    Case("generate/resolution-1", gen("--resolution", "1"), "argument --resolution"),
    Case("generate/resolution-70000", gen("--resolution", "70000"), "argument --resolution"),
    Case("generate/resolution-1-in-spec", gen("--set", "rig.resolution=1", "--resolution", "1"),
         "argument --resolution"),
    Case("generate/spec-resolution-70000", gen_spec("big.toml"), "'rig.resolution' must be a whole number of "
         "pixels from 2 to 16384", setup=lambda c: c.write("big.toml", "[rig]\nresolution = 70000\n")),
    Case("generate/spec-resolution-1", gen_spec("one.toml"), "'rig.resolution' must be",
         setup=lambda c: c.write("one.toml", "[rig]\nresolution = 1\n")),
    Case("generate/more-memory-than-the-machine", gen("--resolution", "16384", "--set", "rig.wavelengths_nm.step=4"),
         "GiB of memory"),
    Case("generate/radius-1e300", gen("--set", "shape.radius=1e300"), "'shape.radius' must be a length"),
    Case("generate/radius-1e-300", gen("--set", "shape.radius=1e-300"), "'shape.radius' must be a length"),
    Case("generate/radius-nan", gen("--set", "shape.radius=nan"), "'shape.radius' must be a finite number"),
    Case("generate/mesh-scale-1e300", gen("--set", "shape.kind=mesh", "--set", "shape.path=box.obj",
                                          "--set", "shape.scale=1e300"), "'shape.scale' must be a length"),
    Case("generate/mesh-scale-1e-300", gen("--set", "shape.kind=mesh", "--set", "shape.path=box.obj",
                                           "--set", "shape.scale=1e-300"), "'shape.scale' must be a length"),
    Case("generate/mesh-far-too-big", gen("--set", "shape.kind=mesh", "--set", "shape.path=huge.obj"),
         "scene units across", setup=_mesh("huge.obj", BOX_OBJ.replace("v 0.5", "v 5e9"))),
    Case("generate/exposure-1e30", gen("--set", "noise.model=camera", "--set", "noise.exposure=1e30"),
         "'noise.exposure' must be"),
    Case("generate/full-well-1e30", gen("--set", "noise.model=camera", "--set", "noise.full_well=1e30"),
         "'noise.full_well' must be a number of electrons"),
    Case("generate/read-noise-1e30", gen("--set", "noise.read_noise=1e30"), "'noise.read_noise' must be"),
    Case("generate/camera-csv-nan", gen("--set", "rig.camera=cam.csv"), "line 3: camera sensitivity CSV holds NaN",
         setup=_csv("cam.csv", CSV_OK.replace("500,0.4", "500,nan"))),
    Case("generate/camera-csv-text-cell", gen("--set", "rig.camera=cam.csv"), "cell 'high' is not a number",
         setup=_csv("cam.csv", CSV_OK.replace("0.5,0.6", "high,0.6"))),
    Case("generate/camera-csv-columns", gen("--set", "rig.camera=cam.csv"), "needs 4 columns",
         setup=_csv("cam.csv", CSV_OK.replace(",0.3\n", "\n"))),
    Case("generate/camera-csv-one-row", gen("--set", "rig.camera=cam.csv"), "at least 2 rows",
         setup=_csv("cam.csv", "wavelength_nm,r,g,b\n500,1,1,1\n")),
    Case("generate/camera-csv-empty", gen("--set", "rig.camera=cam.csv"), "at least 2 rows",
         setup=_csv("cam.csv", "")),
    Case("generate/camera-csv-decreasing", gen("--set", "rig.camera=cam.csv"), "wavelengths must be increasing",
         setup=_csv("cam.csv", "700,1,1,1\n400,1,1,1\n")),
    Case("generate/camera-csv-binary", gen("--set", "rig.camera=cam.csv"), "not a UTF-8 text file",
         setup=_csv("cam.csv", NOT_UTF8)),
    Case("generate/illuminant-csv-negative", gen("--set", "rig.illuminant=ill.csv"), "values >= 0",
         setup=_csv("ill.csv", "400,1\n500,-2\n700,1\n")),
    Case("generate/bitmap-of-strings", gen("--set", "film.thickness.profile=bitmap", "--set",
                                           "film.thickness.path=t.npy"), "must hold numbers",
         setup=lambda c: c.npy("t.npy", np.full((4, 4), "abc"))),
    Case("generate/bitmap-of-objects", gen("--set", "film.thickness.profile=bitmap", "--set",
                                           "film.thickness.path=t.npy"), "cannot read thickness bitmap",
         setup=lambda c: c.npy("t.npy", np.array([{"a": 1}, None], dtype=object))),
    Case("generate/bitmap-nan", gen("--set", "film.thickness.profile=bitmap", "--set",
                                    "film.thickness.path=t.npy"), "NaN",
         setup=lambda c: c.npy("t.npy", np.array([[400.0, np.nan], [400.0, 400.0]]))),
    Case("generate/bitmap-3d", gen("--set", "film.thickness.profile=bitmap", "--set",
                                   "film.thickness.path=t.npy"), "must be a 2-D image",
         setup=lambda c: c.npy("t.npy", np.zeros((2, 2, 2)))),
    Case("generate/bitmap-in-metres", gen("--set", "film.thickness.profile=bitmap", "--set",
                                          "film.thickness.path=t.npy"), "expected at most",
         setup=lambda c: c.npy("t.npy", np.full((2, 2), 4e9))),
    Case("generate/bitmap-truncated-exr", gen("--set", "film.thickness.profile=bitmap", "--set",
                                              "film.thickness.path=t.exr"), "not a readable EXR file",
         setup=lambda c: c.write("t.exr", Path(c.p("ds", "ground_truth.exr")).read_bytes()[:700])),
    Case("generate/polarizer-400", gen("--set", "rig.polarizer_angles_deg=[0,45,90,400]"),
         "whole-degree polarizer angles from 0 to 359"),
    Case("generate/polarizer-negative", gen("--set", "rig.polarizer_angles_deg=[-45,0,45,90]"), "from 0 to 359"),
    Case("generate/polarizer-twice", gen("--set", "rig.polarizer_angles_deg=[0,0,45,90]"), "distinct"),
    Case("generate/wavelength-nan", gen("--set", "rig.wavelengths_nm={start=nan,stop=700.0,step=40.0}"),
         "'rig.wavelengths_nm.start' must be a finite number"),
    Case("generate/passband-1e-6", gen("--set", "rig.band_fwhm_nm=1e-6"), "renders per image"),
    Case("generate/passband-1e30", gen("--set", "rig.band_fwhm_nm=1e30"), "'rig.band_fwhm_nm' must be"),
    Case("generate/thickness-negative", gen("--set", "film.thickness.value=-5"), "'film.thickness.value' must be"),
    Case("generate/thickness-1e9", gen("--set", "film.thickness.value=1e9"), "'film.thickness.value' must be"),
    Case("generate/film-ior-nan", gen("--set", "film.ior=nan"), "'film.ior'"),
    Case("generate/film-index-1e-300", gen("--set", "film.ior=1e-300"), "'film.ior' must be a refractive index"),
    Case("generate/film-index-complex-1e300", gen("--set", "film.ior='1e300+0.1i'"), "'film.ior' must be a refractive"),
    Case("generate/substrate-index-1e300", gen("--set", "substrate.ior=1e300"), "'substrate.ior' must be"),
    Case("generate/substrate-k-1e300", gen("--set", "substrate.k=1e300"), "'substrate.k' must be"),
    Case("generate/mesh-path-a-folder", gen("--set", "shape.kind=mesh", "--set", "shape.path=ds"),
         "names a file that does not exist"),
    Case("generate/mesh-path-a-device", gen("--set", "shape.kind=mesh", "--set", "shape.path=/dev/zero"),
         "names a file that does not exist"),
    Case("generate/out-through-a-link-loop", gen(out="loop/out"), "--out",
         setup=lambda c: os.symlink(c.p("loop"), c.p("loop"))),
    Case("generate/seed-negative", gen("--seed", "-5"), "'seed' must be a whole number from 0"),
    Case("generate/seed-2^40", gen("--seed", str(2**40)), "'seed' must be a whole number from 0"),
    Case("generate/malformed-set", gen("--set", "novalue"), "expected KEY=VALUE"),
    Case("generate/unknown-key", gen("--set", "rig.resolutoin=8"), "unknown key 'rig.resolutoin'"),
    Case("generate/mesh-edge-on", gen("--set", "shape.kind=mesh", "--set", "shape.path=sliver.obj"),
         "covers no pixel that faces the camera",
         setup=_mesh("sliver.obj", "v 0 0 0\nv 1 0 0\nv 0.5 1e-7 1\nf 1 2 3\n")),
    Case("generate/cylinder-thinner-than-a-pixel", gen("--set", "shape.kind=cylinder", "--set",
                                                       "shape.length=1e-6"), "covers no pixel"),
    Case("generate/mesh-degenerate", gen("--set", "shape.kind=mesh", "--set", "shape.path=line.obj"),
         "line.obj",
         setup=_mesh("line.obj", "v 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 3\n")),
    Case("generate/mesh-garbage", gen("--set", "shape.kind=mesh", "--set", "shape.path=junk.ply"),
         "junk.ply", setup=_mesh("junk.ply", "this is not a mesh\n")),
    Case("generate/mesh-empty", gen("--set", "shape.kind=mesh", "--set", "shape.path=empty.obj"),
         "empty.obj", setup=_mesh("empty.obj", "")),
    Case("generate/out-a-folder-of-user-files", gen(), "not a thinfilm output",
         setup=_dir_with("out", {"thesis.tex": "do not delete"})),
    Case("generate/out-old-dataset-with-src", gen(), "not a thinfilm output",
         setup=_dir_with("out", {"meta.json": "{}", "src/main.c": "int main;", ".git/HEAD": "ref"})),
    Case("generate/out-ours-plus-notes", gen(out="ds"), "holds 'notes.md'",
         setup=lambda c: c.write("ds/notes.md", "my notes")),
    Case("generate/out-ours-plus-git", gen(out="ds"), "holds '.git'",
         setup=lambda c: c.write("ds/.git/HEAD", "ref: refs/heads/main")),
    Case("generate/out-an-estimate", gen(out="est"), "holds the output of 'thinfilm reconstruct'"),
    Case("generate/out-the-bitmaps-folder", gen("--set", "film.thickness.profile=bitmap", "--set",
                                                "film.thickness.path=maps/t.npy", out="maps"),
         "contains the input", setup=lambda c: c.npy("maps/t.npy", np.full((4, 4), 400.0))),
    Case("generate/out-the-spec-folder", gen_spec("specs/s.toml", "--resolution", "8", out="specs"),
         "contains the input", setup=lambda c: c.write("specs/s.toml", "[shape]\nkind = 'hemisphere'\n")),
    Case("generate/out-is-a-file", gen(out="file"), "exists and is not a folder",
         setup=lambda c: c.write("file", "x")),
    Case("generate/out-under-a-file", gen(out="file/out"), "cannot create the folder",
         setup=lambda c: c.write("file", "x")),
    Case("generate/out-root", gen(out=None), "file-system root"),
    Case("generate/lock-held", gen(), "another thinfilm command", hold=_lock("out")),
    # the output machinery touches only what it made: the lock path, links, named-alike files
    Case("generate/lock-path-a-link-to-a-user-file", gen(), "'.out.lock' beside it is a symbolic link that "
         "thinfilm did not make", setup=_decoys(_link(".out.lock", "thesis.txt"))),
    Case("generate/lock-path-a-dangling-link", gen(), "'.out.lock' beside it is a symbolic link",
         setup=_decoys(_link(".out.lock", "gone/zzz"))),
    Case("generate/lock-path-a-user-file", gen(), "'.out.lock' beside it is a file that thinfilm did not make",
         setup=_decoys(lambda c: c.write(".out.lock", "my own lock file"))),
    Case("generate/lock-path-a-user-folder", gen(), "'.out.lock' beside it is a folder",
         setup=_decoys(lambda c: c.write(".out.lock/notes.txt", "mine"))),
    Case("generate/lock-of-another-host", gen(), "another thinfilm command (process 1 on elsewhere)",
         setup=_decoys(lambda c: c.write(".out.lock", "thinfilm-lock/1 1 elsewhere\n"))),
    Case("generate/out-a-dangling-link", gen(out="dangling"), "is a symbolic link that points nowhere",
         setup=_decoys(_link("dangling", "gone/zzz"))),
    Case("generate/out-under-a-dangling-link", gen(out="dangling/out"), "is a symbolic link that points nowhere",
         setup=_decoys(_link("dangling", "gone/zzz"))),
    Case("generate/out-a-link-to-an-earlier-dataset", gen(out="link"), "refusing to write through it",
         setup=_decoys(_link("link", "ds"))),
    Case("generate/full-disk", gen(out="new/deeper/out"), "cannot write the output (No space left on device)",
         patch=_full_disk),

    # --- reconstruct ------------------------------------------------------------------------------
    Case("reconstruct/dataset-missing", rec(ds="nowhere"), "dataset folder not found"),
    Case("reconstruct/not-a-dataset", rec(ds="empty"), "not a thinfilm dataset folder",
         setup=lambda c: os.mkdir(c.p("empty"))),
    Case("reconstruct/meta-invalid-json", rec(), "meta.json: not valid JSON",
         setup=lambda c: c.write("ds/meta.json", "{")),
    Case("reconstruct/meta-unknown-format", rec(), "unknown format", setup=_json_edit("ds/meta.json", format="x/9")),
    Case("reconstruct/meta-nan-substrate", rec(), "'substrate_ior' is NaN", absent=("--substrate-ior",),
         setup=_json_edit("ds/meta.json", substrate_ior=float("nan"))),
    Case("reconstruct/meta-polarizer-400", rec(), "'polarizer_angles_deg' must be whole degrees from 0 to 359",
         setup=_json_edit("ds/meta.json", polarizer_angles_deg=[0, 45, 90, 400])),
    Case("reconstruct/truncated-exr", rec(), "polarized_rgb.exr: not a readable EXR file",
         setup=lambda c: c.write("ds/polarized_rgb.exr", Path(c.p("ds/polarized_rgb.exr")).read_bytes()[:900])),
    Case("reconstruct/exr-header-only", rec(), "polarized_rgb.exr: not a readable EXR file",
         setup=lambda c: c.write("ds/polarized_rgb.exr", Path(c.p("ds/polarized_rgb.exr")).read_bytes()[:100])),
    Case("reconstruct/nan-in-capture", rec(), "contains NaN",
         setup=_exr_edit("ds/polarized_rgb.exr", lambda ch: _set(ch, ["pol045.G"], np.nan))),
    Case("reconstruct/missing-channel", rec(), "missing channel 'pol090.R'",
         setup=_exr_edit("ds/polarized_rgb.exr", lambda ch: ch.pop("pol090.R"))),
    Case("reconstruct/out-is-the-dataset", rec(out="ds"), "is the input"),
    Case("reconstruct/out-inside-the-dataset", rec(out="ds/est"), "lies inside the input"),
    Case("reconstruct/out-the-parent-of-the-dataset", rec(out="."), "contains the input"),
    Case("reconstruct/out-link-to-the-dataset", rec(out="link"), "is the input",
         setup=lambda c: os.symlink(c.ds, c.p("link"))),
    Case("reconstruct/out-user-folder-with-estimate-json", rec(), "not a thinfilm output",
         setup=_dir_with("out", {"estimate.json": "{}", "src/x.py": "print()"})),
    Case("reconstruct/out-another-dataset", rec(out="ds2"), "holds the output of 'thinfilm generate'",
         setup=_copy_of("ds", "ds2")),
    Case("reconstruct/out-ours-plus-notes", rec(out="est2"), "holds 'notes.txt'",
         setup=_copy_of("est", "est2", {"notes.txt": "mine"})),
    Case("reconstruct/thickness-range-1e9", rec("rgb", "--thickness-range", "0", "1e9"),
         "--thickness-range: MAX must be at most"),
    Case("reconstruct/thickness-range-reversed", rec("rgb", "--thickness-range", "500", "100"),
         "--thickness-range: expected 0 <= MIN < MAX"),
    Case("reconstruct/thickness-range-nan", rec("rgb", "--thickness-range", "nan", "100"), "argument --thickness-range"),
    Case("reconstruct/film-ior-nan", rec("rgb", "--film-ior", "nan"), "argument --film-ior"),
    Case("reconstruct/film-ior-negative", rec("rgb", "--film-ior", "-1.4"), "argument --film-ior"),
    Case("reconstruct/film-ior-1e-300", rec("rgb", "--film-ior", "1e-300"), "argument --film-ior"),
    Case("reconstruct/meta-json-a-folder", rec(), "meta.json: file not found",
         setup=lambda c: (os.unlink(c.p("ds/meta.json")), os.mkdir(c.p("ds/meta.json")))),
    Case("reconstruct/substrate-ior-zero", rec("spectral", "--substrate-ior", "0"), "argument --substrate-ior"),
    Case("reconstruct/mask-missing", rec("rgb", "--mask", "nomask.png"), "mask file not found"),
    Case("reconstruct/mask-wrong-shape", rec("rgb", "--mask", "m.npy"), "mask has shape",
         setup=lambda c: c.npy("m.npy", np.ones((3, 5)))),
    Case("reconstruct/mask-of-strings", rec("rgb", "--mask", "m.npy"), "cannot read the mask image",
         setup=lambda c: c.npy("m.npy", np.full((8, 8), "yes"))),
    Case("reconstruct/unknown-method", rec("rgb", "--method", "telepathy"), "telepathy"),
    Case("reconstruct/spectral-out-is-the-dataset", rec("spectral", out="ds"), "is the input"),
    Case("reconstruct/lock-held", rec(), "another thinfilm command", hold=_lock("out")),
    Case("reconstruct/lock-path-a-link-to-a-user-file", rec(out="est"), "'.est.lock' beside it is a symbolic "
         "link", setup=_decoys(_link(".est.lock", "thesis.txt"))),
    Case("reconstruct/lock-path-a-user-file", rec(out="est"), "'.est.lock' beside it is a file",
         setup=_decoys(lambda c: c.write(".est.lock", "12345\n"))),

    # --- evaluate ---------------------------------------------------------------------------------
    Case("evaluate/out-is-the-dataset", ev(out="ds"), "is the input"),
    Case("evaluate/out-is-the-estimate", ev(out="est"), "is the input"),
    Case("evaluate/out-inside-the-estimate", ev(out="est/eval"), "lies inside the input"),
    Case("evaluate/out-holds-both-inputs", ev(out="."), "contains the input"),
    Case("evaluate/out-user-folder-with-metrics-json", ev(), "not a thinfilm output",
         setup=_dir_with("out", {"metrics.json": "{}", "paper.tex": "draft"})),
    Case("evaluate/estimate-missing", ev(est="none"), "estimate folder not found"),
    Case("refine/estimate-missing", ref(est="none"), "estimate folder not found"),
    Case("refine/dataset-missing", ref(ds="nowhere"), "dataset folder not found"),
    Case("refine/out-is-the-estimate", ref(out="est"), "is the input"),
    Case("refine/out-is-the-dataset", ref(out="ds"), "is the input"),
    Case("refine/iterations-zero", ref("--iterations", "0"), "--iterations"),
    Case("refine/prior-unknown", ref("--prior", "gaussian"), "--prior"),
    Case("evaluate/nan-normal", ev(), "channel 'normal' is NaN",
         setup=_exr_edit("est/estimate.exr", lambda ch: _set(ch, ["normal.X"], np.nan, _valid))),
    Case("evaluate/negative-thickness", ev(), "channel 'thickness' is negative",
         setup=_exr_edit("est/estimate.exr", lambda ch: _set(ch, ["thickness"], -20.0, _valid))),
    Case("evaluate/non-unit-normals", ev(), "not unit vectors",
         setup=_exr_edit("est/estimate.exr", lambda ch: ch.update(
             {k: ch[k] * 2 for k in ("normal.X", "normal.Y", "normal.Z")}))),
    Case("evaluate/normals-facing-away", ev(), "'normal.Z' is <= 0",
         setup=_exr_edit("est/estimate.exr", lambda ch: ch.update({"normal.Z": -ch["normal.Z"]}))),
    Case("evaluate/no-valid-pixel", ev(), "marks no pixel",
         setup=_exr_edit("est/estimate.exr", lambda ch: _set(ch, ["valid"], 0.0))),
    Case("evaluate/valid-only-off-the-object", ev(), "no pixel marked valid lies on the object",
         setup=_exr_edit("est/estimate.exr", lambda ch: ch.update(
             {"valid": (ch["valid"] < 0.5).astype(np.float32), "normal.X": np.zeros_like(ch["valid"]),
              "normal.Y": np.zeros_like(ch["valid"]), "normal.Z": np.ones_like(ch["valid"]),
              "thickness": np.full_like(ch["valid"], 300.0)}))),
    Case("evaluate/nan-in-ground-truth", ev(), "ground_truth.exr: channel 'thickness' contains NaN",
         setup=_exr_edit("ds/ground_truth.exr", lambda ch: _set(ch, ["thickness"], np.nan,
                                                                 lambda c: c["mask"] > 0.5))),
    Case("evaluate/estimate-json-not-an-object", ev(), "expected a JSON object",
         setup=lambda c: c.write("est/estimate.json", "[1]")),
    Case("evaluate/film-ior-unknown-material", ev(), "'film_ior'",
         setup=_json_edit("est/estimate.json", film_ior="unobtainium")),
    Case("evaluate/film-ior-nan", ev(), "'film_ior' must be positive",
         setup=_json_edit("est/estimate.json", film_ior=float("nan"))),
    Case("evaluate/film-ior-1e-300", ev(), "'film_ior' must be a refractive index",
         setup=_json_edit("est/estimate.json", film_ior=1e-300)),
    Case("evaluate/substrate-ior-1e300", ev(), "field 'substrate_ior' must be a refractive index",
         setup=_json_edit("est/estimate.json", substrate_ior=1e300)),
    Case("evaluate/substrate-ior-infinite", ev(), "'substrate_ior' must be a positive number",
         setup=_json_edit("est/estimate.json", substrate_ior=float("inf"))),
    Case("evaluate/estimate-of-another-size", ev(), "the estimate does not belong to this dataset",
         setup=_exr_edit("est/estimate.exr", lambda ch: ch.update({k: v[:4, :5] for k, v in ch.items()}))),
    Case("evaluate/lock-held", ev(), "another thinfilm command", hold=_lock("out")),

    # --- import ----------------------------------------------------------------------------------------
    Case("import/out-is-the-images-folder", imp(out="imgs"), "contains the input", setup=_images),
    Case("import/out-is-an-image", imp(out="imgs/a000.png"), "is the input", setup=_images),
    Case("import/out-over-a-generated-dataset", imp(out="ds"), "holds the output of 'thinfilm generate'",
         setup=_images),
    Case("import/out-a-folder-of-user-files", imp(), "not a thinfilm output",
         setup=lambda c: (_images(c), c.write("out/raw/IMG_0001.CR2", b"camera raw"))),
    Case("import/lock-held", imp(), "another thinfilm command", setup=_images, hold=_lock("out")),
    Case("import/missing-image", imp(), "a135.png",
         setup=lambda c: (_images(c), os.unlink(c.p("imgs", "a135.png")))),
    Case("import/spectral-missing-cube", lambda c: ["import", "spectral", c.p("cube.hdr"), "--out", c.p("out")],
         "cube.hdr"),

    # --- fit-spectrum ------------------------------------------------------------------------------------
    Case("fit-spectrum/missing-file", fit(spectrum="none.txt"), "none.txt: spectrum file (two columns: wavelength in nm, value) not found"),
    Case("fit-spectrum/nan-value", fit(), "not a finite number",
         setup=lambda c: _spectrum(c, lambda wl: np.where(wl == 500, np.nan, 0.05))),
    Case("fit-spectrum/text-cell", fit(), "is not a number", setup=lambda c: c.write("s.txt", "400,0.1\n410,high\n")),
    Case("fit-spectrum/thickness-range-1e12", fit("--thickness-range", "0", "1e12"), "--thickness-range: MAX",
         setup=_spectrum),
    Case("fit-spectrum/film-index-1e-300", lambda c: ["fit-spectrum", c.p("s.txt"), "--film-ior", "1e-300",
                                                      "--substrate-ior", "1.52"], "--film-ior", setup=_spectrum),
    Case("fit-spectrum/cauchy-1e300", lambda c: ["fit-spectrum", c.p("s.txt"), "--film-ior", "cauchy:1e300,0",
                                                 "--substrate-ior", "1.52"], "Cauchy constants", setup=_spectrum),
    Case("fit-spectrum/angle-1e300", fit("--angle", "1e300"), "--angle", setup=_spectrum),

    # --- benchmark --------------------------------------------------------------------------------
    Case("benchmark/out-over-a-dataset", lambda c: ["benchmark", "--quick", "--out", c.ds],
         "holds the output of 'thinfilm generate'"),
    Case("benchmark/out-old-results-with-notes", lambda c: ["benchmark", "--quick", "--out", c.p("b")],
         "not a thinfilm output", setup=_dir_with("b", {"results.json": "{}", "notes.md": "mine"})),
    Case("benchmark/out-is-a-file", lambda c: ["benchmark", "--out", c.p("file")], "exists and is not a folder",
         setup=lambda c: c.write("file", "x")),
    Case("benchmark/out-root", lambda c: ["benchmark", "--out", "/"], "file-system root"),
    Case("benchmark/lock-held", lambda c: ["benchmark", "--quick", "--out", c.p("b")], "another thinfilm command",
         hold=_lock("b")),


    # --- bounded inputs: special files, long names, deep nesting, sizes, limits ---------------------
    Case("generate/spec-is-a-fifo", gen_spec("fifo.toml"), "fifo.toml: not a regular file", setup=_fifo("fifo.toml")),
    Case("render/scene-is-a-fifo", render(scene="fifo.toml"), "fifo.toml: not a regular file",
         setup=_fifo("fifo.toml")),
    Case("generate/camera-csv-is-a-fifo", gen("--set", "rig.camera=cam.csv"), "cam.csv",
         setup=_fifo("cam.csv")),
    Case("generate/spec-from-a-device", lambda c: ["generate", "/dev/zero", "--out", c.p("out")],
         "/dev/zero: not a regular file"),
    Case("fit-spectrum/spectrum-is-a-fifo", fit(spectrum="fifo.txt"), "fifo.txt: not a regular file",
         setup=_fifo("fifo.txt")),
    Case("fit-spectrum/background-is-a-fifo", fit("--background", "bg.txt"), "bg.txt: not a regular file",
         setup=lambda c: (_spectrum(c), _fifo("bg.txt")(c))),
    Case("reconstruct/mask-is-a-fifo", rec("rgb", "--mask", "m.npy"), "m.npy: not a regular file",
         setup=_fifo("m.npy")),
    Case("reconstruct/capture-is-a-fifo", rec(), "polarized_rgb.exr: not a regular file",
         setup=_fifo("ds/polarized_rgb.exr")),
    Case("evaluate/estimate-json-is-a-fifo", ev(), "estimate.json: not a regular file",
         setup=_fifo("est/estimate.json")),
    Case("import/image-is-a-fifo", imp(), "a090.png: not a regular file",
         setup=lambda c: (_images(c), _fifo("imgs/a090.png")(c))),
    Case("generate/spec-name-over-255", gen_spec("s" * 300 + ".toml"), "file name too long"),
    Case("generate/spec-path-over-4096", gen_spec("d/" * 2100 + "s.toml"), "path too long"),
    Case("reconstruct/dataset-name-over-255", rec(ds="d" * 300), "file name too long"),
    Case("generate/out-name-over-255", gen(out="o" * 300), "file name too long"),
    Case("fit-spectrum/path-over-4096", fit(spectrum="d/" * 2100 + "s.txt"), "path too long"),
    Case("generate/toml-nested-3000", gen_spec("deep.toml"), "deep.toml: not valid TOML (nested too deeply)",
         setup=lambda c: c.write("deep.toml", "x = " + "[" * 3000 + "]" * 3000 + "\n")),
    Case("generate/set-nested-5000", gen("--set", "shape.radius=" + "[" * 5000 + "]" * 5000),
         "--set shape.radius=[[[[", absent=("RecursionError",)),
    Case("generate/spec-with-bom-is-read", gen_spec("bom.toml"), "unknown key 'shape.colour'",
         setup=lambda c: c.write("bom.toml", b"\xef\xbb\xbf[shape]\nkind = 'hemisphere'\ncolour = 1\n")),
    Case("generate/mesh-nan-vertex", gen("--set", "shape.kind=mesh", "--set", "shape.path=nan.obj"),
         "nan.obj: mesh has non-finite vertex positions",
         setup=_mesh("nan.obj", BOX_OBJ.replace("v -0.5 -0.5 0.0", "v nan -0.5 0.0"))),
    Case("generate/mesh-too-many-faces", gen("--set", "shape.kind=mesh", "--set", "shape.path=box.obj"),
         "box.obj: the mesh has 12 faces, at most 10", patch=_few_faces),
    Case("generate/group-3000-parts", gen_spec("group.toml"), "'shape.parts' holds 3000 parts, at most",
         setup=lambda c: c.write("group.toml", _group_spec(3000))),
    Case("generate/stack-3000-layers", gen_spec("stack.toml"), "'film.layers' holds 3000 layers, at most 200",
         setup=lambda c: c.write("stack.toml", _stack_spec(3000))),
    Case("reconstruct/meta-wavelengths-empty", rec("spectral"), "'wavelengths_nm' is empty",
         setup=_json_edit("ds/meta.json", wavelengths_nm=[])),
    Case("reconstruct/meta-wavelengths-empty-rgb", rec(), "'wavelengths_nm' is empty",
         setup=_json_edit("ds/meta.json", wavelengths_nm=[])),
    Case("reconstruct/meta-fewer-wavelengths-than-bands", rec("spectral"),
         "meta.json: lists 3 wavelengths but stokes_spectral.exr holds 9 bands",
         setup=_json_edit("ds/meta.json", wavelengths_nm=[400.0, 440.0, 480.0])),
    Case("reconstruct/captures-3e38", rec(), "polarized_rgb.exr: channel 'pol000.R' holds 3e+38",
         setup=_exr_edit("ds/polarized_rgb.exr", lambda ch: _set(ch, [k for k in ch if k.startswith("pol")], 3e38))),
    Case("reconstruct/spectral-captures-3e38", rec("spectral"), "stokes_spectral.exr: channel 'S0.band000' holds 3e+38",
         setup=_exr_edit("ds/stokes_spectral.exr", lambda ch: _set(ch, [k for k in ch if k.startswith("S0.")], 3e38))),
    Case("fit-spectrum/over-the-size-limit", fit(), "s.txt: the spectrum file (two columns: wavelength in nm, value) is 17000000 bytes, at most",
         setup=lambda c: os.truncate(c.write("s.txt", ""), 17_000_000)),
    Case("fit-spectrum/over-the-line-limit", fit(), "s.txt: the spectrum file (two columns: wavelength in nm, value) has more than 100000 lines",
         setup=lambda c: c.write("s.txt", "".join(f"{400 + i * 1e-3:.3f},0.05\n" for i in range(100_001)))),
    Case("fit-spectrum/all-zero", fit(), "no variation", setup=lambda c: _spectrum(c, lambda wl: 0.0 * wl)),
    Case("fit-spectrum/constant", fit(), "no variation", setup=lambda c: _spectrum(c, lambda wl: 0 * wl + 0.05)),
    Case("fit-spectrum/values-1e308", fit(), "line 2: the value 1e+308 is beyond", setup=lambda c: _spectrum(
         c, lambda wl: np.where(wl == 410, 1e308, 0.04 + 0.02 * np.cos(wl / 30.0)))),
    Case("fit-spectrum/background-brighter-than-the-signal", fit("--background", "bg.txt"), "the background is brighter than spectrum",
         setup=lambda c: (_spectrum(c), c.write("bg.txt", "".join(f"{w},1.0\n" for w in range(390, 712, 10))))),
    Case("fit-spectrum/more-memory-than-the-machine", fit(), "GiB of memory, this machine has",
         setup=_spectrum, patch=lambda monkeypatch, c: monkeypatch.setattr(
             "thinfilm.fit_spectrum.physical_memory", lambda: 2**20)),
    Case("benchmark/scheduler-no-port", bench_at(lambda c: "tcp://localhost"), "--scheduler tcp://localhost: "),
    Case("benchmark/scheduler-unknown-scheme", bench_at(lambda c: "foo://x:1"), "--scheduler foo://x:1: "),
    Case("benchmark/scheduler-port-not-a-number", bench_at(lambda c: "tcp://127.0.0.1:http"), "--scheduler"),
    Case("benchmark/scheduler-file-not-json", bench_at(lambda c: c.p("sched.json")), "sched.json: not valid JSON",
         setup=lambda c: c.write("sched.json", "address = tcp://x:1\n")),
    Case("benchmark/scheduler-file-numeric-address", bench_at(lambda c: c.p("sched.json")),
         "sched.json: 'address' must be", setup=lambda c: c.write("sched.json", '{"address": 5}')),
    Case("benchmark/scheduler-speaks-http", bench_at(lambda c: c.peer), "not a Dask scheduler",
         hold=_serving(b"HTTP/1.1 400 Bad Request\r\nContent-Length: 0\r\n\r\n"), absent=("memory",)),
    Case("benchmark/scheduler-says-nothing", bench_at(lambda c: c.peer), "no answer", patch=_short_connect_timeout,
         hold=_serving(None)),
    Case("benchmark/scheduler-unreachable", bench_at(lambda c: c.peer), "cannot connect", setup=_closed_port,
         patch=_short_connect_timeout, absent=("memory",)),

    # --- methods and usage ------------------------------------------------------------------------
    Case("methods/extra-argument", lambda c: ["methods", "--jsn"], "unrecognized arguments"),
    Case("usage/unknown-command", lambda c: ["frobnicate"], "invalid choice"),
    Case("usage/generate-without-out", lambda c: ["generate", "hemisphere"], "--out"),
    Case("usage/reconstruct-without-kind", lambda c: ["reconstruct"], "required"),
]


# -- the runner ----------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def base(tmp_path_factory):
    return build_base(tmp_path_factory.mktemp("hostile_base"))


def test_the_corpus_is_large_and_covers_every_subcommand():
    ids = [c.id for c in CASES]
    assert len(ids) == len(set(ids)) and len(ids) >= 100
    commands = {i.split("/")[0] for i in ids}
    assert {"render", "generate", "reconstruct", "evaluate", "benchmark", "methods", "import",
            "fit-spectrum"} <= commands


@pytest.mark.parametrize("case", CASES, ids=[c.id for c in CASES])
def test_hostile_input(case, base, tmp_path, monkeypatch, capfd):
    if case.skip and case.skip():
        pytest.skip(case.skip())
    copy_base(base, tmp_path)
    monkeypatch.chdir(tmp_path)
    c = Ctx(tmp_path)
    with contextlib.ExitStack() as stack:
        if case.setup:
            case.setup(c)
        if case.hold:
            stack.enter_context(case.hold(c))
        if case.patch:
            case.patch(monkeypatch, c)
        argv = case.argv(c)
        before = snapshot(tmp_path)
        capfd.readouterr()
        code = run_cli(argv)
        out, err = capfd.readouterr()
        after = snapshot(tmp_path)
    lines = err.strip().splitlines()
    assert code == 2, (case.id, code, err)
    assert len(lines) == 1, (case.id, err)
    assert lines[0].startswith(("thinfilm: error:", "thinfilm generate: error:", "thinfilm render: error:",
                                "thinfilm reconstruct: error:", "thinfilm evaluate: error:",
                                "thinfilm benchmark: error:", "thinfilm methods: error:", "thinfilm refine: error:",
                                "thinfilm reconstruct rgb: error:", "thinfilm reconstruct spectral: error:",
                                "thinfilm import polarization: error:", "thinfilm fit-spectrum: error:")), err
    assert case.expect in lines[0], (case.id, lines[0])
    for word in case.absent:
        assert word not in lines[0], (case.id, lines[0])
    assert "Traceback" not in err and "unexpected failure" not in err, err
    assert out == "", out
    assert before == after, (case.id, diff(before, after))


# -- real processes: signals, two writers, start-up interrupts --------------------------------------

THINFILM = [sys.executable, "-m", "thinfilm.cli"]


def _spawn(args, cwd):
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    return subprocess.Popen([*THINFILM, *map(str, args)], cwd=cwd, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, env=env)


def _wait_for(predicate, proc, timeout=60.0):
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if predicate():
            return True
        if proc.poll() is not None:
            return False
        time.sleep(0.005)
    return False


def _temporaries(folder, name):
    return sorted(p.name for p in Path(folder).iterdir() if p.name.startswith(f".{name}."))


#: a generation long enough (about a second) to be caught in the middle
SLOW = ["generate", "hemisphere", "--resolution", "96", "--set", "noise.model=none"]


@pytest.mark.parametrize("sig, code, word", [(signal.SIGTERM, 143, "terminated"), (signal.SIGINT, 130, "interrupted"),
                                             (signal.SIGQUIT, 131, "terminated"), (signal.SIGHUP, 129, "terminated")])
def test_a_signal_while_writing_leaves_nothing(tmp_path, sig, code, word):
    (tmp_path / "keep.txt").write_text("mine")
    before = snapshot(tmp_path)
    proc = _spawn([*SLOW, "--out", tmp_path / "out"], tmp_path)
    assert _wait_for(lambda: any(".tmp-" in n for n in _temporaries(tmp_path, "out")), proc), proc.communicate()
    proc.send_signal(sig)
    out, err = proc.communicate(timeout=120)
    assert proc.returncode == code, err
    assert err.strip().splitlines() == [f"thinfilm: {word}"] and out == ""
    assert snapshot(tmp_path) == before, diff(before, snapshot(tmp_path))


def test_the_next_run_removes_what_a_killed_run_left(tmp_path, capfd):
    proc = _spawn([*SLOW, "--out", tmp_path / "out"], tmp_path)
    assert _wait_for(lambda: any(".tmp-" in n for n in _temporaries(tmp_path, "out")), proc), proc.communicate()
    proc.kill()
    proc.communicate(timeout=60)
    left = _temporaries(tmp_path, "out")
    assert any(".tmp-" in n for n in left) and ".out.lock" in left  # SIGKILL cannot be cleaned up after...
    (tmp_path / ".out.tmp-notours").mkdir()  # a name outside the pattern is never touched
    mine = tmp_path / f".out.tmp-{proc.pid}@{_host()}-abcdefgh"  # nor a folder named like ours, without our record
    (mine / "sub").mkdir(parents=True)
    (mine / "sub" / "notes.txt").write_text("mine")
    before = snapshot(mine)
    capfd.readouterr()
    assert run_cli(["generate", "hemisphere", *SMALL, "--out", tmp_path / "out"]) == 0, capfd.readouterr().err
    # ... the next run writing beside it removes it, and takes over and removes the dead process's lock.
    assert _temporaries(tmp_path, "out") == sorted([".out.tmp-notours", mine.name])
    assert snapshot(mine) == before
    assert (tmp_path / "out" / "meta.json").is_file()


def _host():
    from thinfilm.core import outputs

    return outputs.host_tag()


def _beside(root):
    """A decoy file and a decoy folder, and the snapshot to compare them with."""
    (root / "decoy.txt").write_text("a file of the user's")
    (root / "decoy").mkdir()
    (root / "decoy" / "inner.txt").write_text("a folder of the user's")
    return {k: v for k, v in snapshot(root).items() if k.startswith("decoy")}


def _decoys_of(root):
    return {k: v for k, v in snapshot(root).items() if k.startswith("decoy")}


def test_folders_and_files_named_like_stale_temporaries_are_never_removed(base, tmp_path, monkeypatch, capfd):
    monkeypatch.chdir(tmp_path)
    decoys = _beside(tmp_path)
    mine = [tmp_path / f".out.tmp-999999@{_host()}-abcdefgh", tmp_path / f".out.old-999999@{_host()}-abcdefgh",
            tmp_path / f".out.stage-999999@{_host()}-abcdefgh"]
    for folder in mine:
        (folder / "chapter").mkdir(parents=True)
        (folder / "chapter" / "1.tex").write_text("mine")
    (tmp_path / f".out.tmp-999999@{_host()}-abcdefgh.exr").write_text("a file of mine")
    (tmp_path / "out").mkdir()  # an empty folder: may be filled
    before = {k: v for k, v in snapshot(tmp_path).items() if k.startswith(".out.")}
    capfd.readouterr()
    assert run_cli(["generate", "hemisphere", *SMALL, "--out", "out"]) == 0, capfd.readouterr().err
    out, err = capfd.readouterr()
    assert err == "" and out.startswith("wrote")
    assert {k: v for k, v in snapshot(tmp_path).items() if k.startswith(".out.")} == before
    assert _decoys_of(tmp_path) == decoys and (tmp_path / "out" / "meta.json").is_file()


def test_an_old_output_that_cannot_be_removed_whole_is_kept_as_it_was(base, tmp_path, monkeypatch, capfd):
    """An immutable file in the old output (simulated: one file of it refuses to move, where a
    deletion would fail too): the old output stays whole, the new one is kept beside it and
    named in the one line, the exit code is 2."""
    from thinfilm.core import outputs

    monkeypatch.chdir(tmp_path)
    decoys = _beside(tmp_path)
    assert run_cli(["generate", "hemisphere", *SMALL, "--seed", "1", "--out", "out"]) == 0
    old = snapshot(tmp_path / "out")
    move = outputs.move_entry

    def immutable(src, dst):
        if os.path.basename(src) == "meta.json":
            raise PermissionError(errno.EPERM, os.strerror(errno.EPERM), src)
        move(src, dst)

    monkeypatch.setattr(outputs, "move_entry", immutable)
    capfd.readouterr()
    code = run_cli(["generate", "hemisphere", *SMALL, "--seed", "2", "--out", "out"])
    out, err = capfd.readouterr()
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 1 and out == "", err
    assert lines[0].startswith("thinfilm: error: --out ") and "cannot remove the old output" in lines[0]
    assert f"it is kept as it was, and the new output is at {tmp_path / 'out.new'}" in lines[0], lines[0]
    assert snapshot(tmp_path / "out") == old  # whole, byte for byte
    assert json.loads((tmp_path / "out.new" / "meta.json").read_text())["seed"] == 2
    assert sorted(p.name for p in tmp_path.iterdir()) == ["decoy", "decoy.txt", "out", "out.new"]
    assert _decoys_of(tmp_path) == decoys


def test_a_stale_lock_of_a_killed_process_is_taken_over(base, tmp_path, monkeypatch, capfd):
    monkeypatch.chdir(tmp_path)
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    (tmp_path / ".out.lock").write_text(f"thinfilm-lock/1 {dead.pid} {_host()}\n")
    capfd.readouterr()
    assert run_cli(["generate", "hemisphere", *SMALL, "--out", "out"]) == 0, capfd.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]


def test_two_writers_to_one_out_cannot_both_succeed(tmp_path, capfd):
    first = _spawn([*SLOW, "--out", tmp_path / "out"], tmp_path)
    try:
        assert _wait_for(lambda: any(".tmp-" in n for n in _temporaries(tmp_path, "out")), first)
        first.send_signal(signal.SIGSTOP)  # hold the first writer in the middle of its work
        capfd.readouterr()
        code = run_cli(["generate", "hemisphere", *SMALL, "--out", tmp_path / "out"])
        err = capfd.readouterr().err.strip().splitlines()
        assert code == 2 and len(err) == 1
        assert f"another thinfilm command (process {first.pid}) is writing it" in err[0]
    finally:
        first.send_signal(signal.SIGCONT)
    out, err = first.communicate(timeout=120)
    assert first.returncode == 0, err
    assert json.loads((tmp_path / "out" / "meta.json").read_text())["resolution"] == 96  # the first one's
    assert _temporaries(tmp_path, "out") == []


def _mapped(pid, name):
    try:
        return name in Path(f"/proc/{pid}/maps").read_text()
    except OSError:
        return False


@pytest.mark.skipif(not Path("/proc/self/maps").exists(), reason="needs /proc to see the start-up phase")
@pytest.mark.parametrize("library, delay", [("numpy", 0.0), ("drjit", 0.0), ("mitsuba", 0.1)])
def test_ctrl_c_during_start_up_is_one_line(tmp_path, library, delay):
    # Wait until the command is importing its libraries (numpy: the command's module; drjit,
    # mitsuba: choosing the Mitsuba variant, where an interrupt was once blamed on libLLVM).
    proc = _spawn(["generate", "hemisphere", *SMALL, "--out", tmp_path / "out"], tmp_path)
    assert _wait_for(lambda: _mapped(proc.pid, library), proc, timeout=30), proc.communicate()
    time.sleep(delay)
    proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=60)
    assert "Traceback" not in err and "libLLVM" not in err, err
    if proc.returncode == 0:  # it finished first: a success, nothing to clean
        return
    assert proc.returncode == 130, (proc.returncode, err)
    assert err.strip().splitlines() == ["thinfilm: interrupted"], (proc.returncode, err)
    assert sorted(p.name for p in tmp_path.iterdir()) == []


def _can_mount_tmpfs(path) -> bool:
    if os.geteuid() != 0 or not sys.platform.startswith("linux"):
        return False
    run = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=96k", "tmpfs", str(path)], capture_output=True)
    return run.returncode == 0


def test_a_really_full_disk_is_one_line_naming_out(tmp_path):
    small = tmp_path / "small"
    small.mkdir()
    if not _can_mount_tmpfs(small):
        pytest.skip("needs root and tmpfs to fill a real disk (the table's full-disk case simulates one)")
    try:
        (small / "keep.txt").write_text("mine")
        before = snapshot(small)
        run = subprocess.run([*THINFILM, "generate", "hemisphere", "--resolution", "32", "--set", "noise.model=none",
                              "--out", str(small / "ds")], capture_output=True, text=True, cwd=tmp_path)
        err = run.stderr.strip().splitlines()
        assert run.returncode == 2 and len(err) == 1, run.stderr
        assert "--out" in err[0] and "No space left on device" in err[0] and "Traceback" not in run.stderr
        assert snapshot(small) == before
    finally:
        subprocess.run(["umount", str(small)], check=False)


# -- outputs that succeed: normal permissions, no stray lines ---------------------------------------

def test_outputs_get_normal_permissions_and_successes_print_only_what_they_wrote(base, tmp_path, monkeypatch,
                                                                                   capfd):
    copy_base(base, tmp_path)
    monkeypatch.chdir(tmp_path)
    old = os.umask(0o022)
    try:
        capfd.readouterr()
        assert run_cli(["reconstruct", "rgb", "ds", "--out", "rec"]) == 0
        assert run_cli(["evaluate", "ds", "est", "--out", "ev"]) == 0
        assert run_cli(["render", "scene.toml", "--variant", "llvm_ad_spectral_polarized", "--out", "img"]) == 0
        out, err = capfd.readouterr()
    finally:
        os.umask(old)
    assert err == "", err  # no library warning leaks (ComplexWarning, RuntimeWarning, Mitsuba's log)
    assert [line.split()[0] for line in out.strip().splitlines()] == ["wrote"] * 3, out
    for folder in ("rec", "ev"):
        assert (tmp_path / folder).stat().st_mode & 0o777 == 0o755
        assert all(p.stat().st_mode & 0o777 == 0o644 for p in (tmp_path / folder).iterdir())
    assert (tmp_path / "img.exr").stat().st_mode & 0o777 == 0o644
    # render again: refused without --overwrite, replaced with it
    assert run_cli(["render", "scene.toml", "--variant", "llvm_ad_spectral_polarized", "--out", "img"]) == 2
    assert run_cli(["render", "scene.toml", "--variant", "llvm_ad_spectral_polarized", "--out", "img",
                    "--overwrite"]) == 0
    assert sorted(p.name for p in tmp_path.iterdir() if p.name.startswith(".")) == []


def test_a_dictionary_scene_without_integrator_renders_with_mitsubas_default(base, tmp_path, monkeypatch, capfd):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "s.toml").write_text(RENDER_SCENE.replace("THICKNESS", "300.0").split("[integrator]")[0]
                                     + "[sensor]" + RENDER_SCENE.split("[sensor]")[1].replace("THICKNESS", "300"))
    capfd.readouterr()
    assert run_cli(["render", "s.toml", "--variant", "llvm_ad_spectral_polarized", "--out", "img"]) == 0
    out, err = capfd.readouterr()
    assert err == "" and out.startswith("wrote") and (tmp_path / "img.exr").is_file()
