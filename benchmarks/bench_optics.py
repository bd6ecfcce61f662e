"""Benchmark: the optics core's film stacks against colour-science's ``multilayer_tmm`` and ``tmm``.

The same wavelength × angle × thickness grid (81 wavelengths 380-780 nm, 18 angles 0-85°,
32 thickness scales 0.5-1.5 applied to every layer) for a few stacks on glass, computing
R_s, R_p, T_s and T_p everywhere:

* ours, NumPy (``optics.stack_powers`` on broadcast arrays, one thread);
* ours, Dr.Jit LLVM in double precision (``drjit.llvm.Float64``, the same function traced
  into one kernel; Dr.Jit runs it on all cores; timed after a warm-up call that compiles it,
  so each timed call still traces the Python but hits the kernel cache);
* colour-science's ``multilayer_tmm`` (transfer matrices broadcast over the whole grid);
* ``tmm.coh_tmm``, which takes one wavelength, angle and polarization per call: timed on a
  random subset of the grid and scaled per evaluation to the full grid (said so in the output).

Methods are interleaved in every repeat and medians are reported, with ratios against
ours (NumPy) from the same run. Agreement is printed as well (max |ΔR| over the grid or the
subset). colour-science computes the refraction angles from the real parts of the indices,
so for the absorbing stack its numbers are approximate at oblique incidence (timed anyway).

    python benchmarks/bench_optics.py [--repeats 5] [--tmm-samples 300] [--quick]
"""

import argparse
import statistics
import time
import warnings

import numpy as np

QW = 550.0
STACKS = {
    "AR 2-layer (MgF2/ZrO2)": [(1.38, QW / (4 * 1.38)), (2.05, QW / (4 * 2.05))],
    "absorbing 4-layer": [(1.38, 110.0), (2.0 + 0.3j, 40.0), (1.46, 150.0), (0.5 + 2.4j, 8.0)],
    "Bragg 10 pairs (20 layers)": [(2.35, QW / (4 * 2.35)), (1.38, QW / (4 * 1.38))] * 10,
}
SUBSTRATE = 1.52


def grid(quick):
    lam = np.linspace(380.0, 780.0, 41 if quick else 81)
    theta = np.linspace(0.0, 85.0, 9 if quick else 18)
    scale = np.linspace(0.5, 1.5, 8 if quick else 32)
    return lam, theta, scale


def ours_numpy(layers, lam, theta, scale):
    from thinfilm.bsdf import optics

    cos = np.cos(np.radians(theta))[None, :, None]
    lam3 = lam[:, None, None]
    s3 = scale[None, None, :]
    stack = [(complex(n).real, complex(n).imag, d * s3) for n, d in layers]
    return optics.stack_powers(cos, lam3, stack, SUBSTRATE)  # each (W, A, T)


class OursDrJit:
    """The same optics on flattened Dr.Jit LLVM Float64 arrays."""

    def __init__(self, lam, theta, scale):
        import drjit as dr

        self.dr = dr
        F = dr.llvm.Float64
        L, A, S = np.meshgrid(lam, np.cos(np.radians(theta)), scale, indexing="ij")
        self.lam, self.cos, self.scale = F(L.ravel()), F(A.ravel()), F(S.ravel())
        self.shape = L.shape

    def __call__(self, layers):
        from thinfilm.bsdf import optics

        stack = [(complex(n).real, complex(n).imag, self.scale * d) for n, d in layers]
        out = optics.stack_powers(self.cos, self.lam, stack, SUBSTRATE)
        self.dr.eval(*out)
        self.dr.sync_thread()
        return out

    def numpy(self, out):
        return [np.array(v).reshape(self.shape) for v in out]


def colour_tmm(layers, lam, theta, scale):
    from colour.phenomena import multilayer_tmm

    n = [1.0] + [complex(v) for v, _ in layers] + [SUBSTRATE]
    t = np.array([d for _, d in layers])[None, :] * scale[:, None]  # (T, L): colour's thickness sweep
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return multilayer_tmm(n, t, lam, theta)  # R, T each (W, A, T, [s, p])


