"""``thinfilm refine DATASET ESTIMATE --out DIR`` and ``reconstruct … --refine``: an estimate
fitted again to all of a dataset's captures (:mod:`thinfilm.reconstruction.refine`).

The estimate may be anyone's: a built-in method's, the paper's, or a third party's estimate
folder (``docs/design.md``, *Estimate folder*). The refined estimate is a new estimate folder
with the σ channels; its ``estimate.json`` holds the start's entries, ``method`` with
``+refine`` appended, and ``refine`` (prior, capture, costs, timings).
"""

from __future__ import annotations

import time

__all__ = ["CAPTURE_FILES", "read_for_refine", "refine", "cli_main"]

#: the dataset file of each capture a refinement can fit
CAPTURE_FILES = {"stokes": "stokes_spectral.exr", "spectral_s": "spectral_s.exr",
                 "polarized_rgb": "polarized_rgb.exr"}


def read_for_refine(dataset_path, estimate):
    """The dataset, with the one capture the refinement of ``estimate`` fits read (the one the
    estimate was made from where the dataset holds it: :func:`thinfilm.core.bound.estimate_capture`)."""
    from thinfilm.core.bound import estimate_capture
    from thinfilm.core.errors import UserError
    from thinfilm.core.io import read_dataset

    light = read_dataset(dataset_path, need=(), optional=())
    have = [c for c, f in CAPTURE_FILES.items() if (light.path / f).is_file()]
    if not have:
        raise UserError(f"{light.path}: the dataset holds none of {', '.join(CAPTURE_FILES.values())}")
    # what the dataset holds, for a method the registry does not know
    from types import SimpleNamespace

    holds = SimpleNamespace(polarized_rgb="polarized_rgb" in have, stokes="stokes" in have,
                            spectral_s=True if "spectral_s" in have else None)
    cap = estimate_capture(estimate, holds)
    if cap not in have:
        cap = have[0]
    return read_dataset(dataset_path, need=(cap,), optional=())


def refine(dataset_path, estimate, prior: str = "default", iterations: int = 8, progress: bool = False):
    """Refine ``estimate`` (an :class:`~thinfilm.core.io.Estimate`) on the dataset folder
    ``dataset_path`` (:func:`thinfilm.reconstruction.refine.refine_estimate`)."""
    from thinfilm.core.variants import use_variant
    from thinfilm.reconstruction.refine import refine_estimate

    use_variant()
    ds = read_for_refine(dataset_path, estimate)
    return refine_estimate(ds, estimate, prior=prior, iterations=iterations, progress=progress)


def cli_main(args) -> int:
    """``thinfilm refine DATASET ESTIMATE --out DIR [--prior default|none] [--iterations N]``."""
    import sys

    from thinfilm.core.io import read_estimate, write_estimate
    from thinfilm.core.outputs import atomic_output_dir, check_output_dir

    t0 = time.perf_counter()
    inputs = [args.dataset, args.estimate]
    out = check_output_dir(args.out, command="refine", inputs=inputs)
    start = read_estimate(args.estimate)
    with atomic_output_dir(out, command="refine", inputs=inputs) as tmp:
        est = refine(args.dataset, start, prior=args.prior, iterations=args.iterations,
                     progress=sys.stderr.isatty())
        est.info["timings_s"] = {**start.info.get("timings_s", {}), "refine": time.perf_counter() - t0}
        write_estimate(tmp, est)
    r = est.info["refine"]
    print(f"wrote {out} (refined {start.info.get('method') or 'estimate'} on {r['capture']}, prior {r['prior']}, "
          f"{int(est.valid.sum())} pixels, {time.perf_counter() - t0:.1f} s)")
    return 0
