"""Dataset sweeps: a scene spec in which any value may be a distribution.

A sweep file is a scene spec (TOML, the keys of :mod:`.spec`) where any value may instead be
a one-key table naming a distribution::

    seed = 0                                          # optional; see "Noise seeds" below
    [shape]
    kind = { choice = ["hemisphere", "cylinder"] }
    [film]
    ior = { uniform = [1.30, 1.50] }
    [film.thickness]
    profile = "uniform"
    value = { normal = [450.0, 60.0], round = 1 }     # round: decimals kept
    [rig]
    resolution = 128

=================================  ===========================================================
distribution                       draws
=================================  ===========================================================
``{ uniform = [a, b] }``           a float in [a, b)
``{ loguniform = [a, b] }``        a float whose logarithm is uniform (0 < a < b)
``{ normal = [mu, sigma] }``       a float from the normal distribution
``{ lognormal = [mu, sigma] }``    ``exp`` of a normal draw (mu, sigma of the logarithm)
``{ integers = [a, b] }``          a whole number from a to b, both included
``{ choice = [v1, v2, ...] }``     one of the values, equally likely; a value may be a table
                                   or a list, and may hold distributions itself
=================================  ===========================================================

A distribution table may add ``round = N`` (decimals kept after drawing a float).

Determinism
-----------
Dataset ``i`` of a sweep with seed ``S`` depends on ``(sweep, S, i)`` only: each distribution
draws from its own generator, seeded by ``numpy.random.SeedSequence(S, spawn_key=(i,
crc32(path)))`` where ``path`` names the value (``film.thickness.value``; inside a chosen
table, the table's path and the key). So the same sweep and seed give the same specs in any
order, on any machine, with any number of datasets drawn, and adding a distribution to a sweep
does not change the draws of the others.

Noise seeds
-----------
The scene spec's ``seed`` (the camera noise) is drawn like the rest when it is a distribution,
kept when it is a number, and otherwise derived from ``(S, i)`` (a 31-bit whole number), so
each dataset gets its own noise.

Examples
--------
>>> sweep = {"film": {"ior": {"uniform": [1.3, 1.5]}, "thickness": {"value": {"integers": [300, 600]}}}}
>>> a, da = draw(sweep, seed=7, index=3)
>>> b, db = draw(sweep, seed=7, index=3)
>>> a == b and list(da) == ["seed", "film.ior", "film.thickness.value"]
True
>>> 1.3 <= da["film.ior"] < 1.5 and 300 <= da["film.thickness.value"] <= 600
True
"""

from __future__ import annotations

import copy
import math
import zlib

import numpy as np

from thinfilm.core.errors import UserError

__all__ = ["DISTRIBUTIONS", "is_distribution", "check_sweep", "draw", "sweep_spec", "folder_name"]

#: distribution name → number of parameters (None: a non-empty list of values)
DISTRIBUTIONS = {"uniform": 2, "loguniform": 2, "normal": 2, "lognormal": 2, "integers": 2, "choice": None}


def is_distribution(value) -> bool:
    """Whether ``value`` is a distribution table (one distribution key, optionally ``round``)."""
    if not isinstance(value, dict):
        return False
    names = [k for k in value if k in DISTRIBUTIONS]
    return len(names) == 1 and all(k in DISTRIBUTIONS or k == "round" for k in value)


def _number(v):
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def _check(value, path: str, where: str) -> None:
    if is_distribution(value):
        name = next(k for k in value if k in DISTRIBUTIONS)
        args = value[name]
        if name == "choice":
            if not isinstance(args, list) or not args:
                raise UserError(f"{where}: '{path}': choice needs a non-empty list of values, got {args!r}")
            for i, v in enumerate(args):
                _check(v, f"{path}[{i}]", where)
        else:
            if not isinstance(args, list) or len(args) != 2 or not all(_number(a) for a in args):
                raise UserError(f"{where}: '{path}': {name} needs two numbers [a, b], got {args!r}")
            a, b = args
            if name in ("uniform", "loguniform", "integers") and not a <= b:
                raise UserError(f"{where}: '{path}': {name} needs a <= b, got {args!r}")
            if name == "loguniform" and not a > 0:
                raise UserError(f"{where}: '{path}': loguniform needs 0 < a, got {args!r}")
            if name in ("normal", "lognormal") and not b >= 0:
                raise UserError(f"{where}: '{path}': {name} needs sigma >= 0, got {args!r}")
            if name == "integers" and not all(float(x).is_integer() for x in args):
                raise UserError(f"{where}: '{path}': integers needs whole numbers, got {args!r}")
        if "round" in value:
            r = value["round"]
            if isinstance(r, bool) or not isinstance(r, int) or r < 0:
                raise UserError(f"{where}: '{path}': round must be a whole number >= 0, got {r!r}")
        return
    if isinstance(value, dict):
        for k, v in value.items():
            _check(v, f"{path}.{k}" if path else str(k), where)
    elif isinstance(value, list):
        for i, v in enumerate(value):
            _check(v, f"{path}[{i}]", where)


