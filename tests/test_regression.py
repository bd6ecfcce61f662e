"""Regression suite: every reconstruction method scored on small rendered scenes.

Each (preset, kind, method) of the benchmark (:data:`thinfilm.benchmark.PRESET_KINDS`, the
paper and default methods of each ``thinfilm reconstruct`` kind) is run on a 48 px dataset of
the preset with its default camera noise (fixed seed, so the data are the same on every run),
re-rendered and scored by :func:`thinfilm.evaluation.evaluate`. The scores must stay within
the limits below: a change that makes an estimator worse fails CI.

The limits were set from the scores measured when each method was added, with headroom
(about 1.5x, plus a small absolute margin) for platform-dependent rounding in the renderer and
the solvers; ``measured`` records those scores. A method found in a registry without limits
here fails with its measured scores, so that new methods get limits rather than a free pass;
a reconstruction kind whose module is missing fails too (it is part of the project).
"""

from __future__ import annotations

import pytest

from thinfilm import benchmark

RESOLUTION = 48

# (preset, kind, method) -> limits on the mean errors over the object (and minimum coverage).
# "measured": the scores when the limits were set (48 px, default noise, seed 0).
LIMITS = {
    ('hemisphere', 'rgb', 'kobayashi2023'): {
        "normal_error_deg": 3.0, "thickness_error_nm": 114.9, "delta_e_ab": 9.3, "film_ior_error": 0.005, "coverage": 0.95,
        "measured": {"normal_error_deg": 1.6411, "thickness_error_nm": 75.9244, "delta_e_ab": 6.063, "film_ior_error": 0.0, "coverage": 1.0}},
    ('hemisphere', 'rgb', 'coherent'): {
        "normal_error_deg": 1.5, "thickness_error_nm": 3.1, "delta_e_ab": 1.74, "film_ior_error": 0.005, "coverage": 0.95,
        "measured": {"normal_error_deg": 0.665, "thickness_error_nm": 1.3573, "delta_e_ab": 1.0205, "film_ior_error": 0.0, "coverage": 1.0}},
    ('cylinder', 'rgb', 'kobayashi2023'): {
        "normal_error_deg": 3.3, "thickness_error_nm": 47.6, "delta_e_ab": 3.32, "film_ior_error": 0.005, "coverage": 0.95,
        "measured": {"normal_error_deg": 1.8103, "thickness_error_nm": 31.0335, "delta_e_ab": 2.0759, "film_ior_error": 0.0, "coverage": 1.0}},
    ('cylinder', 'rgb', 'coherent'): {
        "normal_error_deg": 1.9, "thickness_error_nm": 3.4, "delta_e_ab": 1.53, "film_ior_error": 0.005, "coverage": 0.95,
        "measured": {"normal_error_deg": 0.9068, "thickness_error_nm": 1.5613, "delta_e_ab": 0.8853, "film_ior_error": 0.0, "coverage": 1.0}},
    ('pyramid', 'rgb', 'kobayashi2023'): {
        "normal_error_deg": 0.9, "thickness_error_nm": 2.2, "delta_e_ab": 0.74, "film_ior_error": 0.005, "coverage": 0.95,
        "measured": {"normal_error_deg": 0.2501, "thickness_error_nm": 0.7953, "delta_e_ab": 0.3546, "film_ior_error": 0.0, "coverage": 1.0}},
    ('pyramid', 'rgb', 'coherent'): {
        "normal_error_deg": 0.9, "thickness_error_nm": 2.1, "delta_e_ab": 0.65, "film_ior_error": 0.005, "coverage": 0.95,
        "measured": {"normal_error_deg": 0.228, "thickness_error_nm": 0.6806, "delta_e_ab": 0.2984, "film_ior_error": 0.0, "coverage": 1.0}},
    ('hemisphere', 'spectral', 'eikonal'): {
        "normal_error_deg": 4.2, "thickness_error_nm": 4.4, "delta_e_ab": 0.76, "film_ior_error": 0.006, "coverage": 0.95,
        "measured": {"normal_error_deg": 2.4485, "thickness_error_nm": 2.2077, "delta_e_ab": 0.3696, "film_ior_error": 0.0002, "coverage": 1.0}},
    ('hemisphere', 'spectral', 'kobayashi'): {
        "normal_error_deg": 6.5, "thickness_error_nm": 56.7, "delta_e_ab": 21.31, "film_ior_error": 0.005, "coverage": 0.72,
        "measured": {"normal_error_deg": 3.9928, "thickness_error_nm": 37.0792, "delta_e_ab": 14.068, "film_ior_error": 0.0, "coverage": 0.7752}},
    ('cylinder', 'spectral', 'eikonal'): {
        "normal_error_deg": 3.7, "thickness_error_nm": 2.0, "delta_e_ab": 0.74, "film_ior_error": 0.006, "coverage": 0.95,
        "measured": {"normal_error_deg": 2.069, "thickness_error_nm": 0.6357, "delta_e_ab": 0.357, "film_ior_error": 0.0002, "coverage": 1.0}},
    ('cylinder', 'spectral', 'kobayashi'): {
        "normal_error_deg": 5.5, "thickness_error_nm": 55.1, "delta_e_ab": 22.41, "film_ior_error": 0.005, "coverage": 0.91,
        "measured": {"normal_error_deg": 3.3074, "thickness_error_nm": 36.0534, "delta_e_ab": 14.8054, "film_ior_error": 0.0, "coverage": 0.968}},
}

