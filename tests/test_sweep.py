"""``thinfilm generate --sweep``: distributions, determinism, the index, resume."""

from __future__ import annotations

import csv
import io
import math
import zlib

import numpy as np
import pytest

from thinfilm.cli import main
from thinfilm.core.errors import UserError
from thinfilm.generators import sweep as sw
from thinfilm.sweep import index_csv, load_sweep, plan_sweep, run_sweep

SWEEP = """
[shape]
kind = { choice = ["hemisphere", "cylinder"] }
[film]
ior = { uniform = [1.30, 1.45] }
[film.thickness]
profile = "uniform"
value = { normal = [450.0, 60.0], round = 1 }
[rig]
resolution = 16
wavelengths_nm = { start = 400.0, stop = 720.0, step = 16.0 }
"""


def test_each_distribution_draws_from_its_own_seeded_generator():
    sweep = {"a": {"uniform": [1.0, 2.0]}, "b": {"loguniform": [1.0, 100.0]}, "c": {"normal": [5.0, 2.0]},
             "d": {"lognormal": [0.0, 0.5]}, "e": {"integers": [3, 4]}, "f": {"choice": ["x", "y", "z"]},
             "g": {"uniform": [0.0, 1.0], "round": 2}, "h": 7}
    spec, drawn = sw.draw(sweep, seed=11, index=5)
    assert list(drawn) == ["seed", "a", "b", "c", "d", "e", "f", "g"] and spec["h"] == 7

    def rng(path):  # the documented seeding, written out
        return np.random.default_rng(np.random.SeedSequence(11, spawn_key=(5, zlib.crc32(path.encode()))))

    assert spec["a"] == rng("a").uniform(1.0, 2.0)
    assert spec["b"] == pytest.approx(math.exp(rng("b").uniform(0.0, math.log(100.0))), rel=1e-15)
    assert spec["c"] == rng("c").normal(5.0, 2.0)
    assert spec["d"] == pytest.approx(math.exp(rng("d").normal(0.0, 0.5)), rel=1e-15)
    assert spec["e"] == rng("e").integers(3, 5)
    assert spec["f"] == ["x", "y", "z"][rng("f").integers(3)]
    assert spec["g"] == round(rng("g").uniform(0.0, 1.0), 2)
    # the noise seed is derived from (seed, index) when the sweep gives none, kept when it does
    assert isinstance(spec["seed"], int) and 0 <= spec["seed"] < 2 ** 31
    assert sw.draw(dict(sweep, seed=3), 11, 5)[0]["seed"] == 3
    assert sw.draw(sweep, 11, 6)[0]["seed"] != spec["seed"]


def test_draws_depend_only_on_sweep_seed_and_index():
    sweep = {"film": {"ior": {"uniform": [1.3, 1.5]}}}
    more = {"film": {"ior": {"uniform": [1.3, 1.5]}, "thickness": {"value": {"uniform": [300.0, 600.0]}}}}
    values = [sw.draw(sweep, 4, i)[1]["film.ior"] for i in range(50)]
    assert len(set(values)) == 50 and all(1.3 <= v < 1.5 for v in values)
    # adding a distribution leaves the others' draws alone; other seeds differ
    assert [sw.draw(more, 4, i)[1]["film.ior"] for i in range(50)] == values
    assert sw.draw(sweep, 5, 0)[1]["film.ior"] != values[0]
    # the sample statistics are those asked for
    normals = [sw.draw({"x": {"normal": [10.0, 2.0]}}, 1, i)[0]["x"] for i in range(4000)]
    assert abs(np.mean(normals) - 10.0) < 0.15 and abs(np.std(normals) - 2.0) < 0.15
    ints = [sw.draw({"x": {"integers": [1, 3]}}, 1, i)[0]["x"] for i in range(600)]
    assert set(ints) == {1, 2, 3}


def test_a_chosen_table_may_hold_distributions():
    sweep = {"shape": {"choice": [{"kind": "hemisphere", "radius": {"uniform": [0.5, 1.0]}},
                                  {"kind": "cylinder", "length": {"integers": [2, 3]}}]}}
    kinds = set()
    for i in range(20):
        spec, drawn = sw.draw(sweep, 0, i)
        kinds.add(spec["shape"]["kind"])
        if spec["shape"]["kind"] == "hemisphere":
            assert 0.5 <= spec["shape"]["radius"] < 1.0 and drawn["shape.radius"] == spec["shape"]["radius"]
        else:
            assert spec["shape"]["length"] in (2, 3) and "shape.radius" not in drawn
        assert drawn["shape"].startswith('{"kind":')
        sw.sweep_spec(spec, "test", None)  # a valid scene spec
    assert kinds == {"hemisphere", "cylinder"}


