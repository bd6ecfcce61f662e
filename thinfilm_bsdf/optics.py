"""Thin-film optics core: Airy amplitudes, reflectances and the reflection Mueller matrix.

This module is the project's single source of truth for the physics of a single
homogeneous film (index ``n2 + i k2``, thickness ``d``) on a substrate
(``n3 + i k3``), lit from an exterior medium ``n1``. The Mitsuba plugin, the
capture generators and the reconstruction forward models all call it.

Every function is written once against a tiny complex-number type built on
pairs of real arrays, so the same code runs on

* NumPy arrays (any leading shape, broadcasting as usual), and
* Dr.Jit arrays inside a Mitsuba-traced kernel (``mi.Float``,
  ``mi.UnpolarizedSpectrum`` …), in scalar, LLVM and CUDA variants alike.

Conventions (the same as the ``tmm`` package and Mitsuba's ``fresnel_polarized``):

* refractive indices ``n + i k`` with ``k >= 0`` absorbing;
* wavelength and thickness in nanometres;
* ``r_s = (q1 - q2) / (q1 + q2)`` and ``r_p = (n2² q1 - n1² q2) / (n2² q1 + n1² q2)``
  with ``q_j = n_j cos θ_j``, the branch with ``Im q_j >= 0`` (decaying wave);
* the film adds the round-trip phase ``exp(i Δ)``, ``Δ = 4π q2 d / λ``, and the
  Airy sum ``r = (r12 + r23 e^{iΔ}) / (1 + r12 r23 e^{iΔ})``.

The reflection Mueller matrix in the s/p frame (Stokes reference axis
perpendicular to the plane of incidence, Mitsuba's layout) is::

    [[a, b, 0, 0],
     [b, a, 0, 0],
     [0, 0, c, s],
     [0, 0, -s, c]]

with ``a = (R_s + R_p)/2``, ``b = (R_s - R_p)/2`` and ``c + i s = conj(r_s) r_p``.

Phase convention: ``tmm`` (and this module) write waves as ``exp(i(kz - ωt))`` with
absorbing indices ``n + ik``; Mitsuba's ``fresnel_polarized`` returns the complex
conjugates of these amplitudes (for absorbing media; for lossless ones they are
real and identical). The Mueller matrix above is therefore built from
``conj(r_s) r_p``, which equals Mitsuba's ``a_s conj(a_p)``: with thickness 0 it is
Mitsuba's ``mueller::specular_reflection`` entry for entry. Only the sign of the
retardance entry ``s`` depends on this choice.

References
----------
.. [1] M. Born, E. Wolf, *Principles of Optics*, 7th ed., Sec. 1.6.4 and 7.6.1
   (Airy formula for a single film).
.. [2] S. J. Byrnes, "Multilayer optical calculations", arXiv:1603.02720 (the
   ``tmm`` package, used as the independent reference in the tests).
.. [3] Kobayashi et al., "Shapes and Appearances Reconstructions of Thin Film
   Objects", Eqs. 2-9.

Examples
--------
>>> import numpy as np
>>> R_s, R_p = reflectances(np.cos(np.radians(30.0)), 550.0, 400.0, 1.37, 1.6)
>>> round(float(R_s), 4), round(float(R_p), 4)
(0.0634, 0.0288)
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = [
    "Complex",
    "film_amplitudes",
    "reflectances",
    "mueller_entries",
    "reflection_mueller",
    "interface_amplitudes",
]


# ---------------------------------------------------------------------------
# Array backends
# ---------------------------------------------------------------------------


class _NumpyOps:
    """The handful of real operations the optics needs, for NumPy."""

    sqrt = staticmethod(np.sqrt)
    exp = staticmethod(np.exp)
    cos = staticmethod(np.cos)
    sin = staticmethod(np.sin)
    abs = staticmethod(np.abs)

    @staticmethod
    def select(cond, a, b):
        return np.where(cond, a, b)

    @staticmethod
    def maximum(a, b):
        return np.maximum(a, b)


class _DrJitOps:
    """The same operations for Dr.Jit arrays (scalar, LLVM or CUDA backends)."""

    def __init__(self):
        import drjit as dr

        self.dr = dr
        self.sqrt = dr.sqrt
        self.exp = dr.exp
        self.cos = dr.cos
        self.sin = dr.sin
        self.abs = dr.abs
        self.select = dr.select
        self.maximum = dr.maximum


_NUMPY = _NumpyOps()
_DRJIT: _DrJitOps | None = None


def _is_drjit(x: Any) -> bool:
    # Dr.Jit arrays, and Mitsuba's own array types (Color1f, UnpolarizedSpectrum …).
    module = type(x).__module__
    return module.startswith("drjit") or module.startswith("mitsuba")


def _ops_for(*values):
    """Pick the backend from the arguments: Dr.Jit if any of them is a Dr.Jit array."""
    global _DRJIT
    for v in values:
        if isinstance(v, Complex):
            v = v.re
        if _is_drjit(v):
            if _DRJIT is None:
                _DRJIT = _DrJitOps()
            return _DRJIT
    return _NUMPY


# ---------------------------------------------------------------------------
# A minimal complex type on real arrays
# ---------------------------------------------------------------------------


@dataclass
class Complex:
    """Complex number stored as two real arrays (``re``, ``im``) of any backend.

    Dr.Jit's own complex type only wraps ``Float``; Mitsuba's spectra are
    4-wide arrays, so the optics keeps real and imaginary parts apart and works
    on any real array type that supports ``+ - * /``.
    """

    re: Any
    im: Any

    @staticmethod
    def of(x) -> "Complex":
        if isinstance(x, Complex):
            return x
        if isinstance(x, (complex, np.complexfloating)) or (
            isinstance(x, np.ndarray) and np.iscomplexobj(x)
        ):
            return Complex(np.real(x), np.imag(x))
        return Complex(x, 0.0 * x)

    def __add__(self, o):
        o = Complex.of(o)
        return Complex(self.re + o.re, self.im + o.im)

    __radd__ = __add__

    def __sub__(self, o):
        o = Complex.of(o)
        return Complex(self.re - o.re, self.im - o.im)

    def __rsub__(self, o):
        return Complex.of(o) - self

    def __neg__(self):
        return Complex(-self.re, -self.im)

    def __mul__(self, o):
        if not isinstance(o, Complex):
            return Complex(self.re * o, self.im * o)
        return Complex(self.re * o.re - self.im * o.im, self.re * o.im + self.im * o.re)

    __rmul__ = __mul__

    def __truediv__(self, o):
        if not isinstance(o, Complex):
            return Complex(self.re / o, self.im / o)
        inv = 1.0 / (o.re * o.re + o.im * o.im)
        return Complex(
            (self.re * o.re + self.im * o.im) * inv,
            (self.im * o.re - self.re * o.im) * inv,
        )

    def __rtruediv__(self, o):
        return Complex.of(o) / self

    def conj(self) -> "Complex":
        return Complex(self.re, -self.im)

    def abs2(self):
        return self.re * self.re + self.im * self.im

    def to_numpy(self) -> np.ndarray:
        """As a NumPy complex array (NumPy backend only)."""
        return np.asarray(self.re) + 1j * np.asarray(self.im)


def _csqrt(z: Complex, ops) -> Complex:
    """Principal square root (Re >= 0; Im has the sign of Im z, +0 counted positive).

    The numerically stable form: ``t = sqrt((|z| + |Re z|)/2)`` and the other component
    as ``Im z / (2t)``, so a nearly real argument (a weakly absorbing medium) keeps its
    small imaginary part accurately instead of losing it to cancellation.
    """
    t = ops.sqrt(0.5 * (ops.sqrt(z.re * z.re + z.im * z.im) + ops.abs(z.re)))
    small = ops.select(t > 0, 0.5 * z.im / ops.select(t > 0, t, 1.0), 0.0 * t)
    positive = z.re >= 0
    re = ops.select(positive, t, ops.abs(small))
    im = ops.select(positive, small, ops.select(z.im < 0, -t, t))
    return Complex(re, im)


def _cexp_i(z: Complex, ops) -> Complex:
    """exp(i z) for complex z."""
    mag = ops.exp(-z.im)
    return Complex(mag * ops.cos(z.re), mag * ops.sin(z.re))


# ---------------------------------------------------------------------------
# Physics
# ---------------------------------------------------------------------------


def _index(n, k) -> Complex:
    n = Complex.of(n)
    if isinstance(k, (int, float)) and k == 0:
        return n
    return n + Complex(0.0 * n.re + 0.0, k)


def _normal_component(n: Complex, n1_sin2: Any, ops) -> Complex:
    """q = n cos θ = sqrt(n² - n1² sin² θ1), decaying branch (Im q >= 0)."""
    return _csqrt(n * n - n1_sin2, ops)


def _fresnel(n_i: Complex, q_i: Complex, n_j: Complex, q_j: Complex):
    """Fresnel amplitude coefficients (r_s, r_p) of the interface i → j."""
    r_s = (q_i - q_j) / (q_i + q_j)
    ni2 = n_i * n_i
    nj2 = n_j * n_j
    r_p = (nj2 * q_i - ni2 * q_j) / (nj2 * q_i + ni2 * q_j)
    return r_s, r_p


def interface_amplitudes(cos_theta1, n1, n2, k2=0.0):
    """Fresnel amplitudes (r_s, r_p) of a single interface n1 → n2 + i k2.

    Parameters
    ----------
    cos_theta1 : array_like
        Cosine of the angle of incidence in medium ``n1`` (in [0, 1]).
    n1 : array_like
        Real index of the incident medium.
    n2, k2 : array_like
        Complex index of the second medium, ``k2 >= 0`` absorbing.

    Returns
    -------
    (r_s, r_p) : NumPy complex arrays, or :class:`Complex` for Dr.Jit input.
    """
    return film_amplitudes(cos_theta1, 550.0, 0.0, n2, n2, k2, n1, film_k=k2)


def film_amplitudes(
    cos_theta1,
    wavelength_nm,
    thickness_nm,
    film_ior,
    substrate_ior,
    substrate_k=0.0,
    ext_ior=1.0,
    film_k=0.0,
):
    """Complex s and p reflection amplitudes of a film on a substrate (Airy sum).

    Parameters
    ----------
    cos_theta1 : array_like
        Cosine of the incident angle in the exterior medium, in [0, 1].
    wavelength_nm : array_like
        Vacuum wavelength in nm.
    thickness_nm : array_like
        Film thickness in nm (``>= 0``; 0 gives the bare substrate).
    film_ior, film_k : array_like
        Film index ``n2 + i k2``.
    substrate_ior, substrate_k : array_like
        Substrate index ``n3 + i k3`` (``k3 > 0`` for a metal).
    ext_ior : array_like
        Exterior (real) index ``n1``.

    All arguments broadcast against each other (NumPy) or are Dr.Jit arrays of
    compatible widths.

    Returns
    -------
    (r_s, r_p)
        NumPy complex arrays for NumPy input, :class:`Complex` pairs for
        Dr.Jit input. Same sign convention as ``tmm.coh_tmm(...)['r']`` and
        Mitsuba's ``fresnel_polarized``.
    """
    ops = _ops_for(cos_theta1, wavelength_nm, thickness_nm, film_ior, substrate_ior, substrate_k)
    numpy_in = ops is _NUMPY
    if numpy_in:
        cos_theta1 = np.asarray(cos_theta1, dtype=np.float64)
        wavelength_nm = np.asarray(wavelength_nm, dtype=np.float64)
        thickness_nm = np.asarray(thickness_nm, dtype=np.float64)

    n1 = Complex.of(ext_ior * 1.0)
    n2 = _index(film_ior, film_k)
    n3 = _index(substrate_ior, substrate_k)

    sin2 = 1.0 - cos_theta1 * cos_theta1
    n1_sin2 = n1 * n1 * sin2  # n1 real: (n1 sin θ1)²
    q1 = n1 * cos_theta1
    q2 = _normal_component(n2, n1_sin2, ops)
    q3 = _normal_component(n3, n1_sin2, ops)

    r12_s, r12_p = _fresnel(n1, q1, n2, q2)
    r23_s, r23_p = _fresnel(n2, q2, n3, q3)

    # Round-trip phase Δ = 4π q2 d / λ (complex for an absorbing film).
    k0d = (4.0 * np.pi) * thickness_nm / wavelength_nm
    phase = _cexp_i(q2 * k0d, ops)

    t_s = r23_s * phase
    t_p = r23_p * phase
    r_s = (r12_s + t_s) / (1.0 + r12_s * t_s)
    r_p = (r12_p + t_p) / (1.0 + r12_p * t_p)
    if numpy_in:
        return r_s.to_numpy(), r_p.to_numpy()
    return r_s, r_p


def reflectances(cos_theta1, wavelength_nm, thickness_nm, film_ior, substrate_ior,
                 substrate_k=0.0, ext_ior=1.0, film_k=0.0):
    """Power reflectances ``(R_s, R_p)`` of the film, each in [0, 1].

    Same parameters as :func:`film_amplitudes`.

    Examples
    --------
    >>> R_s, R_p = reflectances(1.0, 550.0, 0.0, 1.37, 1.6)   # bare PET, normal incidence
    >>> round(float(R_s), 4), round(float(R_p), 4)
    (0.0533, 0.0533)
    """
    r_s, r_p = film_amplitudes(cos_theta1, wavelength_nm, thickness_nm, film_ior,
                               substrate_ior, substrate_k, ext_ior, film_k)
    if isinstance(r_s, Complex):
        return r_s.abs2(), r_p.abs2()
    return np.abs(r_s) ** 2, np.abs(r_p) ** 2


def mueller_entries(r_s, r_p):
    """The four distinct entries ``(a, b, c, s)`` of the reflection Mueller matrix.

    ``a = (|r_s|² + |r_p|²)/2``, ``b = (|r_s|² - |r_p|²)/2``,
    ``c + i s = conj(r_s) · r_p`` for amplitudes in this module's (``tmm``'s) phase
    convention, which is Mitsuba's ``a_s conj(a_p)`` (see the module docstring).
    Accepts NumPy complex arrays or :class:`Complex`.
    """
    r_s = Complex.of(r_s)
    r_p = Complex.of(r_p)
    Rs, Rp = r_s.abs2(), r_p.abs2()
    x = r_s.conj() * r_p
    return 0.5 * (Rs + Rp), 0.5 * (Rs - Rp), x.re, x.im


def reflection_mueller(cos_theta1, wavelength_nm, thickness_nm, film_ior, substrate_ior,
                       substrate_k=0.0, ext_ior=1.0, film_k=0.0) -> np.ndarray:
    """Reflection Mueller matrix of the film in the s/p frame, shape ``(..., 4, 4)``.

    NumPy only (the Mitsuba plugin assembles Mitsuba's own matrix type from
    :func:`mueller_entries`). The Stokes reference axis is perpendicular to the
    plane of incidence, as in Mitsuba's ``mueller::specular_reflection``.
    """
    r_s, r_p = film_amplitudes(cos_theta1, wavelength_nm, thickness_nm, film_ior,
                               substrate_ior, substrate_k, ext_ior, film_k)
    a, b, c, s = (np.asarray(v, dtype=np.float64) for v in mueller_entries(r_s, r_p))
    z = np.zeros_like(a)
    rows = [[a, b, z, z], [b, a, z, z], [z, z, c, s], [z, z, -s, c]]
    return np.stack([np.stack(r, axis=-1) for r in rows], axis=-2)