SCORED = ("normal_error_deg", "thickness_error_nm", "delta_e_ab", "film_ior_error", "coverage")


def _plan():
    cases = []
    for kind in ("rgb", "spectral"):
        try:
            methods = benchmark._selected_methods(kind)
        except Exception as e:  # reported by the test itself, never skipped
            cases.append(pytest.param("-", kind, None, str(e), id=f"{kind}-unavailable"))
            continue
        for preset, kinds in benchmark.PRESET_KINDS.items():
            if kind in kinds:
                for method in methods:
                    cases.append(pytest.param(preset, kind, method, None, id=f"{preset}-{kind}-{method}"))
    return cases


@pytest.fixture(scope="module")
def datasets(tmp_path_factory):
    """Generate each preset once per module (48 px, default camera noise, seed 0)."""
    made = {}

    def get(preset):
        if preset not in made:
            import mitsuba as mi

            from thinfilm.generators.generate import VARIANT, generate_dataset
            from thinfilm.generators.spec import load_spec

            mi.set_variant(VARIANT)
            out = tmp_path_factory.mktemp("regression") / preset
            generate_dataset(load_spec(preset, resolution=RESOLUTION, seed=0), out, progress=False)
            made[preset] = out
        return made[preset]

    return get


def _scores(result):
    m = result["metrics"]
    return {"normal_error_deg": m["normal_error_deg"]["mean"], "thickness_error_nm": m["thickness_error_nm"]["mean"],
            "delta_e_ab": m["delta_e_ab"]["mean"], "film_ior_error": m["film_ior_error"],
            "coverage": result["info"]["coverage"]}


@pytest.mark.slow
@pytest.mark.parametrize("preset, kind, method, unavailable", _plan())
def test_estimator_scores_within_limits(datasets, tmp_path, preset, kind, method, unavailable):
    assert unavailable is None, f"reconstruct {kind} cannot be benchmarked: {unavailable}"
    import mitsuba as mi

    from thinfilm import evaluation as ev

    ds = datasets(preset)
    benchmark._reconstruct(kind, ds, tmp_path / "est", method)
    mi.set_variant(ev.RENDER_VARIANT)
    scores = _scores(ev.evaluate(ds, tmp_path / "est"))
    limits = LIMITS.get((preset, kind, method))
    assert limits is not None, (f"no regression limits recorded for {(preset, kind, method)}; "
                                f"measured {scores}: add them to LIMITS in tests/test_regression.py")
    worse = []
    for key in SCORED:
        value, limit = scores[key], limits[key]
        if value is None:
            worse.append(f"{key}: no value")
        elif key == "coverage" and value < limit:
            worse.append(f"coverage {value:.3f} < {limit}")
        elif key != "coverage" and value > limit:
            worse.append(f"{key} {value:.4g} > {limit}")
    assert not worse, f"{preset} {kind} {method} got worse: {'; '.join(worse)} (all scores {scores})"
