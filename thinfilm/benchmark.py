"""``thinfilm benchmark [--quick] --out DIR``: every preset × every applicable method, scored.

For each preset (``hemisphere``, ``cylinder``, ``pyramid``) a dataset is generated with the
preset's default (camera) noise; every reconstruction method that applies to it is run —
the RGB-polarization methods on all three, the spectral methods on the hemisphere and the
cylinder (the paper's simulated objects; the pyramid's flat faces leave the spectral
method's eikonal integration nothing to integrate from), every method of the estimator
registry of every role — and every estimate is re-rendered and scored by :mod:`thinfilm.evaluation`.
The ground truth itself is scored too: its ΔE is the capture-noise floor.

``--quick`` renders at :data:`QUICK_RESOLUTION` px (the full run at the presets' own
resolution). The output folder holds ``report.md`` (the paper's reported figures beside
ours, and the figures), ``results.json``, and ``datasets/``, ``estimates/``, ``evaluations/``.
"""

from __future__ import annotations

import argparse
import sys
import time
import traceback
from pathlib import Path

from thinfilm.core.errors import UserError

__all__ = [
    "PRESET_KINDS",
    "QUICK_RESOLUTION",
    "PAPER_FIGURES",
    "benchmark_methods",
    "run_method",
    "run_benchmark",
    "write_report",
    "cli_main",
]

#: Which reconstruction kinds apply to which preset.
PRESET_KINDS = {
    "hemisphere": ("rgb", "spectral"),
    "cylinder": ("rgb", "spectral"),
    "pyramid": ("rgb",),
}
QUICK_RESOLUTION = 128

#: Figures the paper reports (``shared/PAPER.md``), keyed by (kind, preset). ``setting``
#: says what the paper measured them on; ``None`` = not reported.
PAPER_FIGURES = {
    ("rgb", "cylinder"): {
        "setting": "real cylinder (PET, MgF2 400 nm)",
        "normal_error_deg": 4.48, "delta_e_ab": 0.64, "thickness_error_nm": None,
        "film_ior_error": None, "spectral_rmse_pct": None},
    ("rgb", "pyramid"): {
        "setting": "real pyramid button (ABS, MgF2 400-690 nm)",
        "normal_error_deg": 2.82, "delta_e_ab": 3.0, "thickness_error_nm": None,
        "film_ior_error": None, "spectral_rmse_pct": None},
    ("rgb", "hemisphere"): {
        "setting": "spectrometer sweep, 630 nm film, zenith 10-50 deg (Table 1)",
        "normal_error_deg": None, "delta_e_ab": None, "thickness_error_nm": 6.56,
        "film_ior_error": None, "spectral_rmse_pct": None},
    ("spectral", "hemisphere"): {
        "setting": "simulated hemisphere (400 nm); normal error is the max",
        "normal_error_deg": "max ~10", "delta_e_ab": None, "thickness_error_nm": "~10",
        "film_ior_error": 0.0, "spectral_rmse_pct": None},
    ("spectral", "cylinder"): {
        "setting": "simulated cylinder (420-560 nm); normal error is the max",
        "normal_error_deg": "max ~4", "delta_e_ab": None, "thickness_error_nm": "~7",
        "film_ior_error": 0.0, "spectral_rmse_pct": None},
    ("spectral", "real"): {
        "setting": "real sample (n2 1.37 estimated 1.41)",
        "normal_error_deg": None, "delta_e_ab": 3.33, "thickness_error_nm": 45.0,
        "film_ior_error": 0.04, "spectral_rmse_pct": "~2"},
}


# -- steps -------------------------------------------------------------------------------------

def benchmark_methods(kind: str) -> dict:
    """Every registered method of ``kind`` (any role): name → role."""
    from thinfilm.core import registry

    return {m.name: m.role for m in registry.methods(kind)}


def _generate(preset: str, resolution, out: Path) -> None:
    from thinfilm.core.variants import use_variant
    from thinfilm.generators.generate import generate_dataset
    from thinfilm.generators.spec import load_spec

    use_variant()
    spec = load_spec(preset, resolution=resolution)
    generate_dataset(spec, out, progress=False)


