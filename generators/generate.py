"""``thinfilm generate``: a benchmark dataset (format ``thinfilm-dataset/1``) from a scene spec.

Pipeline: :class:`~.spec.SceneSpec` → Mitsuba scene (:mod:`.scene`) → ground truth by ray
casting the pixel-centre rays (:mod:`.ground_truth`) → band-integrated Stokes cube
(:func:`.render.render_stokes_cube`) → captures (:mod:`.captures`) → camera noise
(:mod:`.noise`) → with ``rig.sensor = "dofp-rgb"`` the raw image of a colour polarization
sensor (:mod:`.sensor`) → files (:func:`thinfilm.core.io.write_dataset`, ``raw.tiff``),
written atomically.

The result is a pure function of the spec (seed included): same spec, same bytes.

Rough films
-----------
A film with ``film.roughness`` (alpha) > 0 is rendered with :func:`rough_spp` samples per
pixel, all on the pixel-centre ray (only the BSDF samples vary; see
:mod:`thinfilm.generators.render`), so the ground truth, cast along the same rays, is the
macro surface's (normal, thickness and depth of the surface the microfacets sit on). The
sampler seeds are drawn from the spec's seed, apart from the camera-noise streams: same
spec, same bytes, rough or not. ``meta.json`` gains ``film_roughness`` and ``spp``; smooth
datasets are unchanged (one exact ray per pixel, no new keys).
"""

from __future__ import annotations

import math
import sys
import time

import numpy as np

__all__ = ["ROUGH_SPP", "simulate", "rough_spp", "dataset_meta_of", "write_simulation", "spec_input_files",
           "generate_dataset", "cli_main"]

#: samples per pixel of a rough film for the default camera (full well 10000 e-, 90 % of it
#: at the brightest pixel): the sampling noise of a band image is then below the camera's
#: (root mean square ratio of their standard deviations 0.23-0.48 on the hemisphere,
#: 0.28-0.56 on the cylinder, 0.34-0.75 on the pyramid, whose flat faces are all at full
#: exposure, for alpha 0.02-0.3; 256 samples: 0.11-0.32;
#: ``benchmarks/bench_rough_generate.py``)
ROUGH_SPP = 64


def rough_spp(spec) -> int:
    """Samples per pixel for a :class:`~.spec.SceneSpec`: 1 for a smooth film; ``rig.spp``
    when it is a number; else (``"auto"``) :data:`ROUGH_SPP` for a camera whose full well is
    at most the default 10000 e-, and for a deeper well, whose shot noise is relatively
    smaller by sqrt(full_well / 10000), the power of 4 at or above
    ``ROUGH_SPP * sqrt(full_well / 10000)`` (the sampler's stratified blocks make the
    sampling noise fall about as 1/spp). Noise model ``none`` has no camera noise to stay
    under; it gets the default camera's count.

    Examples
    --------
    >>> from thinfilm.generators.spec import load_spec
    >>> rough_spp(load_spec("hemisphere")), rough_spp(load_spec("hemisphere", ["film.roughness=0.1"]))
    (1, 64)
    >>> rough_spp(load_spec("hemisphere", ["film.roughness=0.1", "noise.full_well=40000"]))
    256
    >>> rough_spp(load_spec("hemisphere", ["film.roughness=0.1", "rig.spp=16"]))
    16
    """
    if not spec.roughness:
        return 1
    if spec.rig.spp != "auto":
        return int(spec.rig.spp)
    noise = spec.noise
    if noise.model == "none" or noise.full_well <= 10000.0:
        return ROUGH_SPP
    wanted = ROUGH_SPP * math.sqrt(noise.full_well / 10000.0)
    return int(min(4 ** math.ceil(math.log(wanted, 4) - 1e-9), 4096))


