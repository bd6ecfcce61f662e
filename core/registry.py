"""The estimator registry: every reconstruction method, built-in or third-party, as a record.

In the spirit of colour-science's ``*_METHODS`` mappings, each method is a :class:`Method`
record (name, kind ``rgb`` | ``spectral``, role, aliases, what it needs from a dataset,
whether it estimates the film index) around one function with one call signature for every
kind::

    def estimator(dataset: thinfilm.core.io.Dataset, options: thinfilm.core.registry.Options)
            -> thinfilm.core.io.Estimate

``reconstruct``, ``evaluate``, ``benchmark`` and the regression suite find methods here, in
Python.

Where methods come from
-----------------------
* **Entry points** of the group ``thinfilm.estimators`` (:data:`ENTRY_POINT_GROUP`): each
  names a :class:`Method`, a list of them, or a function decorated with :func:`estimator`.
  The built-in methods are registered this way too (``pyproject.toml``), so that this layer
  never imports the reconstruction package.
* **A path** ``package.module:function`` given as the method name (``--method``): the
  function is loaded on demand; decorated with :func:`estimator` it brings its record,
  otherwise it gets one named after the path, of the kind asked for.
* :func:`register` for methods made at run time.

Examples
--------
>>> @estimator("flat-demo", kind="rgb", needs=("polarized_rgb",))
... def flat(dataset, options):
...     ...
>>> flat.method.name, flat.method.kind, flat.method.role
('flat-demo', 'rgb', 'other')
"""

from __future__ import annotations

import importlib
import threading
from dataclasses import dataclass, field, replace
from typing import Callable

from .errors import NoResultError, UserError

__all__ = [
    "ENTRY_POINT_GROUP",
    "KINDS",
    "Method",
    "Option",
    "Options",
    "parse_options",
    "estimator",
    "register",
    "methods",
    "get",
    "resolve",
    "run",
]

ENTRY_POINT_GROUP = "thinfilm.estimators"
KINDS = ("rgb", "spectral")
#: dataset parts a method may need (the parts of :func:`thinfilm.core.io.read_dataset`)
PARTS = ("polarized_rgb", "spectral_s", "stokes")
PART_FILES = {"polarized_rgb": "polarized_rgb.exr", "spectral_s": "spectral_s.exr", "stokes": "stokes_spectral.exr"}


#: the types a method option may have, by the name ``thinfilm methods --json`` gives them
OPTION_TYPES = {"int": int, "float": float, "bool": bool, "str": str}
_TRUE, _FALSE = ("1", "true", "yes", "on"), ("0", "false", "no", "off")


@dataclass(frozen=True)
class Option:
    """One tuning option a method declares (``reconstruct … --option NAME=VALUE``).

    Attributes
    ----------
    name : the key (letters, digits, ``_``).
    type : ``int``, ``float``, ``bool`` or ``str``.
    default : the value the method uses when the option is not set.
    help : one line: what it does, with its unit.
    minimum, maximum : bounds of a number (inclusive), None for none.
    choices : the allowed values of a ``str`` option (empty: any).
    """

    name: str
    type: type
    default: object
    help: str = ""
    minimum: float | None = None
    maximum: float | None = None
    choices: tuple = ()

    def __post_init__(self):
        if self.type not in OPTION_TYPES.values():
            raise ValueError(f"option {self.name!r}: type must be one of int, float, bool, str")
        if not self.name.replace("_", "a").isalnum() or not self.name[:1].isalpha():
            raise ValueError(f"option {self.name!r}: names are letters, digits and '_'")

    def convert(self, value):
        """``value`` (a string from the command line, or a Python value) as the option's type,
        checked; :class:`UserError` when it is not one."""
        t = self.type
        try:
            if isinstance(value, str):
                text = value.strip()
                if t is bool:
                    if text.lower() not in _TRUE + _FALSE:
                        raise ValueError
                    out = text.lower() in _TRUE
                else:
                    out = t(text)
            elif t is bool:
                if not isinstance(value, bool):
                    raise ValueError
                out = value
            elif t is float and isinstance(value, (int, float)) and not isinstance(value, bool):
                out = float(value)
            elif isinstance(value, t) and not isinstance(value, bool):
                out = value
            else:
                raise ValueError
        except (TypeError, ValueError):
            raise UserError(f"{self.name}: expected {self.describe()}, got {value!r}", argument="options") from None
        if t in (int, float):
            import math

            if not math.isfinite(out) or (self.minimum is not None and out < self.minimum) or \
                    (self.maximum is not None and out > self.maximum):
                raise UserError(f"{self.name}: expected {self.describe()}, got {value!r}", argument="options")
        if self.choices and out not in self.choices:
            raise UserError(f"{self.name}: expected {self.describe()}, got {value!r}", argument="options")
        return out

    def describe(self) -> str:
        """What the option takes, in words (``a number from 0 to 1``)."""
        if self.choices:
            return "one of " + ", ".join(map(str, self.choices))
        word = {int: "a whole number", float: "a number", bool: "true or false", str: "a word"}[self.type]
        lo, hi = self.minimum, self.maximum
        if lo is not None and hi is not None:
            return f"{word} from {lo:g} to {hi:g}"
        if lo is not None:
            return f"{word} >= {lo:g}"
        if hi is not None:
            return f"{word} <= {hi:g}"
        return word

    def as_dict(self) -> dict:
        """JSON-ready description (``thinfilm methods --json``)."""
        return {"name": self.name, "type": self.type.__name__, "default": self.default, "help": self.help,
                "minimum": self.minimum, "maximum": self.maximum, "choices": list(self.choices)}


