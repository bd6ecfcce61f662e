"""``thinfilm generate``: a benchmark dataset (format ``thinfilm-dataset/1``) from a scene spec.

Pipeline: resolved spec → Mitsuba scene (:mod:`.scene`) → ground truth by ray casting the
pixel-centre rays → band-integrated Stokes cube (:func:`.render.render_stokes_cube`) →
captures → camera noise (:mod:`.noise`) → files, written atomically.

Captures
--------
``polarized_rgb``
    The polarization RGB camera: for each polarizer angle α the camera RGB
    (:mod:`thinfilm.colorimetry`) of I(α) = ½ (S0 + S1 cos 2α + S2 sin 2α), then noise per
    image.
``spectral_s``, ``stokes_spectral``
    The hyperspectral camera with a rotating polarizer: for each band and each polarizer
    angle of the rig an image I(α), each with its own exposure and noise; the Stokes
    components are the least-squares fit to those images (for 0/45/90/135:
    S0 = ½ ΣI, S1 = I0 − I90, S2 = I45 − I135) and ``spectral_s`` = S0 + sqrt(S1² + S2²).
    With noise ``none`` both are exact.

The result is a pure function of the resolved spec (seed included): same spec, same bytes.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

from thinfilm.errors import UserError

__all__ = ["VARIANT", "set_variant", "simulate", "polarized_rgb_channels", "band_channels", "generate_dataset",
           "write_dataset", "cli_main"]

VARIANT = "llvm_ad_mono_polarized"


def set_variant() -> None:
    """Select the Mitsuba variant the generator renders in (entry points only)."""
    import mitsuba as mi

    try:
        mi.set_variant(VARIANT)
    except Exception as e:  # variant missing or LLVM not found
        raise UserError(f"Mitsuba variant {VARIANT} is not available ({e}); install libLLVM "
                        f"or set DRJIT_LIBLLVM_PATH") from None


def simulate(spec: dict, progress: bool = False) -> dict:
    """Render a resolved spec: ground truth, exact Stokes cube and the (noisy) captures.

    Returns
    -------
    dict
        ``ground_truth`` (see :func:`.scene.cast_ground_truth`), ``frame``,
        ``wavelengths_nm``, ``stokes_exact`` (S0/S1/S2 (H, W, B)), ``stokes`` and
        ``spectral_s`` (measured), ``polarized_rgb`` {angle: (H, W, 3)}, ``timings_s``.
    """
    import mitsuba as mi

    from thinfilm.reconstruction.polarization import malus_intensity, stokes_design_matrix

    from .noise import apply_camera_noise
    from .render import captures_from_stokes, render_stokes_cube, spectral_s_from_stokes
    from .scene import build_scene_dict, cast_ground_truth
    from .spec import wavelength_grid

    t0 = time.perf_counter()
    scene_dict, frame, thickness = build_scene_dict(spec)
    scene = mi.load_dict(scene_dict)
    gt = cast_ground_truth(scene, thickness, frame)
    rig, noise = spec["rig"], spec["noise"]
    wl = wavelength_grid(rig)
    t1 = time.perf_counter()
    stokes = render_stokes_cube(scene, wl, rig["band_fwhm_nm"], rig["passband"], progress=progress)
    stokes.pop("mask")
    t2 = time.perf_counter()

    mask = gt["mask"]
    angles = [int(a) for a in rig["polarizer_angles_deg"]]
    # One generator per image stack (RGB, then each angle of the hyperspectral camera),
    # spawned in a fixed order: reproducible whatever order the stacks are processed in.
    rngs = [np.random.default_rng(s) for s in np.random.SeedSequence(spec["seed"]).spawn(1 + len(angles))]
    rgb_exact, spectral_exact = captures_from_stokes(stokes, wl, rig)
    rgb_stack = np.stack([rgb_exact[int(a) % 360] for a in angles])
    rgb_noisy = apply_camera_noise(rgb_stack, mask, noise, rngs[0])
    polarized_rgb = {int(a) % 360: rgb_noisy[i] for i, a in enumerate(angles)}

    if noise["model"] == "none":
        measured, spectral_s = stokes, spectral_exact
    else:
        # Hyperspectral camera behind a rotating polarizer: one noisy image per band and angle.
        from concurrent.futures import ThreadPoolExecutor

        def shoot(i):
            image = malus_intensity(stokes["S0"], stokes["S1"], stokes["S2"], [angles[i]])[0]
            frames = np.moveaxis(image, -1, 0)  # (B, H, W) view
            return np.moveaxis(apply_camera_noise(frames, mask, noise, rngs[1 + i]), 0, -1)

        # The least-squares Stokes fit (reconstruction.polarization.fit_stokes), accumulated
        # one angle at a time so that only one noisy stack is held at once.
        fit = np.linalg.pinv(stokes_design_matrix(angles))  # (3, A)
        acc = np.zeros((3,) + stokes["S0"].shape)
        with ThreadPoolExecutor(max_workers=2) as pool:  # NumPy's generators release the GIL
            for i, noisy in enumerate(pool.map(shoot, range(len(angles)))):
                for s in range(3):
                    acc[s] += fit[s, i] * noisy
        measured = {"S0": acc[0], "S1": acc[1], "S2": acc[2]}
        spectral_s = spectral_s_from_stokes(measured)
    t3 = time.perf_counter()
    return {"ground_truth": gt, "frame": frame, "wavelengths_nm": wl, "stokes_exact": stokes,
            "stokes": measured, "spectral_s": spectral_s, "polarized_rgb": polarized_rgb,
            "timings_s": {"scene": t1 - t0, "render": t2 - t1, "captures": t3 - t2}}


def _versions() -> dict:
    import drjit
    import mitsuba

    import thinfilm

    return {"thinfilm": thinfilm.__version__, "mitsuba": mitsuba.__version__,
            "drjit": drjit.__version__, "numpy": np.__version__}


def _meta(spec: dict, sim: dict) -> dict:
    from thinfilm.dataset import FORMAT

    from .render import passband_quadrature

    rig = spec["rig"]
    sub, _ = passband_quadrature(sim["wavelengths_nm"], rig["band_fwhm_nm"], rig["passband"])
    return {
        "format": FORMAT,
        "wavelengths_nm": [float(v) for v in sim["wavelengths_nm"]],
        "band_fwhm_nm": rig["band_fwhm_nm"],
        "passband": rig["passband"],
        "sub_wavelengths_rendered": int(sub.size),
        "polarizer_angles_deg": [int(a) for a in rig["polarizer_angles_deg"]],
        "camera": rig["camera"],
        "illuminant": rig["illuminant"],
        "dome_hole_deg": rig["dome_hole_deg"],
        "film_ior": spec["film"]["ior"],
        "substrate_ior": spec["substrate"]["ior"],
        "substrate_k": spec["substrate"]["k"],
        "shape": spec["shape"]["kind"],
        "thickness_profile": spec["film"]["thickness"]["profile"],
        "resolution": rig["resolution"],
        "projection": sim["frame"].as_dict(),
        "seed": spec["seed"],
        "noise": dict(spec["noise"]),
        "stokes_spectral": "measured like spectral_s (noisy unless noise model is 'none')",
        "versions": _versions(),
    }


def _srgb8(linear: np.ndarray) -> np.ndarray:
    x = np.clip(linear, 0.0, 1.0)
    srgb = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)
    return np.rint(srgb * 255.0).astype(np.uint8)


def _preview(path: Path, sim: dict) -> None:
    """Two panels: the camera's unpolarized RGB (auto-scaled, sRGB) and the normal map."""
    from PIL import Image

    gt = sim["ground_truth"]
    mask = gt["mask"]
    rgb = sim["polarized_rgb"]
    angles = sorted(rgb)
    s0 = 2.0 * np.mean([rgb[a] for a in angles], axis=0)  # S0 in camera RGB (angles spread evenly)
    level = np.percentile(s0[mask], 99) if np.any(mask) else 1.0
    left = _srgb8(s0 / (level if level > 0 else 1.0))
    normal = np.where(mask[..., None], 0.5 * (gt["normal"] + 1.0), 0.0)
    right = np.rint(np.clip(normal, 0, 1) * 255).astype(np.uint8)
    gap = np.zeros((left.shape[0], 4, 3), dtype=np.uint8)
    Image.fromarray(np.concatenate([left, gap, right], axis=1)).save(path, format="PNG")