def run_method(kind: str, dataset: Path, out: Path, method: str) -> None:
    """Reconstruct ``dataset`` with registered ``method`` of ``kind`` into the folder ``out``."""
    from thinfilm.core.io import write_estimate
    from thinfilm.core.outputs import atomic_output_dir
    from thinfilm.reconstruct import reconstruct

    est, _ = reconstruct(kind, dataset, method)
    with atomic_output_dir(out, command="reconstruct", inputs=[dataset]) as tmp:
        write_estimate(tmp, est)


def _ground_truth_estimate(dataset: Path, out: Path) -> None:
    from thinfilm.core.io import Estimate, read_dataset, write_estimate
    from thinfilm.core.outputs import atomic_output_dir

    ds = read_dataset(dataset, need=("ground_truth",))
    gt = ds.ground_truth
    est = Estimate(gt["normal"], gt["thickness"], gt["mask"], ds.meta["film_ior"], ds.meta["substrate_ior"],
                   info={"method": "ground_truth", "timings_s": {}})
    with atomic_output_dir(out, command="reconstruct", inputs=[dataset]) as tmp:
        write_estimate(tmp, est)


def _evaluate(dataset: Path, estimate: Path, out: Path) -> dict:
    from thinfilm.core.variants import use_variant

    from . import evaluation

    use_variant()  # the evaluation re-renders in the generator's variant
    r = evaluation.evaluate(dataset, estimate, out)
    return {"metrics": r["metrics"], "coverage": r["info"]["coverage"],
            "film_ior_estimated": r["info"]["film_ior_estimated"]}


def run_benchmark(out, quick=False, presets=None, progress=True, resolution=None) -> dict:
    """Run the benchmark into ``out`` (written atomically) and return the results.

    Parameters
    ----------
    quick : bool
        Small images (:data:`QUICK_RESOLUTION` px) unless ``resolution`` is given.
    presets : iterable of str, optional
        Subset of :data:`PRESET_KINDS` (all by default).
    """
    from tqdm import tqdm

    from thinfilm.core.io import write_json
    from thinfilm.core.outputs import atomic_output_dir

    presets = list(presets or PRESET_KINDS)
    for p in presets:
        if p not in PRESET_KINDS:
            raise UserError(f"unknown preset {p!r}: expected one of {', '.join(PRESET_KINDS)}")
    if resolution is None and quick:
        resolution = QUICK_RESOLUTION
    methods = {kind: benchmark_methods(kind) for kind in ("rgb", "spectral")}
    missing = {kind: "no method registered" for kind, found in methods.items() if not found}
    plan = []
    for preset in presets:
        plan.append(("generate", preset, None, None))
        plan.append(("ground_truth", preset, None, None))
        for kind in PRESET_KINDS[preset]:
            for method, role in methods.get(kind, {}).items():
                plan.append(("method", preset, kind, (method, role)))

    t_start = time.perf_counter()
    results = {"quick": bool(quick), "resolution": resolution, "rows": [], "missing_kinds": missing,
               "methods": methods, "timings_s": {}}
    with atomic_output_dir(out, command="benchmark") as tmp:
        bar = tqdm(plan, desc="benchmark", unit="step", disable=not progress, file=sys.stderr)
        for step, preset, kind, extra in bar:
            ds_dir = tmp / "datasets" / preset
            if step == "generate":
                bar.set_postfix_str(f"generate {preset}")
                t0 = time.perf_counter()
                _generate(preset, resolution, ds_dir)
                results["timings_s"][f"generate/{preset}"] = round(time.perf_counter() - t0, 2)
                continue
            if step == "ground_truth":
                label, kind_name, method, role = "ground_truth", "-", "ground truth", "noise floor"
            else:
                method, role = extra
                label, kind_name = f"{kind}-{method}", kind
            bar.set_postfix_str(f"{preset}: {label}")
            est_dir = tmp / "estimates" / preset / label
            ev_dir = tmp / "evaluations" / preset / label
            row = {"preset": preset, "kind": kind_name, "method": method, "role": role,
                   "estimate": str(est_dir.relative_to(tmp)), "evaluation": str(ev_dir.relative_to(tmp))}
            try:
                t0 = time.perf_counter()
                if step == "ground_truth":
                    _ground_truth_estimate(ds_dir, est_dir)
                else:
                    run_method(kind, ds_dir, est_dir, method)
                row["reconstruct_s"] = round(time.perf_counter() - t0, 2)
                t0 = time.perf_counter()
                row.update(_evaluate(ds_dir, est_dir, ev_dir))
                row["evaluate_s"] = round(time.perf_counter() - t0, 2)
            except Exception as e:  # one failing method must not hide the others
                row["error"] = f"{type(e).__name__}: {e}".splitlines()[0]
                row["traceback"] = traceback.format_exc(limit=6)
            results["rows"].append(row)
        results["timings_s"]["total"] = round(time.perf_counter() - t_start, 1)
        write_json(tmp / "results.json", results)
        (tmp / "report.md").write_text(write_report(results))
    return results


