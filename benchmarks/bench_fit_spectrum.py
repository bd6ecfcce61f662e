"""Speed and accuracy of ``fit_spectra`` (``thinfilm fit-spectrum``) on a batch of measured-like
spectra, against a naive baseline measured in the same run.

Spectra: films on one wavelength grid (400-850 nm, 600 samples), thicknesses log-uniform in
50-5000 nm, reflectance from ``tmm`` (an independent transfer-matrix code) times a random
smooth instrument response (its own for each spectrum), plus a background and 0.5 % noise: raw
counts, no background or reference files. ``--with-files``: one instrument for all spectra, with
its dark and white readings given (as the thin films need).

Baseline: what one would write first: per spectrum, the model ``B + G·R(d)`` (B a line and G a
cubic in 1/λ, as ours) fitted by ``scipy.optimize.least_squares`` over all its parameters,
started from the best of a coarse thickness grid (the response started flat at the mean
level); with ``--with-files`` it fits the normalised ``(I − dark)/(white − dark)``. It is slow (one spectrum at a time, finite-difference Jacobians) and falls into the
wrong interference order whenever the start is a fringe off.

Against an earlier version of the project (``--baseline-python CMD``: an interpreter, or a
wrapper script, that imports that version): the same spectra are fitted by ``fit_spectra`` in
a subprocess run by ``CMD``, interleaved with ours, and the ratio of the rates is printed.

Usage::

    python benchmarks/bench_fit_spectrum.py [--count 300] [--naive-count 60] [--substrate free|silicon]
                                            [--with-files] [--repeats 3] [--seed 0]
                                            [--baseline-python CMD]

Prints absolute times, spectra per second of both, their ratio (medians over interleaved
repeats), and the accuracy of both by thickness band.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

SUBSTRATES = {"free": (1.33, 1.0, 0.0), "silicon": (1.46, 3.9, 0.02)}


def _tmm_reflectance(lam, d, n2, n3, k3):
    import tmm

    out = np.empty(lam.size)
    for i, wl in enumerate(lam):  # normal incidence: R_s = R_p
        out[i] = tmm.coh_tmm("s", [1.0, n2, n3 + 1j * k3], [np.inf, d, np.inf], 0.0, wl)["R"]
    return out


def _instrument(rng, t):
    response = 1000.0 * np.exp(rng.uniform(-0.5, 0.5) * t + rng.uniform(-0.4, 0.4) * t * t)
    return response, 20.0 + rng.uniform(-5.0, 5.0) * t


def make_spectra(count, n2, n3, k3, seed, lam, one_instrument):
    """Thicknesses and raw spectra; each spectrum its own random instrument, or (with
    ``one_instrument``) one instrument for all, whose dark and white readings are returned."""
    rng = np.random.default_rng(seed)
    d = np.exp(rng.uniform(np.log(50.0), np.log(5000.0), count))
    t = (lam - lam.mean()) / (0.5 * np.ptp(lam))
    shared = _instrument(rng, t)
    raw = []
    for di in d:
        R = _tmm_reflectance(lam, di, n2, n3, k3)
        response, background = shared if one_instrument else _instrument(rng, t)
        sigma = 0.005 * np.mean(response * R)
        raw.append(background + response * R + rng.normal(0.0, sigma, lam.size))
    response, background = shared
    sigma = 0.005 * np.mean(response) * 0.05
    dark = background + rng.normal(0.0, sigma, lam.size)
    white = background + 0.95 * response + rng.normal(0.0, sigma, lam.size)
    return d, np.array(raw), dark, white


def naive_fit(lam, y, model, d_range=(1.0, 10000.0), grid_points=40):
    """The baseline: least_squares on (d, B line, G cubic) from the best coarse-grid start."""
    from scipy.optimize import least_squares

    from thinfilm.bsdf import optics

    x = 1.0 / lam
    t = 2.0 * (x - x.min()) / np.ptp(x) - 1.0
    V = np.polynomial.legendre.legvander(t, 3)
    n2, k2, n3, k3 = model.indices(lam)

    def reflectance(d):  # normal incidence, the optics core in NumPy
        R_s, R_p = optics.reflectances(1.0, lam, d, n2, n3, k3, model.ext_ior, k2)
        return 0.5 * (R_s + R_p)

    def model_y(p):
        B = p[1] + p[2] * t
        G = V @ p[3:]
        return B + G * reflectance(p[0])

    grid = np.linspace(d_range[0], d_range[1], grid_points)
    R = reflectance(grid[:, None])
    g0 = (y.mean() - y.min()) / np.maximum(R.mean(axis=1), 1e-12)
    costs = np.sum((y.min() + g0[:, None] * R - y) ** 2, axis=1)
    k = int(np.argmin(costs))
    p0 = np.r_[grid[k], y.min(), 0.0, g0[k], 0.0, 0.0, 0.0]
    res = least_squares(lambda p: model_y(p) - y, p0, x_scale="jac",
                        bounds=([d_range[0]] + [-np.inf] * 6, [d_range[1]] + [np.inf] * 6))
    return float(res.x[0])


def accuracy(truth, est):
    rel = np.abs(np.asarray(est) - truth) / truth
    rows = []
    for lo, hi in [(50, 150), (150, 400), (400, 5001)]:
        s = (truth >= lo) & (truth < hi)
        if np.any(s):
            rows.append(f"{lo}-{min(hi, 5000)} nm: {np.mean(rel[s] <= 0.01):.0%} within 1 % (n={s.sum()})")
    return f"{np.mean(rel <= 0.01):.0%} within 1 %, median error {100 * np.median(rel):.2f} %; " + ", ".join(rows)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--count", type=int, default=300)
    ap.add_argument("--naive-count", type=int, default=60)
    ap.add_argument("--substrate", choices=sorted(SUBSTRATES), default="free")
    ap.add_argument("--with-files", action="store_true", help="give a background and a reference")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--baseline-python", default=None, metavar="CMD",
                    help="interpreter importing an earlier version: its fit_spectra timed on the same spectra")
    ap.add_argument("--fit-only", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.fit_only:
        return _fit_only(args)

    from thinfilm.reconstruction.spectrum_fit import FilmModel, fit_spectra

    n2, n3, k3 = SUBSTRATES[args.substrate]
    lam = np.linspace(400.0, 850.0, 600)
    t0 = time.perf_counter()
    truth, raw, dark, white = make_spectra(args.count, n2, n3, k3, args.seed, lam, args.with_files)
    print(f"{args.count} spectra, film n={n2} on n3={n3}+{k3}i, {lam.size} samples 400-850 nm, "
          f"{'with background and reference' if args.with_files else 'raw counts only'} "
          f"(generated with tmm in {time.perf_counter() - t0:.1f} s)")
    model = FilmModel(n2, n3, k3)
    naive_idx = np.linspace(0, args.count - 1, min(args.naive_count, args.count)).round().astype(int)

    def robust():
        files = {"background": dark, "reference": white} if args.with_files else {}
        return [f.thickness_nm for f in fit_spectra(lam, raw, model, **files)]

    def naive():
        if args.with_files:
            return [naive_fit(lam, (raw[i] - dark) / (white - dark), model) for i in naive_idx]
        return [naive_fit(lam, raw[i], model) for i in naive_idx]

    times_r, times_n = [], []
    for _ in range(args.repeats):  # interleaved
        t = time.perf_counter()
        est_r = robust()
        times_r.append(time.perf_counter() - t)
        t = time.perf_counter()
        est_n = naive()
        times_n.append(time.perf_counter() - t)
    tr, tn = np.median(times_r), np.median(times_n)
    rate_r, rate_n = args.count / tr, naive_idx.size / tn
    print(f"fit_spectra (variable projection, every order): {tr:.2f} s for {args.count} spectra "
          f"= {rate_r:.1f} spectra/s (median of {args.repeats}: {', '.join(f'{v:.2f}' for v in times_r)} s)")
    print(f"naive least_squares from a grid start:          {tn:.2f} s for {naive_idx.size} spectra "
          f"= {rate_n:.1f} spectra/s (median of {args.repeats}: {', '.join(f'{v:.2f}' for v in times_n)} s)")
    print(f"speed ratio (spectra/s): {rate_r / rate_n:.1f}x")
    if args.baseline_python:
        import shlex
        import subprocess
        import sys

        cmd = [*shlex.split(args.baseline_python), __file__, "--fit-only", "--count", str(args.count), "--seed", str(args.seed),
               "--substrate", args.substrate] + (["--with-files"] if args.with_files else [])
        times_b, times_o = [], []
        for _ in range(args.repeats):  # interleaved with ours again
            out = subprocess.run(cmd, capture_output=True, text=True, check=True).stdout.split()
            times_b.append(float(out[0]))
            est_b = np.array([float(v) for v in out[1:]])
            t = time.perf_counter()
            robust()
            times_o.append(time.perf_counter() - t)
        tb, to = np.median(times_b), np.median(times_o)
        print(f"baseline fit_spectra ({args.baseline_python}): {tb:.2f} s = {args.count / tb:.1f} spectra/s; "
              f"this version in the same run: {to:.2f} s = {args.count / to:.1f} spectra/s; "
              f"ratio {tb / to:.2f}x", file=sys.stdout)
        print(f"accuracy, baseline fit_spectra: {accuracy(truth, est_b)}")
    print(f"accuracy, fit_spectra: {accuracy(truth, est_r)}")
    print(f"accuracy, naive (same {naive_idx.size} spectra as below): {accuracy(truth[naive_idx], est_n)}")
    print(f"accuracy, fit_spectra on those {naive_idx.size}: {accuracy(truth[naive_idx], np.asarray(est_r)[naive_idx])}")


def _fit_only(args):
    """Time fit_spectra alone on the benchmark's spectra; print the seconds and the thicknesses."""
    from thinfilm.reconstruction.spectrum_fit import FilmModel, fit_spectra

    n2, n3, k3 = SUBSTRATES[args.substrate]
    lam = np.linspace(400.0, 850.0, 600)
    _, raw, dark, white = make_spectra(args.count, n2, n3, k3, args.seed, lam, args.with_files)
    files = {"background": dark, "reference": white} if args.with_files else {}
    t = time.perf_counter()
    fits = fit_spectra(lam, raw, FilmModel(n2, n3, k3), **files)
    print(time.perf_counter() - t, *(f.thickness_nm for f in fits))


if __name__ == "__main__":
    main()