@pytest.mark.parametrize("bad, message", [
    ({"x": {"uniform": [2.0, 1.0]}}, "a <= b"),
    ({"x": {"uniform": [1.0]}}, "two numbers"),
    ({"x": {"loguniform": [0.0, 1.0]}}, "0 < a"),
    ({"x": {"normal": [1.0, -1.0]}}, "sigma >= 0"),
    ({"x": {"integers": [1.5, 3]}}, "whole numbers"),
    ({"x": {"choice": []}}, "non-empty list"),
    ({"x": {"uniform": [0, 1], "round": -1}}, "round"),
    ({"a": {"b": {"choice": [{"normal": [0, -2]}]}}}, "'a.b\\[0\\]'"),
])
def test_bad_distributions_are_one_line_errors(bad, message):
    with pytest.raises(UserError, match=message) as e:
        sw.check_sweep(bad, "sweep.toml")
    assert "\n" not in str(e.value) and str(e.value).startswith("sweep.toml")


def test_index_lists_every_drawn_value_in_a_fixed_order(tmp_path):
    (tmp_path / "s.toml").write_text(SWEEP)
    sweep = load_sweep(tmp_path / "s.toml", overrides=["noise.bits=10"])
    assert sweep["noise"]["bits"] == 10
    plan = plan_sweep(sweep, seed=2, count=12)
    assert [p[0] for p in plan] == [f"{i:04d}" for i in range(12)]
    rows = list(csv.reader(io.StringIO(index_csv(plan))))
    assert rows[0] == ["index", "folder", "seed", "shape.kind", "film.ior", "film.thickness.value"]
    for row, (name, spec, drawn) in zip(rows[1:], plan):
        assert row[1] == name and int(row[2]) == spec.seed
        assert row[3] == spec.shape.kind and float(row[4]) == spec.film.effective_index()
        assert float(row[5]) == spec.thickness["value"]
    assert index_csv(plan) == index_csv(plan_sweep(sweep, seed=2, count=12))
    assert plan_sweep(sweep, 2, 20)[:12] == plan  # dataset i does not depend on the count


@pytest.mark.slow
def test_sweep_writes_datasets_and_index_and_resumes(tmp_path, capsys):
    (tmp_path / "s.toml").write_text(SWEEP)
    out = tmp_path / "out"
    args = ["generate", "--sweep", str(tmp_path / "s.toml"), "--count", "3", "--seed", "9", "--workers", "0",
            "--out", str(out)]
    assert main(args) == 0
    assert "3 generated" in capsys.readouterr().out
    names = sorted(p.name for p in out.iterdir())
    assert names == [".thinfilm-output", "0000", "0001", "0002", "index.csv", "sweep.json"]
    plan = plan_sweep(load_sweep(tmp_path / "s.toml"), 9, 3)
    for name, spec, _ in plan:
        assert (out / name / "scene.toml").read_text() == spec.to_toml()
    assert (out / "index.csv").read_text() == index_csv(plan)
    before = {p: p.read_bytes() for p in (out / "0001").iterdir()}
    # resume: a lost dataset is made again, byte for byte; the count may grow
    import shutil

    shutil.rmtree(out / "0001")
    stamp = (out / "0000" / "meta.json").stat().st_mtime_ns
    r = run_sweep(tmp_path / "s.toml", 4, 9, out, resume=True, workers=0)
    assert (r["generated"], r["resumed"], r["failed"]) == (2, 2, {})
    assert {p: p.read_bytes() for p in (out / "0001").iterdir()} == before
    assert (out / "0000" / "meta.json").stat().st_mtime_ns == stamp
    assert (out / "index.csv").read_text() == index_csv(plan_sweep(load_sweep(tmp_path / "s.toml"), 9, 4))
    # resuming with another seed is refused; without --resume the folder is replaced
    assert main(args[:-2] + ["--seed", "8", "--resume", "--out", str(out)]) == 2
    assert "another sweep or seed" in capsys.readouterr().err


def test_generate_arguments_are_checked(tmp_path, capsys):
    (tmp_path / "s.toml").write_text(SWEEP)
    cases = [
        (["generate", "--sweep", str(tmp_path / "s.toml"), "--out", str(tmp_path / "o")], "--count"),
        (["generate", "hemisphere", "--sweep", str(tmp_path / "s.toml"), "--count", "2", "--out",
          str(tmp_path / "o")], "not both"),
        (["generate", "--out", str(tmp_path / "o")], "scene spec"),
        (["generate", "hemisphere", "--count", "2", "--out", str(tmp_path / "o")], "--sweep only"),
        (["generate", "--sweep", str(tmp_path / "none.toml"), "--count", "2", "--out", str(tmp_path / "o")],
         "not found"),
    ]
    for args, message in cases:
        assert main(args) == 2, args
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and message in err, (args, err)
    assert not (tmp_path / "o").exists()