def tmm_subset(layers, points):
    import tmm

    n_list = [1.0] + [complex(v) for v, _ in layers] + [SUBSTRATE]
    out = []
    for lam, theta, scale in points:
        d_list = [np.inf] + [d * scale for _, d in layers] + [np.inf]
        row = []
        for pol in "sp":
            res = tmm.coh_tmm(pol, n_list, d_list, np.radians(theta), lam)
            row += [res["R"], res["T"]]
        out.append(row)
    return np.array(out)  # (points, [R_s, T_s, R_p, T_p])


def timed(fn, *args):
    t0 = time.perf_counter()
    out = fn(*args)
    return time.perf_counter() - t0, out


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--tmm-samples", type=int, default=300)
    ap.add_argument("--quick", action="store_true", help="a smaller grid (a smoke run)")
    args = ap.parse_args()

    import drjit as dr

    import thinfilm  # noqa: F401  (points Dr.Jit at a working libLLVM)

    lam, theta, scale = grid(args.quick)
    n_eval = lam.size * theta.size * scale.size
    rng = np.random.default_rng(0)
    idx = rng.integers(0, [lam.size, theta.size, scale.size], size=(args.tmm_samples, 3))
    points = [(lam[i], theta[j], scale[k]) for i, j, k in idx]
    drjit_eval = OursDrJit(lam, theta, scale)
    print(f"grid: {lam.size} wavelengths x {theta.size} angles x {scale.size} thickness scales "
          f"= {n_eval} evaluations of (R_s, R_p, T_s, T_p); median of {args.repeats} interleaved repeats")
    print(f"NumPy on one thread; Dr.Jit LLVM on {dr.thread_count()} threads; tmm timed on "
          f"{args.tmm_samples} random grid points (both polarizations) and scaled to the grid")

    for name, layers in STACKS.items():
        t_compile, _ = timed(drjit_eval, layers)  # warm-up: trace and compile
        colour_tmm(layers, lam[:2], theta[:2], scale[:2])  # warm-up: imports
        tmm_subset(layers, points[:2])
        times = {"ours NumPy": [], "ours Dr.Jit LLVM f64": [], "colour multilayer_tmm": [],
                 "tmm (scaled)": []}
        for _ in range(args.repeats):
            t, ours = timed(ours_numpy, layers, lam, theta, scale)
            times["ours NumPy"].append(t)
            t, jit = timed(drjit_eval, layers)
            times["ours Dr.Jit LLVM f64"].append(t)
            t, (R_c, T_c) = timed(colour_tmm, layers, lam, theta, scale)
            times["colour multilayer_tmm"].append(t)
            t, ref = timed(tmm_subset, layers, points)
            times["tmm (scaled)"].append(t * n_eval / len(points))

        R_s, R_p, T_s, T_p = ours
        jit = drjit_eval.numpy(jit)
        d_jit = max(np.abs(a - b).max() for a, b in zip(ours, jit))
        finite = np.isfinite(R_c[..., 0]) & np.isfinite(R_c[..., 1])
        d_colour = max(np.abs(R_s - R_c[..., 0])[finite].max(), np.abs(R_p - R_c[..., 1])[finite].max())
        colour_note = "" if finite.all() else f" where finite ({100 * (1 - finite.mean()):.0f} % NaN)"
        sub = tuple(np.array(v) for v in (idx[:, 0], idx[:, 1], idx[:, 2]))
        d_tmm = max(np.abs(R_s[sub] - ref[:, 0]).max(), np.abs(T_s[sub] - ref[:, 1]).max(),
                    np.abs(R_p[sub] - ref[:, 2]).max(), np.abs(T_p[sub] - ref[:, 3]).max())
        base = statistics.median(times["ours NumPy"])
        print(f"\n{name}: max |Δ| vs tmm {d_tmm:.1e}, vs colour (R) {d_colour:.1e}{colour_note}, "
              f"Dr.Jit vs NumPy {d_jit:.1e}; Dr.Jit first call (trace + compile) {t_compile * 1e3:.0f} ms")
        for method, ts in times.items():
            med = statistics.median(ts)
            print(f"  {method:24s} {med * 1e3:10.1f} ms   {med / base:8.2f} x ours NumPy   "
                  f"{med / n_eval * 1e9:9.1f} ns/evaluation")


if __name__ == "__main__":
    main()
