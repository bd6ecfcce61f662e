"""Refractive-index dispersion: constant, Cauchy, and tabulated named materials.

Every model is a callable ``n(wavelength_nm)`` that works on NumPy arrays and on
Dr.Jit / Mitsuba arrays (so the plugin can evaluate it inside a traced kernel).

Named materials ship as CSV tables in ``thinfilm_bsdf/data/`` (columns
``wavelength_nm, n, k`` on a uniform grid); each file's header names the source
of its numbers. :func:`material_names` lists them.

Examples
--------
>>> m = named_material("MgF2")
>>> round(float(m(550.0)), 4)
1.3785
>>> round(float(Cauchy(1.5, 0.004)(500.0)), 4)
1.516
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from importlib import resources

import numpy as np

from .optics import _NUMPY, _ops_for

__all__ = ["Constant", "Cauchy", "Tabulated", "named_material", "material_names", "as_dispersion"]


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
    n_values: tuple
    k_values: tuple

    def _interp(self, values, wavelength_nm):
        ops = _ops_for(wavelength_nm)
        if ops is _NUMPY:
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
    """A dispersion model from a number, a material name, a model, or a ``{"cauchy": [A, B, C]}`` table."""
    if isinstance(value, (Constant, Cauchy, Tabulated)):
        return value
    if isinstance(value, str):
        try:
            return Constant(float(value))
        except ValueError:
            return named_material(value)
    if isinstance(value, dict) and "cauchy" in value:
        return Cauchy(*[float(c) for c in value["cauchy"]])
    if isinstance(value, (int, float, np.floating, np.integer)) and not isinstance(value, bool):
        return Constant(float(value))
    raise ValueError(f"refractive index {value!r}: expected a number, a material name or {{cauchy = [A, B, C]}}")