def simulate(spec, progress: bool = False) -> dict:
    """Render a :class:`~.spec.SceneSpec`: ground truth, exact Stokes cube and the (noisy)
    captures. The caller sets the render variant
    (:func:`thinfilm.core.variants.use_variant`).

    Returns
    -------
    dict
        ``ground_truth`` (see :func:`.ground_truth.cast_ground_truth`), ``frame``,
        ``wavelengths_nm``, ``stokes_exact`` (S0/S1/S2 (H, W, B); noise free, but for a rough
        film with the sampling noise of its ``spp`` samples), ``stokes`` and ``spectral_s``
        (measured), ``polarized_rgb`` {angle: (H, W, 3)}, ``spp`` (samples per pixel
        rendered), ``timings_s``; with ``rig.sensor = "dofp-rgb"`` also ``raw`` ((H, W) uint16)
        and ``sensor`` (its ``meta.json`` entry, :func:`.sensor.dofp_raw`).
    """
    import mitsuba as mi

    from thinfilm.core.conventions import s_polarized

    from thinfilm.core.model import captures_from_stokes

    from .captures import hyperspectral_capture
    from .ground_truth import cast_ground_truth
    from .noise import apply_camera_noise
    from .render import render_stokes_cube, sample_blocks
    from .scene import build_scene_dict, rough_integrator

    t0 = time.perf_counter()
    scene_dict, frame, thickness = build_scene_dict(spec)
    scene = mi.load_dict(scene_dict)
    gt = cast_ground_truth(scene, thickness, frame)
    rig, noise = spec.rig, spec.noise.as_dict()
    if not gt["mask"].any():
        from thinfilm.core.errors import UserError

        raise UserError(f"{spec.source}: the {spec.shape.kind} covers no pixel that faces the camera at "
                        f"rig.resolution {rig.resolution} (seen edge-on, from behind, or degenerate); "
                        f"there is nothing to capture")
    wl = rig.wavelengths
    t1 = time.perf_counter()
    spp = rough_spp(spec)
    if spp == 1:
        stokes = render_stokes_cube(scene, wl, rig.band_fwhm_nm, rig.passband, progress=progress)
    else:
        stokes = render_stokes_cube(scene, wl, rig.band_fwhm_nm, rig.passband, progress=progress,
                                    spp=spp, seed=spec.seed, integrator=rough_integrator(spec))
        block, passes = sample_blocks(spp)
        spp = block * passes
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
           "stokes": measured, "spectral_s": spectral_s, "polarized_rgb": polarized_rgb, "spp": spp}
    if rig.sensor == "dofp-rgb":
        from .sensor import dofp_raw

        out["raw"], out["sensor"] = dofp_raw(stokes, wl, rig.camera, rig.illuminant, mask, noise, rngs[-1])
    t3 = time.perf_counter()
    out["timings_s"] = {"scene": t1 - t0, "render": t2 - t1, "captures": t3 - t2}
    return out


def dataset_meta_of(spec, sim: dict) -> dict:
    """``meta.json`` of a simulated spec."""
    from thinfilm.core.io import dataset_meta

    from thinfilm.core.bands import passband_quadrature

    rig = spec.rig
    sub, _ = passband_quadrature(sim["wavelengths_nm"], rig.band_fwhm_nm, rig.passband)
    # Only rough films get the keys of rough rendering: smooth datasets stay as they were.
    rough = {"film_roughness": spec.roughness, "spp": int(sim["spp"])} if spec.roughness else {}
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
        **rough,
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


def spec_input_files(spec) -> list:
    """The files a :class:`~.spec.SceneSpec` reads (mesh, thickness bitmap, camera and
    illuminant CSVs): an output may not overwrite them."""
    out = [spec.shape.params.get("path"), spec.thickness.get("path")]
    out += [v for v in (spec.rig.camera, spec.rig.illuminant) if str(v).lower().endswith(".csv")]
    return [p for p in out if p]


def generate_dataset(spec, out_dir, progress: bool = True, inputs=()) -> dict:
    """Generate a dataset folder from a :class:`~.spec.SceneSpec`.

    The Mitsuba variant must be :data:`thinfilm.core.variants.RENDER_VARIANT` (set by the
    caller). The folder is written atomically and under its lock
    (:func:`thinfilm.core.outputs.atomic_output_dir`); ``inputs`` are more files the output
    may not replace (the spec file), besides those the spec names.

    Returns
    -------
    dict
        Timings in seconds (``scene``, ``render``, ``captures``, ``write``).
    """
    from thinfilm.core.outputs import atomic_output_dir

    if spec.rig.sensor == "dofp-rgb":  # before any rendering: raw.tiff is written with tifffile
        from .sensor import RAW_WRITER_EXTRA
        from thinfilm.core.extras import require_extra

        require_extra("tifffile", RAW_WRITER_EXTRA, what='rig.sensor = "dofp-rgb" (raw.tiff)')
    with atomic_output_dir(out_dir, command="generate", inputs=[*spec_input_files(spec), *inputs]) as tmp:
        sim = simulate(spec, progress=progress)
        timings = dict(sim["timings_s"])
        t = time.perf_counter()
        write_simulation(sim, spec, tmp)
        timings["write"] = time.perf_counter() - t
    return timings


def cli_main(args) -> int:
    """``thinfilm generate SPEC.toml|PRESET --out DIR [--set k=v ...] [--resolution N] [--seed S]``."""
    from pathlib import Path

    from thinfilm.core.outputs import check_output_dir
    from thinfilm.core.variants import use_variant

    from .spec import load_spec

    spec = load_spec(args.spec, overrides=list(args.overrides or ()), resolution=args.resolution,
                     seed=args.seed)
    spec_file = Path(args.spec).expanduser()
    inputs = [spec_file] if spec_file.is_file() else []
    out = check_output_dir(args.out, command="generate", inputs=[*spec_input_files(spec), *inputs])
    use_variant()
    t = generate_dataset(spec, out, progress=sys.stderr.isatty(), inputs=inputs)
    raw = ", raw.tiff of a colour polarization sensor" if spec.rig.sensor == "dofp-rgb" else ""
    rough = ""
    if spec.roughness:
        from .render import sample_blocks

        block, passes = sample_blocks(rough_spp(spec))
        rough = f", rough film alpha {spec.roughness:g} at {block * passes} samples per pixel"
    print(f"wrote {out} ({spec.rig.resolution}x{spec.rig.resolution}, "
          f"{len(spec.rig.polarizer_angles_deg)} polarizer angles{raw}{rough}; {sum(t.values()):.1f} s)")
    return 0
