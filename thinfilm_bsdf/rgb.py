"""Colour basis of the ``thinfilm`` BSDF in Mitsuba's RGB variants.

In a spectral variant Mitsuba renders a surface of reflectance ``R(λ)`` under an emitter of
RGB or float radiance as follows (``spectrum.h``, ``d65.cpp``, ``properties.cpp``, the films):

* the emitter's spectrum is the CIE D65 illuminant, normalised to unit luminance
  (``cie_d65``, i.e. the 5 nm table divided by ``MI_CIE_D65_NORMALIZATION``), times the grey
  value given;
* the sensor samples wavelengths in 360–830 nm and divides by their density, and the film
  converts each sample to linear sRGB with the CIE 1931 2° colour-matching functions
  (``cie1931_xyz``: the 5 nm table, linearly interpolated), ``MI_CIE_Y_NORMALIZATION``
  and the XYZ → linear Rec. 709 / sRGB matrix (``xyz_to_srgb``, D65 white).

A converged spectral render of the film under a white sky is therefore, per channel ``c``,

    RGB_c = ∫ W_c(λ) R(λ) dλ,     W_c(λ) = Y_norm · D65(λ) · (M_xyz→sRGB · x̄ȳz̄(λ))_c

(Mitsuba's own ``spectrum_list_to_srgb(..., d65=True)`` projects reflectance spectra the same
way). This module builds a quadrature for that integral that the plugin evaluates *inside*
the kernel of an RGB variant:

* nodes ``λ_i``: ``N`` wavelengths equally spaced in wavenumber ``1/λ`` over
  :data:`NODE_RANGE_NM`. A film's round-trip phase ``4π n d cos θ / λ`` is linear in ``1/λ``,
  so its reflectance is a smooth, nearly periodic function of the wavenumber;
* weights ``w_ic = ∫ W_c(λ) φ_i(1/λ) dλ`` where ``φ_i`` are the cardinal functions of the
  natural cubic spline through the nodes (in wavenumber, held constant beyond the end
  nodes): the rule integrates the spline interpolant of ``R`` exactly against ``W_c``;
* each channel is divided by its white value, so ``R ≡ 1`` gives exactly ``(1, 1, 1)``, as
  Mitsuba's RGB variants render a white emitter seen in a perfect mirror. (Mitsuba's
  tables give ``(0.99999, 0.99987, 0.99980)`` for it in spectral variants.)

The tables are read from Mitsuba itself (:func:`mitsuba_colour_tables`), in whatever variant is
active: the plugin stores no copy of them.

References
----------
.. [1] CIE 015:2018, *Colorimetry*, 4th ed. (CIE 1931 2° observer, illuminant D65).
.. [2] IEC 61966-2-1 (sRGB: Rec. 709 primaries, D65 white point).
.. [3] L. Belcour, P. Barla, "A Practical Extension to Microfacet Theory for the Modeling of
   Varying Iridescence", ACM TOG 36(4), 2017 (spectral integration of thin-film reflectance
   in an RGB renderer; an analytic alternative to this quadrature).

Examples
--------
A basis from tables given directly (here: a flat illuminant and box-shaped matching
functions), normalised so that a unit reflectance is white:

>>> import numpy as np
>>> lam = np.linspace(360.0, 830.0, 95)
>>> cmf = np.stack([(lam > 600), (lam > 500) & (lam <= 600), (lam <= 500)], -1) * 1.0
>>> tables = ColourTables(lam, cmf, np.ones_like(lam), np.eye(3), 1.0)
>>> basis = colour_basis(tables, n_nodes=24)
>>> np.round(basis.weights.sum(axis=0), 6).tolist()
[1.0, 1.0, 1.0]
>>> np.round(basis.rgb(np.ones(24)), 6).tolist()
[1.0, 1.0, 1.0]
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

__all__ = [
    "N_NODES",
    "NODE_RANGE_NM",
    "ColourTables",
    "ColourBasis",
    "mitsuba_colour_tables",
    "colour_weights",
    "colour_basis",
    "integrate",
]

#: Number of quadrature nodes (a multiple of 3: the plugin evaluates them three at a time,
#: in the RGB variants' 3-wide spectrum type).
N_NODES = 24

#: Wavelength range of the nodes in nm. The colour weights outside it (360–390 nm,
#: 730–830 nm) are small and go to the end nodes.
NODE_RANGE_NM = (390.0, 730.0)

#: Spacing of the fine grid on which the weights are integrated, in nm.
_FINE_STEP_NM = 0.05


@dataclass(frozen=True)
class ColourTables:
    """The tables of a spectral → linear RGB conversion.

    Attributes
    ----------
    wavelengths_nm : ndarray, shape (K,)
        Knots of the tables (increasing); values in between are linearly interpolated.
    cmf : ndarray, shape (K, 3)
        Colour-matching functions x̄, ȳ, z̄ at the knots.
    illuminant : ndarray, shape (K,)
        Spectral power of the illuminant at the knots.
    xyz_to_rgb : ndarray, shape (3, 3)
        XYZ → linear RGB matrix.
    y_normalization : float
        Factor applied to the XYZ integrals.
    """

    wavelengths_nm: np.ndarray
    cmf: np.ndarray
    illuminant: np.ndarray
    xyz_to_rgb: np.ndarray
    y_normalization: float


@dataclass(frozen=True)
class ColourBasis:
    """Quadrature nodes and per-channel weights: ``RGB_c = Σ_i weights[i, c] · R(λ_i)``.

    Attributes
    ----------
    wavelengths_nm : ndarray, shape (N,)
        Node wavelengths in nm.
    weights : ndarray, shape (N, 3)
        Weights of the R, G, B channels; each column sums to 1.
    """

    wavelengths_nm: np.ndarray
    weights: np.ndarray

    def rgb(self, values):
        """Linear RGB of spectra sampled at the nodes: ``values`` (..., N) → (..., 3)."""
        return np.asarray(values, dtype=np.float64) @ self.weights


def mitsuba_colour_tables() -> ColourTables:
    """The CIE 1931 2° CMFs, D65 and XYZ → sRGB matrix of Mitsuba's spectral pipeline.

    Read through Mitsuba's own functions (``cie1931_xyz``, ``cie_d65``, ``xyz_to_srgb``,
    ``MI_CIE_Y_NORMALIZATION``) at its 95 table knots (360–830 nm, 5 nm) in the active
    variant, so the basis matches what Mitsuba's spectral variants render. The illuminant is
    ``cie_d65``: D65 normalised to unit luminance, as Mitsuba's emitters use it.
    """
    import drjit as dr
    import mitsuba as mi

    knots = np.linspace(float(mi.MI_CIE_MIN), float(mi.MI_CIE_MAX), 95)
    if dr.is_jit_v(mi.Float):
        lam = mi.Float(knots)
        cmf = np.array(mi.cie1931_xyz(lam), dtype=np.float64).T
        d65 = np.array(mi.cie_d65(lam), dtype=np.float64)
        unit = [mi.xyz_to_srgb(mi.Color3f(*(float(v) for v in e))) for e in np.eye(3)]
        matrix = np.array([[float(dr.ravel(u[r])[0]) for u in unit] for r in range(3)])
    else:
        cmf = np.array([list(mi.cie1931_xyz(float(x))) for x in knots], dtype=np.float64)
        d65 = np.array([float(mi.cie_d65(float(x))) for x in knots])
        unit = [mi.xyz_to_srgb(mi.Color3f(*(float(v) for v in e))) for e in np.eye(3)]
        matrix = np.array([[float(u[r]) for u in unit] for r in range(3)])
    return ColourTables(knots, cmf, d65, matrix, float(mi.MI_CIE_Y_NORMALIZATION))


def colour_weights(tables: ColourTables, step_nm: float = _FINE_STEP_NM):
    """Fine-grid weights of ``∫ W_c(λ) R(λ) dλ`` (trapezoid rule on the tables' range).

    Returns
    -------
    grid_nm : ndarray, shape (F,)
    weights : ndarray, shape (F, 3)
        ``RGB_c ≈ Σ_f weights[f, c] · R(grid_nm[f])``, not yet normalised to white.
    """
    lam = np.asarray(tables.wavelengths_nm, dtype=np.float64)
    count = int(round((lam[-1] - lam[0]) / step_nm)) + 1
    grid = np.linspace(lam[0], lam[-1], count)
    cmf = np.stack([np.interp(grid, lam, tables.cmf[:, j]) for j in range(3)], axis=-1)
    power = np.interp(grid, lam, tables.illuminant)
    density = (cmf @ np.asarray(tables.xyz_to_rgb, dtype=np.float64).T) * (power * tables.y_normalization)[:, None]
    dw = np.full(count, grid[1] - grid[0])
    dw[0] = dw[-1] = 0.5 * dw[0]
    return grid, density * dw[:, None]


def _spline_cardinals(nodes, x):
    """Natural cubic spline cardinal functions through ``nodes`` (increasing) at ``x``: (len(x), N)."""
    from scipy.interpolate import CubicSpline

    x = np.clip(x, nodes[0], nodes[-1])
    return CubicSpline(nodes, np.eye(len(nodes)), bc_type="natural")(x)


def colour_basis(tables: ColourTables | None = None, n_nodes: int = N_NODES,
                 range_nm: tuple = NODE_RANGE_NM) -> ColourBasis:
    """The quadrature of the module docstring for ``tables`` (default: Mitsuba's own).

    Parameters
    ----------
    tables : ColourTables, optional
        Default :func:`mitsuba_colour_tables` (needs a Mitsuba variant to be set).
    n_nodes : int
        Number of nodes, equally spaced in wavenumber.
    range_nm : (float, float)
        Shortest and longest node wavelength in nm.
    """
    if tables is None:
        return _mitsuba_basis(int(n_nodes), tuple(float(v) for v in range_nm))
    lo, hi = range_nm
    if not (0 < lo < hi) or n_nodes < 4:
        raise ValueError(f"colour_basis: need 0 < range_nm[0] < range_nm[1] and n_nodes >= 4, "
                         f"got {range_nm} and {n_nodes}")
    # Increasing wavenumber k = 1/λ: from 1/hi to 1/lo.
    k_nodes = np.linspace(1.0 / hi, 1.0 / lo, n_nodes)
    grid, fine = colour_weights(tables)
    weights = _spline_cardinals(k_nodes, 1.0 / grid).T @ fine
    weights /= weights.sum(axis=0, keepdims=True)
    return ColourBasis(1.0 / k_nodes, weights)


@lru_cache(maxsize=None)
def _mitsuba_basis(n_nodes, range_nm):
    # Mitsuba's tables are the same in every variant: one basis per process.
    return colour_basis(mitsuba_colour_tables(), n_nodes, range_nm)


def integrate(basis: ColourBasis, entries_of, count: int, spectrum_type):
    """Integrate spectra against the basis inside a Dr.Jit kernel (or in a scalar variant).

    Parameters
    ----------
    basis : ColourBasis
    entries_of : callable
        ``entries_of(wavelengths)`` with ``wavelengths`` a ``spectrum_type`` holding a few
        node wavelengths returns a sequence of spectra (e.g. the Mueller entries) at them.
    count : int
        How many of the returned spectra to integrate (the first ``count``).
    spectrum_type : type
        The variant's spectrum type (``mi.UnpolarizedSpectrum``: RGB, 3 wide); the nodes are
        evaluated that many at a time.

    Returns
    -------
    list of ``count`` colours of ``spectrum_type``.
    """
    import drjit as dr

    width = dr.size_v(spectrum_type)
    nodes = basis.wavelengths_nm
    if len(nodes) % width:
        raise ValueError(f"integrate: {len(nodes)} nodes are not a multiple of the spectrum width {width}")
    acc = [[None] * 3 for _ in range(count)]
    for start in range(0, len(nodes), width):
        values = entries_of(spectrum_type(*(float(v) for v in nodes[start:start + width])))
        for e in range(count):
            for j in range(width):
                v = values[e][j]
                for c in range(3):
                    w = float(basis.weights[start + j, c])
                    acc[e][c] = v * w if acc[e][c] is None else dr.fma(v, w, acc[e][c])
    return [spectrum_type(*channels) for channels in acc]
