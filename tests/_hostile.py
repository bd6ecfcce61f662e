"""Helpers of the hostile-input corpus (``tests/test_hostile.py``): the small inputs every
case starts from, snapshots of a folder tree, and running the command line in-process.

A case gets a :class:`Ctx` whose root holds a copy of a tiny generated dataset (``ds/``),
an estimate of it (``est/``), a small render scene (``scene.toml``) and a closed mesh
(``box.obj``); it may add or damage files, then runs one command. The runner snapshots the
whole root (bytes and mode of every file, mode of every folder, target of every link)
before and after.
"""

from __future__ import annotations

import os
import shutil
import stat
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

RENDER_SCENE = """
type = "scene"
[integrator]
type = "stokes"
nested = { type = "path", max_depth = 2, hide_emitters = true }
[sensor]
type = "orthographic"
to_world = { look_at = { origin = [0, 0, 5], target = [0, 0, 0], up = [0, 1, 0] } }
film = { type = "hdrfilm", width = 8, height = 8, rfilter = { type = "box" } }
sampler = { type = "stratified", sample_count = 1, jitter = false }
[emitter]
type = "constant"
[ball]
type = "sphere"
bsdf = { type = "thinfilm", thickness = THICKNESS, film_ior = 1.37, substrate_ior = 1.6 }
"""

BOX_OBJ = "\n".join(
    [f"v {x} {y} {z}" for x in (-0.5, 0.5) for y in (-0.5, 0.5) for z in (0.0, 1.0)]
    + ["f 1 3 4", "f 1 4 2", "f 5 6 8", "f 5 8 7", "f 1 2 6", "f 1 6 5",
       "f 3 7 8", "f 3 8 4", "f 1 5 7", "f 1 7 3", "f 2 4 8", "f 2 8 6"]) + "\n"

#: overrides that keep a generated dataset tiny and quick
SMALL = ["--resolution", "8", "--set", "rig.wavelengths_nm.step=40", "--set", "noise.model=none"]


def build_base(root: Path) -> Path:
    """The inputs every case starts from, made once per module: a dataset generated at 8x8
    with 9 bands (``ds/``), the ground truth written as an estimate (``est/``), a render
    scene and a mesh."""
    from thinfilm.core.io import Estimate, read_dataset, write_estimate
    from thinfilm.core.outputs import atomic_output_dir
    from thinfilm.core.variants import use_variant
    from thinfilm.generators.generate import generate_dataset
    from thinfilm.generators.spec import load_spec

    import mitsuba as mi

    previous = mi.variant()
    use_variant()
    try:
        spec = load_spec("hemisphere", overrides=["rig.wavelengths_nm.step=40", "noise.model=none"],
                         resolution=8)
        generate_dataset(spec, root / "ds", progress=False)
    finally:
        if previous:
            mi.set_variant(previous)
    ds = read_dataset(root / "ds", need=("ground_truth",))
    gt = ds.ground_truth
    est = Estimate(gt["normal"], gt["thickness"], gt["mask"], ds.meta["film_ior"], ds.meta["substrate_ior"],
                   info={"method": "ground_truth", "timings_s": {}})
    with atomic_output_dir(root / "est", command="reconstruct", inputs=[root / "ds"]) as tmp:
        write_estimate(tmp, est)
    (root / "scene.toml").write_text(RENDER_SCENE.replace("THICKNESS", "300.0"))
    (root / "box.obj").write_text(BOX_OBJ)
    return root


@dataclass
class Ctx:
    """Paths of one case's root (the current folder while the command runs)."""

    root: Path

    def p(self, *parts) -> str:
        return str(self.root.joinpath(*parts))

    @property
    def ds(self) -> str:
        return self.p("ds")

    @property
    def est(self) -> str:
        return self.p("est")

    @property
    def scene(self) -> str:
        return self.p("scene.toml")

    def write(self, rel, data) -> Path:
        path = self.root / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        if isinstance(data, bytes):
            path.write_bytes(data)
        else:
            path.write_text(data)
        return path

    def npy(self, rel, array) -> Path:
        path = self.root / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        np.save(path, array, allow_pickle=True)
        return path


@dataclass
class Case:
    """One hostile input: the command line (``argv(ctx)``), what to prepare (``setup(ctx)``,
    optional), and a fragment the one error line must hold. ``hold(ctx)``: a context
    manager kept open while the command runs (a lock held by another writer).
    ``patch(monkeypatch, ctx)``: simulate the machine (a full disk). ``absent``: fragments
    the line must not hold. ``skip()``: a reason to skip on this machine, or None."""

    id: str
    argv: Callable
    expect: str
    setup: Callable | None = None
    hold: Callable | None = None
    patch: Callable | None = None
    absent: tuple = ()
    skip: Callable | None = None
    tags: tuple = field(default_factory=tuple)


def copy_base(base: Path, root: Path) -> None:
    for item in base.iterdir():
        if item.is_dir():
            shutil.copytree(item, root / item.name, symlinks=True)
        else:
            shutil.copy2(item, root / item.name)


def snapshot(root: Path) -> dict:
    """Every file, folder and link below ``root`` (and ``root`` itself): kind, mode, bytes or
    link target."""
    root = Path(root)
    out = {".": ("dir", stat.S_IMODE(os.lstat(root).st_mode))}
    for dirpath, dirnames, filenames in os.walk(root, followlinks=False):
        for name in dirnames + filenames:
            p = Path(dirpath) / name
            st = os.lstat(p)
            rel = p.relative_to(root).as_posix()
            if stat.S_ISLNK(st.st_mode):
                out[rel] = ("link", os.readlink(p))
            elif stat.S_ISDIR(st.st_mode):
                out[rel] = ("dir", stat.S_IMODE(st.st_mode))
            elif not stat.S_ISREG(st.st_mode):  # a FIFO: never opened
                out[rel] = ("special", stat.S_IFMT(st.st_mode), stat.S_IMODE(st.st_mode), st.st_ino)
            else:
                out[rel] = ("file", stat.S_IMODE(st.st_mode), p.read_bytes())
    return out


def diff(before: dict, after: dict) -> str:
    added = sorted(set(after) - set(before))
    removed = sorted(set(before) - set(after))
    changed = sorted(k for k in set(before) & set(after) if before[k] != after[k])
    return f"added {added[:5]}, removed {removed[:5]}, changed {changed[:5]}"


def run_cli(argv) -> int:
    """``thinfilm.cli.main`` in-process; usage errors (SystemExit) give their code."""
    from thinfilm.cli import main

    try:
        return main([str(a) for a in argv])
    except SystemExit as e:
        return e.code


def has_gpu() -> bool:
    return shutil.which("nvidia-smi") is not None or Path("/dev/nvidia0").exists()