@dataclass(frozen=True)
class Method:
    """One reconstruction method.

    Attributes
    ----------
    name : the registry name (``--method``).
    kind : ``"rgb"`` (polarized camera RGB) or ``"spectral"`` (hyperspectral).
    function : ``function(dataset, options) -> Estimate``.
    role : ``"paper"`` (a published method as published), ``"default"`` (the one
        ``reconstruct KIND`` runs without ``--method``), or anything else (``"other"``).
    aliases : other names accepted for it.
    needs : dataset parts that must be present (``polarized_rgb``, ``spectral_s``, ``stokes``).
    uses : parts read when present.
    estimates_film_ior : whether the method estimates the film index (else it takes it as
        input, from ``--film-ior`` or ``meta.json``).
    source : where it comes from (``"thinfilm"``, a distribution name, or a module path).
    description : one line for ``thinfilm methods``.
    options : the :class:`Option` records of its tuning options (``--option NAME=VALUE``);
        the function finds their values, defaults filled in, in ``options.method_options``.
    """

    name: str
    kind: str
    function: Callable = field(repr=False, compare=False)
    role: str = "other"
    aliases: tuple = ()
    needs: tuple = ()
    uses: tuple = ()
    estimates_film_ior: bool = False
    source: str = ""
    description: str = ""
    options: tuple = ()

    def __post_init__(self):
        if self.kind not in KINDS:
            raise ValueError(f"method {self.name!r}: kind must be one of {KINDS}, got {self.kind!r}")
        bad = [p for p in (*self.needs, *self.uses) if p not in PARTS]
        if bad:
            raise ValueError(f"method {self.name!r}: unknown dataset parts {bad}, expected some of {PARTS}")
        if not all(isinstance(o, Option) for o in self.options):
            raise ValueError(f"method {self.name!r}: options must be thinfilm Option records")
        names = [o.name for o in self.options]
        if len(set(names)) != len(names):
            raise ValueError(f"method {self.name!r}: two options have the same name")

    def option_values(self, given=None) -> dict:
        """Every declared option's value: ``given`` (name → value, strings accepted) over the
        defaults; :class:`UserError` for an unknown name or a bad value."""
        declared = {o.name: o for o in self.options}
        out = {o.name: o.default for o in self.options}
        for name, value in dict(given or {}).items():
            if name not in declared:
                known = ", ".join(sorted(declared)) or "none"
                raise UserError(f"method {self.name!r} has no option {name!r} (its options: {known})",
                                argument="options")
            out[name] = declared[name].convert(value)
        return out

    def as_dict(self) -> dict:
        """JSON-ready description (``thinfilm methods --json``)."""
        return {"name": self.name, "kind": self.kind, "role": self.role, "aliases": list(self.aliases),
                "needs": list(self.needs), "uses": list(self.uses),
                "estimates_film_ior": self.estimates_film_ior, "source": self.source,
                "description": self.description, "options": [o.as_dict() for o in self.options]}


