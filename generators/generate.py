"""``thinfilm generate``: a benchmark dataset (format ``thinfilm-dataset/1``) from a scene spec.

Pipeline: :class:`~.spec.SceneSpec` → Mitsuba scene (:mod:`.scene`) → ground truth by ray
casting the pixel-centre rays (:mod:`.ground_truth`) → band-integrated Stokes cube
(:func:`.render.render_stokes_cube`) → captures (:mod:`.captures`) → camera noise
(:mod:`.noise`) → with ``rig.sensor = "dofp-rgb"`` the raw image of a colour polarization
sensor (:mod:`.sensor`) → files (:func:`thinfilm.core.io.write_dataset`, ``raw.tiff``),
written atomically.

The result is a pure function of the spec (seed included): same spec, same bytes.
"""

from __future__ import annotations

import sys
import time

import numpy as np

__all__ = ["simulate", "dataset_meta_of", "write_simulation", "generate_dataset", "cli_main"]


def simulate(spec, progress: bool = False) -> dict:
    """Render a :class:`~.spec.SceneSpec`: ground truth, exact Stokes cube and the (noisy)
    captures. The caller sets the render variant
    (:func:`thinfilm.core.variants.use_variant`).

    Returns
    -------
    dict
        ``ground_truth`` (see :func:`.ground_truth.cast_ground_truth`), ``frame``,
        ``wavelengths_nm``, ``stokes_exact`` (S0/S1/S2 (H, W, B)), ``stokes`` and
        ``spectral_s`` (measured), ``polarized_rgb`` {angle: (H, W, 3)}, ``timings_s``; with
        ``rig.sensor = "dofp-rgb"`` also ``raw`` ((H, W) uint16) and ``sensor`` (its
        ``meta.json`` entry, :func:`.sensor.dofp_raw`).
    """
    import mitsuba as mi

    from thinfilm.core.conventions import s_polarized

    from .captures import captures_from_stokes, hyperspectral_capture
    from .ground_truth import cast_ground_truth
    from .noise import apply_camera_noise
    from .render import render_stokes_cube
    from .scene import build_scene_dict

    t0 = time.perf_counter()
    scene_dict, frame, thickness = build_scene_dict(spec)
    scene = mi.load_dict(scene_dict)
    gt = cast_ground_truth(scene, thickness, frame)
    rig, noise = spec.rig, spec.noise.as_dict()
    wl = rig.wavelengths
    t1 = time.perf_counter()
    stokes = render_stokes_cube(scene, wl, rig.band_fwhm_nm, rig.passband, progress=progress)
    stokes.pop("mask")
    t2 = time.perf_counter()

    mask = gt["mask"]
    angles = [int(a) for a in rig.polarizer_angles_deg]
    # One generator per image stack (RGB, then each angle of the hyperspectral camera, then
    # the raw sensor), spawned in a fixed order: reproducible whatever order the stacks are
    # processed in. Child i of a SeedSequence depends on i only, so the raw sensor's stream
    # leaves the others as they were.
    rngs = [np.random.default_rng(s) for s in np.random.SeedSequence(spec.seed).spawn(2 + len(angles))]
    rgb_exact, spectral_exact = captures_from_stokes(stokes, wl, angles, rig.camera, rig.illuminant)
    rgb_stack = np.stack([rgb_exact[int(a) % 360] for a in angles])
    rgb_noisy = apply_camera_noise(rgb_stack, mask, noise, rngs[0])
    polarized_rgb = {int(a) % 360: rgb_noisy[i] for i, a in enumerate(angles)}
    if noise["model"] == "none":
        measured, spectral_s = stokes, spectral_exact
    else:
        measured = hyperspectral_capture(stokes, angles, mask, noise, rngs[1:1 + len(angles)])
        spectral_s = s_polarized(measured["S0"], measured["S1"], measured["S2"])
    out = {"ground_truth": gt, "frame": frame, "wavelengths_nm": wl, "stokes_exact": stokes,
           "stokes": measured, "spectral_s": spectral_s, "polarized_rgb": polarized_rgb}
    if rig.sensor == "dofp-rgb":
        from .sensor import dofp_raw

        out["raw"], out["sensor"] = dofp_raw(stokes, wl, rig.camera, rig.illuminant, mask, noise, rngs[-1])
    t3 = time.perf_counter()
    out["timings_s"] = {"scene": t1 - t0, "render": t2 - t1, "captures": t3 - t2}
    return out