def polarized_rgb_channels(polarized_rgb: dict) -> dict:
    """EXR channels of polarizer images {angle: (H, W, 3)}: ``pol000.R``, ``pol000.G``, ...
    (:func:`thinfilm.dataset.pol_layer`), in the order of the dict."""
    from thinfilm.dataset import pol_layer

    return {f"{pol_layer(angle)}.{name}": img[..., c]
            for angle, img in polarized_rgb.items() for c, name in enumerate("RGB")}


def band_channels(cube, prefix: str = "") -> dict:
    """EXR channels of a spectral cube (H, W, B): ``{prefix}band000``, ...
    (:func:`thinfilm.dataset.band_channel`)."""
    from thinfilm.dataset import band_channel

    return {f"{prefix}{band_channel(b)}": cube[..., b] for b in range(cube.shape[-1])}


def write_dataset(sim: dict, spec: dict, folder) -> None:
    """Write every file of format ``thinfilm-dataset/1`` into ``folder`` (which exists)."""
    from thinfilm.dataset import write_exr, write_json

    from .spec import dump_toml

    folder = Path(folder)
    gt = sim["ground_truth"]
    (folder / "scene.toml").write_text(dump_toml(spec), encoding="utf-8")
    write_json(folder / "meta.json", _meta(spec, sim))
    write_exr(folder / "ground_truth.exr", {
        "normal.X": gt["normal"][..., 0], "normal.Y": gt["normal"][..., 1],
        "normal.Z": gt["normal"][..., 2], "zenith": gt["zenith"], "azimuth": gt["azimuth"],
        "thickness": gt["thickness"], "depth": gt["depth"], "mask": gt["mask"].astype(np.float32),
    })
    write_exr(folder / "polarized_rgb.exr", polarized_rgb_channels(sim["polarized_rgb"]))
    write_exr(folder / "spectral_s.exr", band_channels(sim["spectral_s"]))
    write_exr(folder / "stokes_spectral.exr", {
        k: v for s in ("S0", "S1", "S2") for k, v in band_channels(sim["stokes"][s], f"{s}.").items()})
    _preview(folder / "preview.png", sim)


