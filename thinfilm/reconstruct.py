"""``thinfilm reconstruct rgb|spectral``: run a registered estimator on a dataset folder.

The method comes from the estimator registry (:mod:`thinfilm.core.registry`): a built-in
name or alias, a third-party method of the ``thinfilm.estimators`` entry points, or
``package.module:function``. The dataset is read for the parts the method needs and uses,
the film is taken from ``meta.json`` with ``--film-ior`` / ``--substrate-ior`` applied,
and the estimate folder is written atomically.
"""

from __future__ import annotations

import math
import time

__all__ = ["film_for", "reconstruct", "cli_main"]

#: thickness ranges the RGB table search can cover (nm)
MAX_THICKNESS_RANGE_NM = 20000.0


def film_for(dataset, method, film_ior=None, substrate_ior=None):
    """The film an estimator is given: ``meta.json``'s (its ``film`` entry, else
    ``film_ior`` / ``substrate_ior`` / ``substrate_k``) with the command line's indices
    applied. A method that estimates the film index may do without one."""
    from thinfilm.core.errors import UserError
    from thinfilm.core.film import Film

    meta = dataset.meta
    where = str(dataset.path / "meta.json")
    if isinstance(meta.get("film"), dict):
        film = Film.from_meta(meta, where)
        if film_ior is not None:
            film = film.with_index(film_ior)
        if substrate_ior is not None:
            film = film.with_substrate(substrate_ior)
        return film
    if film_ior is None:
        film_ior = meta.get("film_ior")
        if film_ior is None and not method.estimates_film_ior:
            raise UserError(f"{where}: no 'film_ior'; pass the index with --film-ior")
        where_n2 = f"{where}: 'film_ior'"
    else:
        where_n2 = "--film-ior"
    k = 0.0
    if substrate_ior is None:
        substrate_ior = meta.get("substrate_ior")
        if substrate_ior is None:
            raise UserError(f"{where}: no 'substrate_ior'; pass --substrate-ior")
        k = meta.get("substrate_k", 0.0) or 0.0
        if isinstance(k, bool) or not isinstance(k, (int, float)) or not (math.isfinite(k) and k >= 0):
            raise UserError(f"{where}: 'substrate_k' must be a number >= 0, got {k!r}")
        where_n3 = f"{where}: 'substrate_ior'"
    else:
        where_n3 = "--substrate-ior"
    from thinfilm.core.film import as_index

    n2 = None if film_ior is None else as_index(film_ior, where_n2)
    n3 = as_index(substrate_ior, where_n3)
    return Film.single(n2, None, n3, k, where=where)


def reconstruct(kind: str, dataset_path, method=None, film_ior=None, substrate_ior=None,
                thickness_range_nm=None, mask_path=None, progress: bool = False, options=None):
    """Run method ``method`` (a name, alias or ``package.module:function``; None: the
    default) of ``kind`` on a dataset folder. ``options``: the method's options, a dict or
    ``NAME=VALUE`` strings (checked against what the method declares). Returns the
    :class:`~thinfilm.core.io.Estimate` and the :class:`~thinfilm.core.registry.Method`."""
    from thinfilm.core import registry
    from thinfilm.core.errors import NoResultError, UserError
    from thinfilm.core.io import read_dataset, read_mask_file

    m = registry.get(kind, method)
    given = registry.parse_options(options) if isinstance(options, (list, tuple)) else dict(options or {})
    m.option_values(given)  # unknown or malformed options fail before any reading
    if thickness_range_nm is not None:
        lo, hi = (float(v) for v in thickness_range_nm)
        if not (math.isfinite(lo) and math.isfinite(hi)) or lo >= hi or lo < 0:
            raise UserError(f"expected 0 <= MIN < MAX in nm, got {lo:g} {hi:g}", argument="thickness_range_nm")
        if hi > MAX_THICKNESS_RANGE_NM:
            raise UserError(f"MAX must be at most {MAX_THICKNESS_RANGE_NM:g} nm, got {hi:g}",
                            argument="thickness_range_nm")
        thickness_range_nm = (lo, hi)
    t0 = time.perf_counter()
    ds = read_dataset(dataset_path, need=m.needs, optional=m.uses)
    film = film_for(ds, m, film_ior, substrate_ior)
    mask = read_mask_file(mask_path, ds.shape) if mask_path is not None else None
    t_read = time.perf_counter() - t0
    options = registry.Options(film=film, mask=mask, thickness_range_nm=thickness_range_nm, progress=progress,
                               method_options=given)
    try:
        est = registry.run(m, ds, options)
    except (UserError, NoResultError, MemoryError):
        raise
    except Exception as e:
        if str(getattr(m.function, "__module__", "")).startswith("thinfilm."):
            raise  # a bug of ours: reported as one
        # a method from elsewhere (an installed plugin, package.module:function) that failed
        reason = " ".join(f"{type(e).__name__}: {e}".split())[:300]
        raise UserError(f"the method failed ({reason})", argument="method", value=m.name) from None
    est.info["timings_s"] = {"read": t_read, **est.info.get("timings_s", {})}
    est.info["timings_s"]["total"] = time.perf_counter() - t0
    return est, m


def cli_main(args) -> int:
    """``thinfilm reconstruct KIND DATASET --out DIR [--method NAME] [...]``."""
    import sys

    from thinfilm.core.io import write_estimate, write_json
    from thinfilm.core.outputs import atomic_output_dir, check_output_dir

    t0 = time.perf_counter()
    inputs = [args.dataset, getattr(args, "mask", None)]
    out = check_output_dir(args.out, command="reconstruct", inputs=inputs)
    with atomic_output_dir(out, command="reconstruct", inputs=inputs) as tmp:
        est, method = reconstruct(args.kind, args.dataset, getattr(args, "method", None),
                                  getattr(args, "film_ior", None), getattr(args, "substrate_ior", None),
                                  getattr(args, "thickness_range", None), getattr(args, "mask", None),
                                  progress=sys.stderr.isatty(), options=getattr(args, "option", None) or [])
        if getattr(args, "refine", False):
            from thinfilm.refine import refine

            t = time.perf_counter()
            timings = est.info["timings_s"]
            est = refine(args.dataset, est, prior=args.prior, progress=sys.stderr.isatty())
            est.info["timings_s"] = {**timings, "refine": time.perf_counter() - t}
        t = time.perf_counter()
        write_estimate(tmp, est)
        # estimate.json again, last, so that it holds the time of the writing too
        est.info["timings_s"]["write"] = time.perf_counter() - t
        est.info["timings_s"]["wall"] = time.perf_counter() - t0
        write_json(tmp / "estimate.json", est.json())
    n2 = est.film_ior
    n2_text = f", film index {n2:.4f}" if method.estimates_film_ior and isinstance(n2, float) else ""
    print(f"wrote {out} (method {est.info['method']}{n2_text}, {int(est.valid.sum())} pixels, "
          f"{est.info['timings_s']['wall']:.1f} s)")
    return 0