def dataset_meta_of(spec, sim: dict) -> dict:
    """``meta.json`` of a simulated spec."""
    from thinfilm.core.io import dataset_meta

    from .render import passband_quadrature

    rig = spec.rig
    sub, _ = passband_quadrature(sim["wavelengths_nm"], rig.band_fwhm_nm, rig.passband)
    return dataset_meta(
        wavelengths_nm=[float(v) for v in sim["wavelengths_nm"]],
        band_fwhm_nm=rig.band_fwhm_nm,
        passband=rig.passband,
        sub_wavelengths_rendered=int(sub.size),
        polarizer_angles_deg=[int(a) for a in rig.polarizer_angles_deg],
        camera=rig.camera,
        illuminant=rig.illuminant,
        dome_hole_deg=rig.dome_hole_deg,
        **spec.film.to_meta(),
        shape=spec.shape.kind,
        thickness_profile=spec.thickness["profile"],
        resolution=rig.resolution,
        projection=sim["frame"].as_dict(),
        seed=spec.seed,
        noise=spec.noise.as_dict(),
        stokes_spectral="measured like spectral_s (noisy unless noise model is 'none')",
        source="generated",
        **({"sensor": sim["sensor"]} if "sensor" in sim else {}),
    )


def write_simulation(sim: dict, spec, folder) -> None:
    """Write every file of format ``thinfilm-dataset/1`` into ``folder`` (which exists)."""
    from pathlib import Path

    from thinfilm.core.io import write_dataset

    write_dataset(folder, dataset_meta_of(spec, sim), ground_truth=sim["ground_truth"],
                  polarized_rgb=sim["polarized_rgb"], spectral_s=sim["spectral_s"], stokes=sim["stokes"],
                  scene_toml=spec.to_toml())
    if "raw" in sim:
        from .sensor import write_raw_tiff

        info = sim["sensor"]
        write_raw_tiff(Path(folder) / info["file"], sim["raw"],
                       f"thinfilm dofp-rgb raw; pattern {info['pattern']}; {info['bits']}-bit values")


def generate_dataset(spec, out_dir, progress: bool = True) -> dict:
    """Generate a dataset folder from a :class:`~.spec.SceneSpec`.

    The Mitsuba variant must be :data:`thinfilm.core.variants.RENDER_VARIANT` (set by the
    caller). The folder is written atomically (:func:`thinfilm.core.outputs.atomic_output_dir`).

    Returns
    -------
    dict
        Timings in seconds (``scene``, ``render``, ``captures``, ``write``).
    """
    from thinfilm.core.outputs import atomic_output_dir, check_output_dir

    out = check_output_dir(out_dir, markers=("meta.json",))  # before the work, not after
    sim = simulate(spec, progress=progress)
    timings = dict(sim["timings_s"])
    t = time.perf_counter()
    with atomic_output_dir(out, markers=("meta.json",)) as tmp:
        write_simulation(sim, spec, tmp)
    timings["write"] = time.perf_counter() - t
    return timings


def cli_main(args) -> int:
    """``thinfilm generate SPEC.toml|PRESET --out DIR [--set k=v ...] [--resolution N] [--seed S]``."""
    from thinfilm.core.outputs import check_output_dir
    from thinfilm.core.variants import use_variant

    from .spec import load_spec

    spec = load_spec(args.spec, overrides=list(args.overrides or ()), resolution=args.resolution,
                     seed=args.seed)
    out = check_output_dir(args.out, markers=("meta.json",))
    use_variant()
    t = generate_dataset(spec, out, progress=sys.stderr.isatty())
    raw = ", raw.tiff of a colour polarization sensor" if spec.rig.sensor == "dofp-rgb" else ""
    print(f"wrote {out} ({spec.rig.resolution}x{spec.rig.resolution}, "
          f"{len(spec.rig.polarizer_angles_deg)} polarizer angles{raw}; {sum(t.values()):.1f} s)")
    return 0