def generate_dataset(spec: dict, out_dir, progress: bool = True) -> Path:
    """Generate a dataset folder from a resolved spec (:func:`.spec.load_spec`).

    The Mitsuba variant must be ``llvm_ad_mono_polarized`` (:func:`set_variant`). The
    folder is written atomically: a temporary folder beside ``out_dir`` is renamed to it
    when complete; an existing dataset at ``out_dir`` is replaced.

    Returns
    -------
    Path
        ``out_dir``.
    """
    from thinfilm.dataset import atomic_output_dir, check_output_dir

    out = check_output_dir(out_dir, markers=("meta.json",))  # before the work, not after
    timings = {}
    sim = simulate(spec, progress=progress)
    timings.update(sim["timings_s"])
    t = time.perf_counter()
    with atomic_output_dir(out, markers=("meta.json",)) as tmp:
        write_dataset(sim, spec, tmp)
    timings["write"] = time.perf_counter() - t
    generate_dataset.last_timings_s = timings
    return out


generate_dataset.last_timings_s = {}


def cli_main(args) -> int:
    """``thinfilm generate SPEC.toml|PRESET --out DIR [--set k=v ...] [--resolution N] [--seed S]``."""
    from .spec import load_spec

    spec = load_spec(args.spec, overrides=list(args.overrides or ()), resolution=args.resolution,
                     seed=args.seed)
    from thinfilm.dataset import check_output_dir

    out = check_output_dir(args.out, markers=("meta.json",))
    set_variant()
    generate_dataset(spec, out, progress=sys.stderr.isatty())
    t = generate_dataset.last_timings_s
    print(f"wrote {out} ({spec['rig']['resolution']}x{spec['rig']['resolution']}, "
          f"{len(spec['rig']['polarizer_angles_deg'])} polarizer angles; "
          f"{sum(t.values()):.1f} s)", file=sys.stderr)
    return 0