# -- report --------------------------------------------------------------------------------------

def _f(value, digits=2, scale=1.0):
    if value is None:
        return "—"
    if isinstance(value, str):
        return value
    return f"{value * scale:.{digits}f}"


def _stat(row, key, stat="mean", digits=2, scale=1.0):
    m = row.get("metrics", {}).get(key)
    return _f(None if m is None else m.get(stat), digits, scale)


def write_report(results: dict) -> str:
    """The Markdown text of ``report.md``."""
    rows = results["rows"]
    res = results.get("resolution") or "preset default"
    lines = [
        "# thinfilm benchmark report",
        "",
        f"{'Quick run' if results.get('quick') else 'Full run'}: images {res} px, default camera noise "
        f"(shot + read noise, 12 bits, auto exposure), total wall time "
        f"{results['timings_s'].get('total', 0):.0f} s.",
        "",
        "Every estimate is re-rendered through the `thinfilm` BSDF with the dataset's rig (no "
        "noise) and compared with the captures. ΔE*ab (CIE 1976, paper Eq. 31) and ΔE00 are "
        "taken between the captured and re-rendered s-polarized spectra in CIELAB (CIE 1931 2°, "
        "the dataset illuminant, perfect-white reference); spectral RMSE is paper Eq. 32 in "
        "percent reflectance. Errors are over the object mask where the estimate is valid; "
        "*coverage* is that fraction of the object. The *ground truth* row is the truth itself "
        "scored against the noisy captures: its ΔE is the capture-noise floor.",
        "",
    ]
    if results.get("missing_kinds"):
        lines += ["**Not benchmarked** (not available in this version):", ""]
        lines += [f"- `{k}`: {v}" for k, v in results["missing_kinds"].items()]
        lines.append("")

    lines += ["## Results", "",
              "| preset | kind | method | role | normal err. mean / p95 (°) | zenith err. mean (°) | "
              "thickness err. mean / p95 (nm) | n2 est. (err.) | ΔE*ab mean / p95 | ΔE00 mean | "
              "spectral RMSE mean (%) | coverage | reconstruct (s) |",
              "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        if "error" in r:
            lines.append(f"| {r['preset']} | {r['kind']} | {r['method']} | {r['role']} | "
                         f"**failed**: {r['error'].replace('|', '/')} |  |  |  |  |  |  |  |  |")
            continue
        fi = r.get("film_ior_estimated")
        n2 = (f"{fi:.3f}" if isinstance(fi, (int, float)) else str(fi)) + \
            f" ({_f(r['metrics'].get('film_ior_error'), 3)})"
        lines.append(
            f"| {r['preset']} | {r['kind']} | {r['method']} | {r['role']} | "
            f"{_stat(r, 'normal_error_deg')} / {_stat(r, 'normal_error_deg', 'p95')} | "
            f"{_stat(r, 'zenith_error_deg')} | "
            f"{_stat(r, 'thickness_error_nm', digits=1)} / {_stat(r, 'thickness_error_nm', 'p95', 1)} | "
            f"{n2} | {_stat(r, 'delta_e_ab')} / {_stat(r, 'delta_e_ab', 'p95')} | "
            f"{_stat(r, 'delta_e_2000')} | {_stat(r, 'spectral_rmse', scale=100.0)} | "
            f"{100 * r.get('coverage', 0):.0f} % | {r.get('reconstruct_s', 0):.1f} |")
    lines.append("")

    lines += ["## Paper versus ours", "",
              "The paper's figures (Kobayashi et al.; `shared/PAPER.md`) beside ours on the "
              "matching preset. The paper's RGB figures come from real objects or a "
              "spectrometer sweep, its spectral figures from simulation (and one real sample): "
              "the settings differ, so read the columns side by side, not as a pass mark.", "",
              "| kind | preset | paper setting | normal err. (°) paper / ours | thickness err. (nm) "
              "paper / ours | n2 err. paper / ours | ΔE*ab paper / ours | spectral RMSE (%) paper / ours |",
              "|---|---|---|---|---|---|---|---|"]
    for (kind, preset), paper in PAPER_FIGURES.items():
        ours = [r for r in rows if r["kind"] == kind and "error" not in r
                and (r["preset"] == preset or (preset == "real" and r["preset"] in ("hemisphere", "cylinder")))]
        if not ours:
            ours = [None]
        for r in ours:
            def pair(key, stat="mean", digits=2, scale=1.0, paper_key=None):
                p = _f(paper.get(paper_key or key), digits)
                if r is None:
                    return f"{p} / —"
                if key == "film_ior_error":
                    return f"{p} / {_f(r['metrics'].get(key), 3)}"
                max_too = isinstance(paper.get(paper_key or key), str) and "max" in paper[paper_key or key]
                o = _stat(r, key, "max" if max_too else stat, digits, scale)
                return f"{p} / {('max ' if max_too else '') + o}"
            who = "" if r is None else f" ({r['preset']}, {r['method']})"
            lines.append(
                f"| {kind} | {preset}{who} | {paper['setting']} | {pair('normal_error_deg')} | "
                f"{pair('thickness_error_nm', digits=1)} | {pair('film_ior_error')} | "
                f"{pair('delta_e_ab')} | {pair('spectral_rmse', scale=100.0, paper_key='spectral_rmse_pct')} |")
    lines.append("")

    lines += ["## Figures", ""]
    for r in rows:
        if "error" in r:
            continue
        ev = r["evaluation"]
        lines += [f"### {r['preset']} — {r['method']} ({r['kind']}, {r['role']})", ""]
        for name, alt in (("appearance.png", "captured vs re-rendered, ΔE*ab"),
                          ("normals.png", "normals: truth, estimate, error"),
                          ("thickness.png", "thickness: truth, estimate, error"),
                          ("errors.png", "error maps")):
            if r["method"] == "ground truth" and name in ("normals.png", "thickness.png"):
                continue
            lines.append(f"![{alt}]({ev}/{name})")
        lines.append("")

    failed = [r for r in rows if "error" in r]
    if failed:
        lines += ["## Failures", ""]
        for r in failed:
            lines += [f"### {r['preset']} — {r['kind']} {r['method']}", "", "```", r["traceback"].rstrip(), "```", ""]
    lines += ["## Timings (s)", "", "| step | seconds |", "|---|---|"]
    lines += [f"| {k} | {v} |" for k, v in results["timings_s"].items()]
    lines += [f"| reconstruct+evaluate {r['preset']}/{r['method']} | "
              f"{r.get('reconstruct_s', 0) + r.get('evaluate_s', 0):.1f} |" for r in rows if "error" not in r]
    lines.append("")
    return "\n".join(lines)


def cli_main(args) -> int:
    """``thinfilm benchmark [--quick] --out DIR``. Exit code 1 when a method failed."""
    out = Path(args.out)
    results = run_benchmark(out, quick=args.quick, progress=sys.stderr.isatty())
    failed = [r for r in results["rows"] if "error" in r]
    print(f"benchmark: {len(results['rows'])} runs, {len(failed)} failed, "
          f"{results['timings_s']['total']:.0f} s -> {out / 'report.md'}")
    for r in failed:
        print(f"  failed: {r['preset']} {r['kind']} {r['method']}: {r['error']}", file=sys.stderr)
    if results.get("missing_kinds"):
        for k, v in results["missing_kinds"].items():
            print(f"  not benchmarked: {k}: {v}", file=sys.stderr)
    return 1 if failed or results.get("missing_kinds") else 0


def _main(argv=None) -> int:  # pragma: no cover - `python -m thinfilm.benchmark`
    p = argparse.ArgumentParser(prog="python -m thinfilm.benchmark")
    p.add_argument("--quick", action="store_true")
    p.add_argument("--out", required=True)
    return cli_main(p.parse_args(argv))


if __name__ == "__main__":  # pragma: no cover
    sys.exit(_main())
