"""Refractive-index dispersion: constant, Cauchy, and tabulated named materials.

Every model is a callable ``n(wavelength_nm)`` that works on NumPy arrays and on
Dr.Jit / Mitsuba arrays (so the plugin can evaluate it inside a traced kernel).

Named materials ship as CSV tables in ``thinfilm_bsdf/data/`` (columns
``wavelength_nm, n, k`` on a uniform grid); each file's header names the source
of its numbers. :func:`material_names` lists them.

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

import functools
from dataclasses import dataclass, field
from importlib import resources

import numpy as np

from .optics import NUMPY_OPS, ops_for

__all__ = [
    "Constant",
    "Cauchy",
    "Tabulated",
    "Layer",
    "named_material",
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


def material_names() -> list[str]:
    """Names of the tabulated materials that ship with the package."""
    files = resources.files(__package__).joinpath("data")
    return sorted(p.name[:-4] for p in files.iterdir() if p.name.endswith(".csv"))


@functools.lru_cache(maxsize=None)
def named_material(name: str) -> Tabulated:
    """Load a shipped material table by name (case-insensitive), e.g. ``"MgF2"``, ``"PET"``."""
    lookup = {m.lower(): m for m in material_names()}
    key = lookup.get(str(name).lower())
    if key is None:
        raise ValueError(
            f"unknown material {name!r}: expected a number or one of {', '.join(material_names())}"
        )
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