@dataclass
class Options:
    """What every estimator is given besides the dataset.

    Attributes
    ----------
    film : :class:`thinfilm.core.film.Film`
        The film as known: from ``meta.json`` with the command line's ``--film-ior`` and
        ``--substrate-ior`` applied. Methods that estimate the film index use only its
        substrate (and exterior medium).
    mask : (H, W) bool or None
        The pixels to reconstruct, when given (``--mask``); else the method finds the object.
    thickness_range_nm : (min, max) or None
        The prior thickness range (``--thickness-range``), None for the method's default.
    progress : bool
        Whether to show progress bars (on a terminal).
    method_options : dict
        The values of the method's declared :class:`Option` records (defaults filled in by
        :func:`run`).
    """

    film: object = None
    mask: object = None
    thickness_range_nm: tuple | None = None
    progress: bool = False
    method_options: dict = field(default_factory=dict)


def parse_options(items) -> dict:
    """``NAME=VALUE`` strings (``--option``, repeatable) as a dict of strings; one-line
    :class:`UserError` for a malformed item or a name given twice."""
    out = {}
    for item in items or ():
        name, sep, value = str(item).partition("=")
        name = name.strip()
        if not sep or not name or not name.replace("_", "a").isalnum() or not value.strip():
            raise UserError(f"expected NAME=VALUE, got {item!r}", argument="options")
        if name in out:
            raise UserError(f"{name!r} is given twice", argument="options")
        out[name] = value.strip()
    return out


def estimator(name: str, kind: str, role: str = "other", aliases=(), needs=(), uses=(),
              estimates_film_ior: bool = False, description: str = "", options=()):
    """Decorator attaching a :class:`Method` record to an estimator function (as
    ``function.method``); point an entry point of :data:`ENTRY_POINT_GROUP` at the function
    to register it."""

    def wrap(function):
        source = getattr(function, "__module__", "") or ""
        function.method = Method(name, kind, function, role, tuple(aliases), tuple(needs), tuple(uses),
                                 bool(estimates_film_ior), source,
                                 description or (function.__doc__ or "").strip().split("\n")[0], tuple(options))
        return function

    return wrap


_LOCK = threading.RLock()
_REGISTERED: dict = {}        # (kind, name) -> Method, from register()
_DISCOVERED: dict | None = None
_PROBLEMS: list = []          # entry points that failed to load: (name, message)


def register(method: Method) -> Method:
    """Add ``method`` to the registry (replacing one of the same kind and name)."""
    with _LOCK:
        _REGISTERED[(method.kind, method.name)] = method
    return method


def _records(obj, source: str):
    if isinstance(obj, Method):
        return [obj]
    if callable(obj) and isinstance(getattr(obj, "method", None), Method):
        return [obj.method]
    if isinstance(obj, (list, tuple)):
        return [m for item in obj for m in _records(item, source)]
    raise TypeError(f"expected a thinfilm Method, a list of them or an @estimator function, "
                    f"got {type(obj).__name__}")


def _discover() -> dict:
    """Load the entry points of :data:`ENTRY_POINT_GROUP` once."""
    global _DISCOVERED
    with _LOCK:
        if _DISCOVERED is not None:
            return _DISCOVERED
        from importlib import metadata

        found = {}
        for ep in sorted(metadata.entry_points(group=ENTRY_POINT_GROUP), key=lambda e: e.name):
            dist = getattr(ep, "dist", None)
            source = dist.metadata["Name"] if dist is not None else ep.value
            try:
                recs = _records(ep.load(), source)
            except Exception as e:  # a broken third-party package must not break the others
                _PROBLEMS.append((ep.name, f"{ep.value}: {type(e).__name__}: {e}".splitlines()[0]))
                continue
            for m in recs:
                found.setdefault((m.kind, m.name), replace(m, source=source))
        _DISCOVERED = found
        return found


def problems() -> list:
    """Entry points that could not be loaded: ``[(name, message)]``."""
    _discover()
    return list(_PROBLEMS)


def methods(kind: str | None = None) -> list:
    """Every registered method (of ``kind``), built-in ones first, then by kind and name."""
    found = dict(_discover())
    with _LOCK:
        found.update(_REGISTERED)
    out = [m for m in found.values() if kind is None or m.kind == kind]
    return sorted(out, key=lambda m: (m.source != "thinfilm", KINDS.index(m.kind), m.name))