def check_sweep(sweep: dict, where: str = "sweep") -> None:
    """Check every distribution of a sweep; one-line :class:`UserError` naming the value."""
    if not isinstance(sweep, dict):
        raise UserError(f"{where}: a sweep must be a table")
    _check(sweep, "", where)


def _rng(seed: int, index: int, path: str):
    ss = np.random.SeedSequence(int(seed), spawn_key=(int(index), zlib.crc32(path.encode("utf-8"))))
    return np.random.default_rng(ss)


def _sample(dist: dict, rng):
    name = next(k for k in dist if k in DISTRIBUTIONS)
    args = dist[name]
    if name == "choice":
        return copy.deepcopy(args[int(rng.integers(len(args)))])
    a, b = (float(x) for x in args)
    if name == "uniform":
        v = float(rng.uniform(a, b))
    elif name == "loguniform":
        v = float(math.exp(rng.uniform(math.log(a), math.log(b))))
    elif name == "normal":
        v = float(rng.normal(a, b))
    elif name == "lognormal":
        v = float(math.exp(rng.normal(a, b)))
    else:  # integers
        return int(rng.integers(int(a), int(b) + 1))
    if "round" in dist:
        v = round(v, int(dist["round"]))
    return v


def _record(value):
    """A drawn value as an index cell: numbers, strings and booleans as themselves, tables
    and lists as compact JSON."""
    if isinstance(value, (dict, list)):
        import json

        return json.dumps(value, sort_keys=True, separators=(",", ":"))
    return value


def _resolve(value, path: str, seed: int, index: int, drawn: dict):
    if is_distribution(value):
        v = _sample(value, _rng(seed, index, path))
        drawn[path] = _record(v)
        return _resolve(v, path, seed, index, drawn)  # a chosen table may hold distributions
    if isinstance(value, dict):
        return {k: _resolve(v, f"{path}.{k}" if path else str(k), seed, index, drawn) for k, v in value.items()}
    if isinstance(value, list):
        return [_resolve(v, f"{path}[{i}]", seed, index, drawn) for i, v in enumerate(value)]
    return value


def draw(sweep: dict, seed: int, index: int):
    """The raw scene spec of dataset ``index`` and the values drawn for it.

    Returns
    -------
    spec : dict
        The sweep with every distribution replaced by its draw (load it with
        :func:`sweep_spec`).
    drawn : dict
        ``{path: value}`` in the order drawn, ``seed`` first (the noise seed, see the
        module docstring).
    """
    drawn: dict = {"seed": None}
    spec = _resolve(sweep, "", seed, index, drawn)
    if "seed" not in sweep:
        spec["seed"] = int(np.random.SeedSequence(int(seed), spawn_key=(int(index), zlib.crc32(b"seed")))
                           .generate_state(1, np.uint32)[0] >> 1)
    drawn["seed"] = spec.get("seed")
    return spec, drawn


def sweep_spec(raw: dict, source: str, base_dir):
    """A :class:`~.spec.SceneSpec` from a drawn raw spec; relative paths (meshes, bitmaps,
    camera files) are taken from ``base_dir``, the sweep file's folder."""
    from .spec import SceneSpec
    from .spec_schema import Checker, resolve

    return SceneSpec.from_dict(resolve(copy.deepcopy(raw), Checker(source, base_dir)), source)


def folder_name(index: int, count: int) -> str:
    """``NNNN``: the dataset's index, zero-padded to at least 4 digits (more for larger counts).

    >>> folder_name(7, 10), folder_name(7, 123456)
    ('0007', '000007')
    """
    return f"{int(index):0{max(4, len(str(max(int(count) - 1, 0))))}d}"
