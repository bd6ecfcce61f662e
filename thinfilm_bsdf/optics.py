"""Thin-film optics core: Airy amplitudes, reflectances, transmittances and Mueller matrices.

This module is the project's single source of truth for the physics of a single
homogeneous film (index ``n2 + i k2``, thickness ``d``) on a substrate
(``n3 + i k3``), lit from an exterior medium ``n1``, and of stacks of such films
(:func:`stack_amplitudes`), on a substrate or free-standing (:func:`sheet_amplitudes`,
a soap-bubble wall: the exterior medium on both sides). The Mitsuba plugins, the
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
  Airy sum ``r = (r12 + r23 e^{iΔ}) / (1 + r12 r23 e^{iΔ})``;
* a stack is summed the same way from the substrate up (each layer's Airy sum with
  the reflection of everything below it in place of ``r23``), and transmission
  amplitudes are ``tmm``'s: ratios of the electric-field amplitudes, with interface
  coefficients ``t_s = 2 q1 / (q1 + q2)`` and ``t_p = 2 n1 n2 q1 / (n2² q1 + n1² q2)``,
  so that ``T_s = Re(q_sub) / q1 |t_s|²`` and ``T_p = Re(n_sub conj(q_sub / n_sub)) / q1 |t_p|²``
  (:func:`transmission_factors`).

The reflection Mueller matrix in the s/p frame (Stokes reference axis
perpendicular to the plane of incidence, Mitsuba's layout) is::

    [[a, b, 0, 0],
     [b, a, 0, 0],
     [0, 0, c, s],
     [0, 0, -s, c]]

with ``a = (R_s + R_p)/2``, ``b = (R_s - R_p)/2`` and ``c + i s = conj(r_s) r_p``.
The transmission Mueller matrix has the same layout, built from ``t_s, t_p`` and the
intensity factor of the exit medium (:func:`transmission_mueller_entries`); with the
same medium on both sides it is the identity for a film of thickness 0.

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
    "stack_amplitudes",
    "sheet_amplitudes",
    "reflectances",
    "stack_powers",
    "transmission_factors",
    "mueller_entries",
    "transmission_mueller_entries",
    "mueller_matrix",
    "reflection_mueller",
    "sheet_mueller",
    "interface_amplitudes",
    "ops_for",
    "NUMPY_OPS",
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


#: the NumPy backend (what :func:`ops_for` returns for anything but Dr.Jit arrays)
NUMPY_OPS = _NumpyOps()
_DRJIT: _DrJitOps | None = None


def _is_drjit(x: Any) -> bool:
    # Dr.Jit arrays, and Mitsuba's own array types (Color1f, UnpolarizedSpectrum …).
    module = type(x).__module__
    return module.startswith("drjit") or module.startswith("mitsuba")


def ops_for(*values):
    """Pick the backend from the arguments: Dr.Jit if any of them is a Dr.Jit array (or a
    :class:`Complex` of them), else :data:`NUMPY_OPS`. The backend has ``sqrt``, ``exp``,
    ``cos``, ``sin``, ``abs``, ``select`` and ``maximum``."""
    global _DRJIT
    for v in values:
        if isinstance(v, Complex):
            v = v.re
        if _is_drjit(v):
            if _DRJIT is None:
                _DRJIT = _DrJitOps()
            return _DRJIT
    return NUMPY_OPS


# ---------------------------------------------------------------------------
# A minimal complex type on real arrays
# ---------------------------------------------------------------------------


def _plus(a, b):
    if a is None:
        return b
    return a if b is None else a + b


def _minus(a, b):
    if b is None:
        return a
    return -b if a is None else a - b


def _times(a, b):
    return None if a is None or b is None else a * b


class Complex:
    """Complex number stored as two real arrays (``re``, ``im``) of any backend.

    Dr.Jit's own complex type only wraps ``Float``; Mitsuba's spectra are
    4-wide arrays, so the optics keeps real and imaginary parts apart and works
    on any real array type that supports ``+ - * /``.

    An imaginary part known to be zero (a real number: a lossless index, a real normal
    component) is carried as nothing rather than as an array of zeros, so that the
    arithmetic of real quantities costs what real arithmetic costs; :attr:`im` gives it as an
    array all the same.
    """

    __slots__ = ("re", "_im")

    def __init__(self, re, im=None):
        self.re = re
        self._im = im

    @property
    def im(self):
        """The imaginary part (an array of zeros for a real number)."""
        return 0.0 * self.re if self._im is None else self._im

    @property
    def is_real(self) -> bool:
        """Whether the imaginary part is known to be zero."""
        return self._im is None

    def __repr__(self):
        return f"Complex(re={self.re!r}, im={self.im!r})"

    @staticmethod
    def of(x) -> "Complex":
        if isinstance(x, Complex):
            return x
        if isinstance(x, (complex, np.complexfloating)) or (
            isinstance(x, np.ndarray) and np.iscomplexobj(x)
        ):
            return Complex(np.real(x), np.imag(x))
        return Complex(x)

    def __add__(self, o):
        o = Complex.of(o)
        return Complex(self.re + o.re, _plus(self._im, o._im))

    __radd__ = __add__

    def __sub__(self, o):
        o = Complex.of(o)
        return Complex(self.re - o.re, _minus(self._im, o._im))

    def __rsub__(self, o):
        return Complex.of(o) - self

    def __neg__(self):
        return Complex(-self.re, None if self._im is None else -self._im)

    def __mul__(self, o):
        if not isinstance(o, Complex):
            return Complex(self.re * o, None if self._im is None else self._im * o)
        return Complex(_minus(self.re * o.re, _times(self._im, o._im)),
                       _plus(_times(self.re, o._im), _times(self._im, o.re)))

    __rmul__ = __mul__

    def __truediv__(self, o):
        if not isinstance(o, Complex):
            return Complex(self.re / o, None if self._im is None else self._im / o)
        if o._im is None:
            inv = 1.0 / o.re
            return Complex(self.re * inv, None if self._im is None else self._im * inv)
        inv = 1.0 / (o.re * o.re + o._im * o._im)
        return Complex(
            _plus(self.re * o.re, _times(self._im, o._im)) * inv,
            _minus(_times(self._im, o.re), self.re * o._im) * inv,
        )

    def __rtruediv__(self, o):
        return Complex.of(o) / self

    def conj(self) -> "Complex":
        return Complex(self.re, None if self._im is None else -self._im)

    def abs2(self):
        return self.re * self.re if self._im is None else self.re * self.re + self._im * self._im

    def to_numpy(self) -> np.ndarray:
        """As a NumPy complex array (NumPy backend only)."""
        return np.asarray(self.re) + 1j * np.asarray(self.im)


def _csqrt(z: Complex, ops) -> Complex:
    """Principal square root (Re >= 0; Im has the sign of Im z, +0 counted positive).

    The numerically stable form: ``t = sqrt((|z| + |Re z|)/2)`` and the other component
    as ``Im z / (2t)``, so a nearly real argument (a weakly absorbing medium) keeps its
    small imaginary part accurately instead of losing it to cancellation.
    """
    if z.is_real and ops is NUMPY_OPS and np.all(np.asarray(z.re) >= 0):
        return Complex(np.sqrt(z.re))
    t = ops.sqrt(0.5 * (ops.sqrt(z.re * z.re + z.im * z.im) + ops.abs(z.re)))
    small = ops.select(t > 0, 0.5 * z.im / ops.select(t > 0, t, 1.0), 0.0 * t)
    positive = z.re >= 0
    re = ops.select(positive, t, ops.abs(small))
    im = ops.select(positive, small, ops.select(z.im < 0, -t, t))
    return Complex(re, im)


def _cexp_i(z: Complex, ops) -> Complex:
    """exp(i z) for complex z."""
    if z.is_real:
        return Complex(ops.cos(z.re), ops.sin(z.re))
    mag = ops.exp(-z.im)
    return Complex(mag * ops.cos(z.re), mag * ops.sin(z.re))


# ---------------------------------------------------------------------------
# Physics
# ---------------------------------------------------------------------------


def _index(n, k) -> Complex:
    n = Complex.of(n)
    if isinstance(k, (int, float)) and k == 0:
        return n
    return Complex(n.re, _plus(n._im, k))


def _normal_component(n: Complex, n1_sin2: Any, ops, real: bool = False) -> Complex:
    """q = n cos θ = sqrt(n² - n1² sin² θ1), decaying branch (Im q >= 0); with ``real`` (a
    lossless medium of index at least the exterior's, where the wave never decays) the
    real square root."""
    if real:
        return Complex(ops.sqrt(ops.maximum((n * n - n1_sin2).re, 0.0)))
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

    See Also
    --------
    stack_amplitudes : any number of films, and transmission; this is its one-layer case.
    """
    return stack_amplitudes(cos_theta1, wavelength_nm, [(film_ior, film_k, thickness_nm)], substrate_ior,
                            substrate_k, ext_ior)


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
    return mueller_matrix(*mueller_entries(r_s, r_p))


def mueller_matrix(a, b, c, s) -> np.ndarray:
    """The ``(..., 4, 4)`` NumPy matrix ``[[a, b, 0, 0], [b, a, 0, 0], [0, 0, c, s], [0, 0, -s, c]]``."""
    a, b, c, s = np.broadcast_arrays(*(np.asarray(v, dtype=np.float64) for v in (a, b, c, s)))
    z = np.zeros_like(a)
    rows = [[a, b, z, z], [b, a, z, z], [z, z, c, s], [z, z, -s, c]]
    return np.stack([np.stack(r, axis=-1) for r in rows], axis=-2)


# ---------------------------------------------------------------------------
# Stacks of films, transmission, free-standing films
# ---------------------------------------------------------------------------


def _fresnel_t(n_i: Complex, q_i: Complex, n_j: Complex, q_j: Complex):
    """Fresnel transmission amplitudes (t_s, t_p) of the interface i → j, ``tmm``'s convention
    (ratios of the electric-field amplitudes)."""
    t_s = (2.0 * q_i) / (q_i + q_j)
    t_p = (2.0 * (n_i * n_j * q_i)) / (n_j * n_j * q_i + n_i * n_i * q_j)
    return t_s, t_p


def _layer_triples(layers):
    """``layers`` as a list of ``(n, k, thickness_nm)`` triples."""
    out = []
    for i, layer in enumerate(layers):
        try:
            size = len(layer)
        except TypeError:
            size = 0
        if size == 3:
            out.append(tuple(layer))
        elif size == 2:
            out.append((layer[0], 0.0, layer[1]))
        else:
            raise ValueError(f"stack layer {i}: expected (n, k, thickness_nm) or "
                             f"(index, thickness_nm), got {layer!r}")
    return out


def stack_amplitudes(cos_theta1, wavelength_nm, layers, substrate_ior, substrate_k=0.0,
                     ext_ior=1.0, transmission=False, lossless=False):
    """Complex s and p amplitudes of a stack of films on a substrate (recursive Airy sum).

    Parameters
    ----------
    cos_theta1 : array_like
        Cosine of the incident angle in the exterior medium, in [0, 1].
    wavelength_nm : array_like
        Vacuum wavelength in nm.
    layers : sequence
        The films from the exterior down, each ``(n, k, thickness_nm)`` (index ``n + i k``,
        ``k >= 0`` absorbing) or ``(index, thickness_nm)`` with a real or complex index.
        Every entry may be an array (NumPy or Dr.Jit) broadcasting with the others; an
        empty sequence gives the bare substrate.
    substrate_ior, substrate_k : array_like
        Substrate index ``n_sub + i k_sub`` (``k_sub > 0`` for a metal).
    ext_ior : array_like
        Exterior (real) index ``n1``.
    transmission : bool
        Also return the transmission amplitudes into the substrate.
    lossless : bool
        A promise that every layer and the substrate is lossless (``k = 0``) with an index
        at least the exterior's, so that every normal component is real: the amplitudes are
        then computed with real Fresnel coefficients (about half the arithmetic in a Dr.Jit
        kernel; NumPy finds this out by itself). Results are the same.

    Returns
    -------
    (r_s, r_p) or (r_s, r_p, t_s, t_p)
        NumPy complex arrays for NumPy input, :class:`Complex` pairs for Dr.Jit input, in
        ``tmm``'s conventions (``tmm.coh_tmm(...)['r']`` and ``['t']``). A one-layer stack
        gives exactly (bit for bit) the amplitudes of :func:`film_amplitudes`. Power
        transmittances: :func:`stack_powers`.

    Notes
    -----
    From the substrate up, layer ``j`` (normal component ``q_j = n_j cos θ_j``, one-way
    phase ``β_j = 2π q_j d_j / λ``) replaces what lies below it, seen from above, by::

        r ← (r_j + r e^{2iβ_j}) / (1 + r_j r e^{2iβ_j})
        t ← t_j t e^{iβ_j} / (1 + r_j r e^{2iβ_j})

    with ``r_j, t_j`` the Fresnel coefficients of its top interface: the sum of the
    multiple reflections inside the layer [1]_ [2]_.

    Examples
    --------
    A quarter-wave MgF2 coating on glass at normal incidence reflects
    ``((1.52 - 1.38²) / (1.52 + 1.38²))²``; an 8-pair quarter-wave Bragg mirror almost all:

    >>> r_s, r_p = stack_amplitudes(1.0, 550.0, [(1.38, 0.0, 550.0 / (4 * 1.38))], 1.52)
    >>> round(float(abs(r_s) ** 2), 6), round(((1.52 - 1.38**2) / (1.52 + 1.38**2)) ** 2, 6)
    (0.012601, 0.012601)
    >>> mirror = [(2.35, 550.0 / (4 * 2.35)), (1.38, 550.0 / (4 * 1.38))] * 8
    >>> R_s, R_p, T_s, T_p = stack_powers(1.0, 550.0, mirror, 1.52)
    >>> round(float(R_s), 4), round(float(R_s + T_s), 12)
    (0.9995, 1.0)
    """
    layers = _layer_triples(layers)
    ops = ops_for(cos_theta1, wavelength_nm, substrate_ior, substrate_k, ext_ior,
                  *[v for layer in layers for v in layer])
    numpy_in = ops is NUMPY_OPS
    if numpy_in:
        cos_theta1 = np.asarray(cos_theta1, dtype=np.float64)
        wavelength_nm = np.asarray(wavelength_nm, dtype=np.float64)
        layers = [(n, k, np.asarray(d, dtype=np.float64)) for n, k, d in layers]

    n1 = Complex.of(ext_ior * 1.0)
    indices = [n1] + [_index(n, k) for n, k, _ in layers] + [_index(substrate_ior, substrate_k)]
    sin2 = 1.0 - cos_theta1 * cos_theta1
    n1_sin2 = n1 * n1 * sin2  # n1 real: (n1 sin θ1)², the same in every layer (Snell)
    normals = [n1 * cos_theta1] + [_normal_component(n, n1_sin2, ops, lossless) for n in indices[1:]]

    # The bottom interface, then each layer from the substrate up.
    r_s, r_p = _fresnel(indices[-2], normals[-2], indices[-1], normals[-1])
    if transmission:
        t_s, t_p = _fresnel_t(indices[-2], normals[-2], indices[-1], normals[-1])
    for j in range(len(layers), 0, -1):
        n_top, q_top, n_j, q_j = indices[j - 1], normals[j - 1], indices[j], normals[j]
        top_s, top_p = _fresnel(n_top, q_top, n_j, q_j)
        k0d = (4.0 * np.pi) * layers[j - 1][2] / wavelength_nm
        phase = _cexp_i(q_j * k0d, ops)  # round trip, e^{2iβ}
        x_s = r_s * phase
        x_p = r_p * phase
        den_s = 1.0 + top_s * x_s
        den_p = 1.0 + top_p * x_p
        if transmission:
            one_way = _cexp_i(q_j * (0.5 * k0d), ops)  # e^{iβ}
            tt_s, tt_p = _fresnel_t(n_top, q_top, n_j, q_j)
            t_s = tt_s * (t_s * one_way) / den_s
            t_p = tt_p * (t_p * one_way) / den_p
        r_s = (top_s + x_s) / den_s
        r_p = (top_p + x_p) / den_p

    out = (r_s, r_p, t_s, t_p) if transmission else (r_s, r_p)
    if numpy_in:
        return tuple(v.to_numpy() for v in out)
    return out


def transmission_factors(cos_theta1, substrate_ior, substrate_k=0.0, ext_ior=1.0):
    """Intensity factors ``(f_s, f_p)`` with ``T_s = f_s |t_s|²`` and ``T_p = f_p |t_p|²``.

    ``f_s = Re(n_sub cos θ_sub) / (n1 cos θ1)`` and
    ``f_p = Re(n_sub conj(cos θ_sub)) / (n1 cos θ1)``, ``tmm``'s ``T_from_t``; both equal
    ``n_sub cos θ_sub / (n1 cos θ1)`` for a lossless substrate, and 1 when the exit medium
    is the exterior medium. Zero at grazing incidence (``cos θ1 = 0``). Real arrays
    (NumPy or Dr.Jit).
    """
    ops = ops_for(cos_theta1, substrate_ior, substrate_k, ext_ior)
    if ops is NUMPY_OPS:
        cos_theta1 = np.asarray(cos_theta1, dtype=np.float64)
    n1 = ext_ior * 1.0
    n_sub = _index(substrate_ior, substrate_k)
    q_sub = _normal_component(n_sub, Complex.of(n1 * n1 * (1.0 - cos_theta1 * cos_theta1)), ops)
    q1 = n1 * cos_theta1
    grazing = q1 <= 0
    inv_q1 = 1.0 / ops.select(grazing, 1.0 + 0.0 * q1, q1)
    f_s = ops.select(grazing, 0.0 * q1, q_sub.re * inv_q1)
    cos_sub = q_sub / n_sub
    f_p = ops.select(grazing, 0.0 * q1, (n_sub * cos_sub.conj()).re * inv_q1)
    return f_s, f_p


def stack_powers(cos_theta1, wavelength_nm, layers, substrate_ior, substrate_k=0.0, ext_ior=1.0):
    """Power reflectances and transmittances ``(R_s, R_p, T_s, T_p)`` of a stack on a substrate.

    Same parameters as :func:`stack_amplitudes`; ``T`` is the power carried into the
    substrate (``tmm``'s ``T``), so ``R + T = 1`` for lossless layers and substrate.
    Real arrays (NumPy or Dr.Jit).
    """
    r_s, r_p, t_s, t_p = stack_amplitudes(cos_theta1, wavelength_nm, layers, substrate_ior,
                                          substrate_k, ext_ior, transmission=True)
    f_s, f_p = transmission_factors(cos_theta1, substrate_ior, substrate_k, ext_ior)
    r_s, r_p, t_s, t_p = (Complex.of(v) for v in (r_s, r_p, t_s, t_p))
    return r_s.abs2(), r_p.abs2(), f_s * t_s.abs2(), f_p * t_p.abs2()


def sheet_amplitudes(cos_theta1, wavelength_nm, layers, ext_ior=1.0):
    """Amplitudes ``(r_s, r_p, t_s, t_p)`` of a free-standing film or stack (a soap-bubble wall).

    The exterior medium ``ext_ior`` lies on both sides; ``layers`` as in
    :func:`stack_amplitudes`, listed from the side the light comes from (pass them
    reversed for light arriving from the other side: ``t`` is the same, ``r`` differs
    for an asymmetric stack). The transmitted power is ``|t|²`` (both intensity factors
    are 1), so ``|r|² + |t|² = 1`` for lossless layers.

    Examples
    --------
    >>> r_s, r_p, t_s, t_p = sheet_amplitudes(1.0, 550.0, [(1.33, 0.0, 0.0)])  # no film
    >>> round(abs(complex(t_s)), 12), round(abs(complex(r_s)), 12)
    (1.0, 0.0)
    >>> r_s, r_p, t_s, t_p = sheet_amplitudes(1.0, 550.0, [(1.33, 0.0, 550.0 / (4 * 1.33))])
    >>> round(float(abs(r_s) ** 2 + abs(t_s) ** 2), 12)   # a quarter-wave water film
    1.0
    """
    return stack_amplitudes(cos_theta1, wavelength_nm, layers, ext_ior, 0.0, ext_ior,
                            transmission=True)


def transmission_mueller_entries(t_s, t_p, factor=1.0):
    """The four distinct entries ``(a, b, c, s)`` of the transmission Mueller matrix.

    ``a = f (|t_s|² + |t_p|²)/2``, ``b = f (|t_s|² - |t_p|²)/2``, ``c + i s = f conj(t_s) t_p``
    with ``f`` the intensity factor of a lossless exit medium
    (:func:`transmission_factors`; 1 for a free-standing film). Same layout and phase
    convention as :func:`mueller_entries`; Mitsuba's ``mueller::specular_transmission``
    for a bare interface. Accepts NumPy complex arrays or :class:`Complex`.
    """
    t_s = Complex.of(t_s)
    t_p = Complex.of(t_p)
    Ts, Tp = t_s.abs2(), t_p.abs2()
    x = t_s.conj() * t_p
    return 0.5 * factor * (Ts + Tp), 0.5 * factor * (Ts - Tp), factor * x.re, factor * x.im


def sheet_mueller(cos_theta1, wavelength_nm, layers, ext_ior=1.0):
    """Reflection and transmission Mueller matrices of a free-standing film, ``(M_r, M_t)``.

    NumPy only; each of shape ``(..., 4, 4)`` in the s/p frame (Stokes reference axis
    perpendicular to the plane of incidence), for light arriving on the first layer
    of ``layers`` (see :func:`sheet_amplitudes`).
    """
    r_s, r_p, t_s, t_p = sheet_amplitudes(cos_theta1, wavelength_nm, layers, ext_ior)
    return (mueller_matrix(*mueller_entries(r_s, r_p)),
            mueller_matrix(*transmission_mueller_entries(t_s, t_p)))