def _from_path(path: str, kind: str) -> Method:
    module_name, _, attr = path.partition(":")
    try:
        module = importlib.import_module(module_name)
    except Exception as e:
        raise UserError(f"cannot import module {module_name!r} ({type(e).__name__}: {e})", argument="method", value=path) from None
    obj = getattr(module, attr, None)
    if obj is None:
        raise UserError(f"module {module_name!r} has no {attr!r}", argument="method", value=path)
    if isinstance(obj, Method) or isinstance(getattr(obj, "method", None), Method):
        m = _records(obj, path)[0]
        if m.kind != kind:
            raise UserError(f"a {m.kind} method, not a {kind} one", argument="method", value=path)
        return m
    if not callable(obj):
        raise UserError(f"{attr!r} is not callable", argument="method", value=path)
    return Method(path, kind, obj, source=module_name, description=(obj.__doc__ or "").strip().split("\n")[0])


def get(kind: str, name: str | None = None) -> Method:
    """The method ``name`` (or an alias, or ``package.module:function``) of ``kind``; the
    kind's default when ``name`` is None. :class:`UserError` when unknown."""
    if kind not in KINDS:
        raise UserError(f"unknown reconstruction kind {kind!r}, expected one of {', '.join(KINDS)}")
    candidates = methods(kind)
    if name is None:
        defaults = [m for m in candidates if m.role == "default"]
        if not defaults:
            raise UserError(f"no default {kind} method is registered")
        return defaults[0]
    for m in candidates:
        if m.name == name:
            return m
    for m in candidates:
        if name in m.aliases:
            return m
    if ":" in name:
        return _from_path(name, kind)
    names = sorted({m.name for m in candidates} | {a for m in candidates for a in m.aliases})
    other = [m.name for m in methods() if m.kind != kind and (m.name == name or name in m.aliases)]
    hint = f" ({name!r} is a {', '.join(m.kind for m in methods() if m.name in other)} method)" if other else ""
    raise UserError(f"unknown {kind} method {name!r}{hint}, expected one of {', '.join(names)} "
                    f"or package.module:function", argument="method")


def resolve(names, kind: str | None = None) -> list:
    """Methods for a list of names (any kind unless ``kind``): each name may match methods of
    several kinds (``paper`` is an alias in both)."""
    out = []
    for name in names:
        kinds = [kind] if kind else list(KINDS)
        hits = []
        for k in kinds:
            try:
                hits.append(get(k, name))
            except UserError:
                continue
        if not hits:
            get(kinds[0], name)  # raises the one-line error
        out.extend(h for h in hits if h not in out)
    return out


def run(method: Method, dataset, options: Options):
    """Call ``method`` on a dataset and check what it returns (an
    :class:`~thinfilm.core.io.Estimate` of the dataset's image size, with at least one valid
    pixel: else :class:`~thinfilm.core.errors.NoResultError`). The method's declared options
    get their defaults (and checks) here."""
    import time

    import numpy as np

    from .estimate import Estimate

    for part in method.needs:
        if not dataset.has(part):
            raise UserError(f"{dataset.path}: method {method.name!r} needs {PART_FILES[part]}, "
                            f"which the dataset does not hold")
    options = replace(options, method_options=method.option_values(options.method_options))
    t0 = time.perf_counter()
    est = method.function(dataset, options)
    if not isinstance(est, Estimate):
        raise TypeError(f"method {method.name!r} returned {type(est).__name__}, expected a thinfilm Estimate")
    shape = dataset.shape
    for name in ("normals", "thickness_nm", "valid"):
        arr = np.asarray(getattr(est, name))
        if arr.shape[:2] != tuple(shape):
            raise ValueError(f"method {method.name!r}: {name} has shape {arr.shape}, the images are {shape}")
    if not np.any(np.asarray(est.valid, dtype=bool)):
        reason = est.info.get("no_result_reason") if isinstance(est.info, dict) else None
        raise NoResultError(f"{dataset.path}: method {method.name!r} found no pixel it could reconstruct"
                            + (f" ({reason})" if reason else "") + "; nothing was written")
    est.info = dict(est.info)
    est.info["method"] = method.name
    est.info.setdefault("timings_s", {})
    est.info["timings_s"].setdefault("total", time.perf_counter() - t0)
    return est
