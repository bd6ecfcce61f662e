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
        "normal_error_deg": 3.0, "thickness_error_nm": 114.8, "delta_e_ab": 9.27, "film_ior_error": 0.005, "coverage": 0.95,
        "measured": {"normal_error_deg": 1.6333, "thickness_error_nm": 75.8535, "delta_e_ab": 6.0412, "film_ior_error": 0.0, "coverage": 1.0}},
    ('hemisphere', 'rgb', 'coherent'): {
        "normal_error_deg": 1.5, "thickness_error_nm": 3.0, "delta_e_ab": 1.69, "film_ior_error": 0.005, "coverage": 0.95,
        "measured": {"normal_error_deg": 0.6578, "thickness_error_nm": 1.2986, "delta_e_ab": 0.9923, "film_ior_error": 0.0, "coverage": 1.0}},
    ('cylinder', 'rgb', 'kobayashi2023'): {
        "normal_error_deg": 3.2, "thickness_error_nm": 47.5, "delta_e_ab": 3.37, "film_ior_error": 0.005, "coverage": 0.95,
        "measured": {"normal_error_deg": 1.7644, "thickness_error_nm": 30.9709, "delta_e_ab": 2.1094, "film_ior_error": 0.0, "coverage": 1.0}},
    ('cylinder', 'rgb', 'coherent'): {
        "normal_error_deg": 1.8, "thickness_error_nm": 3.5, "delta_e_ab": 1.56, "film_ior_error": 0.005, "coverage": 0.95,
        "measured": {"normal_error_deg": 0.8103, "thickness_error_nm": 1.6192, "delta_e_ab": 0.9061, "film_ior_error": 0.0, "coverage": 1.0}},
    ('pyramid', 'rgb', 'kobayashi2023'): {
        "normal_error_deg": 0.9, "thickness_error_nm": 2.2, "delta_e_ab": 0.72, "film_ior_error": 0.005, "coverage": 0.95,
        "measured": {"normal_error_deg": 0.2513, "thickness_error_nm": 0.7786, "delta_e_ab": 0.3449, "film_ior_error": 0.0, "coverage": 1.0}},
    ('pyramid', 'rgb', 'coherent'): {
        "normal_error_deg": 0.9, "thickness_error_nm": 2.0, "delta_e_ab": 0.63, "film_ior_error": 0.005, "coverage": 0.95,
        "measured": {"normal_error_deg": 0.227, "thickness_error_nm": 0.6613, "delta_e_ab": 0.2861, "film_ior_error": 0.0, "coverage": 1.0}},
    ('hemisphere', 'spectral', 'eikonal'): {
        "normal_error_deg": 2.7, "thickness_error_nm": 3.0, "delta_e_ab": 0.74, "film_ior_error": 0.006, "coverage": 0.95,
        "measured": {"normal_error_deg": 1.4624, "thickness_error_nm": 1.3313, "delta_e_ab": 0.3595, "film_ior_error": 0.0002, "coverage": 1.0}},
    ('hemisphere', 'spectral', 'kobayashi'): {
        "normal_error_deg": 6.6, "thickness_error_nm": 57.9, "delta_e_ab": 21.78, "film_ior_error": 0.005, "coverage": 0.74,
        "measured": {"normal_error_deg": 4.0484, "thickness_error_nm": 37.8799, "delta_e_ab": 14.3805, "film_ior_error": 0.0, "coverage": 0.795}},
    ('cylinder', 'spectral', 'eikonal'): {
        "normal_error_deg": 3.4, "thickness_error_nm": 2.0, "delta_e_ab": 0.74, "film_ior_error": 0.006, "coverage": 0.95,
        "measured": {"normal_error_deg": 1.9308, "thickness_error_nm": 0.6424, "delta_e_ab": 0.3569, "film_ior_error": 0.0002, "coverage": 1.0}},
    ('cylinder', 'spectral', 'kobayashi'): {
        "normal_error_deg": 6.1, "thickness_error_nm": 58.4, "delta_e_ab": 23.28, "film_ior_error": 0.005, "coverage": 0.91,
        "measured": {"normal_error_deg": 3.6794, "thickness_error_nm": 38.257, "delta_e_ab": 15.3822, "film_ior_error": 0.0, "coverage": 0.9638}},
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
