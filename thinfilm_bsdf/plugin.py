"""Mitsuba 3 plugin ``thinfilm``: a smooth surface coated with one thin film.

.. list-table::
   :header-rows: 1

   * - Parameter
     - Type
     - Default
     - Meaning
     - Exposed (traverse)
   * - ``thickness``
     - float or texture
     - 400
     - Film thickness in nm. A texture (e.g. ``bitmap`` with ``raw: True``) makes it vary over
       the surface; it is read with ``eval_1``.
     - yes, differentiable
   * - ``film_ior``
     - float, spectrum or material name
     - 1.37
     - Film refractive index n2. A name (``"MgF2"``, ``"PET"``, ``"BK7"``, ``"SiO2"``) uses the
       dispersion table shipped in ``thinfilm_bsdf/data``.
     - yes (float or spectrum), differentiable
   * - ``substrate_ior``
     - float
     - 1.6
     - Substrate index n3 (real part).
     - yes
   * - ``substrate_k``
     - float
     - 0
     - Substrate extinction k3 (> 0 for metals).
     - yes
   * - ``ext_ior``
     - float
     - 1.0
     - Exterior index n1.
     - yes
   * - ``wavelength``
     - float
     - 550
     - Wavelength in nm used in ``mono`` variants (which carry none). Changing it through
       ``mi.traverse`` reuses the compiled kernel.
     - yes, not differentiable

Reflection is a delta lobe (mirror direction); transmission is not modelled (the film sits
on an opaque or index-matched substrate). In polarized variants the BSDF returns the full
Mueller matrix of the film (both amplitudes and their phase difference), rotated into
Mitsuba's Stokes bases in the same way as Mitsuba's ``conductor``. With ``thickness = 0`` it
equals ``conductor`` with ``eta = substrate_ior, k = substrate_k``.

Works in the ``scalar_spectral[_polarized]``, ``llvm_ad_spectral[_polarized]``,
``llvm_ad_mono[_polarized]`` and ``cuda_*`` variants.

Example
-------
>>> import mitsuba as mi                                    # doctest: +SKIP
>>> mi.set_variant("llvm_ad_spectral_polarized")            # doctest: +SKIP
>>> import thinfilm.bsdf; thinfilm.bsdf.register()          # doctest: +SKIP
>>> bsdf = mi.load_dict({"type": "thinfilm", "thickness": 400.0,
...                      "film_ior": "MgF2", "substrate_ior": 1.6})  # doctest: +SKIP
"""

from __future__ import annotations

import numbers

import drjit as dr
import mitsuba as mi

from . import optics
from .materials import Constant, as_dispersion

__all__ = ["bsdf_class", "register", "variant_class"]


def _fail(message: str):
    raise ValueError(f"thinfilm: {message}")


def _positive_float(props, name, default, allow_zero=False):
    value = props.get(name, default) if name in props else default
    if not isinstance(value, numbers.Real):
        _fail(f"parameter '{name}' must be a number, got {type(value).__name__}")
    value = float(value)
    if value < 0 or (value == 0 and not allow_zero) or value != value:
        _fail(f"parameter '{name}' must be {'>= 0' if allow_zero else '> 0'}, got {value}")
    return value


def _texture(props, name):
    """The texture given for ``name`` (a texture or spectrum object), else None."""
    if name not in props:
        return None
    value = props.get(name)
    if isinstance(value, mi.Texture):
        return value
    if props.type(name) == mi.Properties.Type.Spectrum:
        return props.get_unbounded_texture(name)
    return None


class _ThinFilmMixin:
    """Thin-film interference BSDF (see the module docstring for the parameter table).

    Mitsuba's ``mi.BSDF`` is a different class in every variant, so the plugin
    class is made per variant by :func:`bsdf_class` from this mixin.
    """

    def __init__(self, props):
        mi.BSDF.__init__(self, props)
        if not (mi.is_spectral or mi.is_monochromatic):
            _fail(f"needs a spectral or mono variant, not '{mi.variant()}'")

        # Thickness: number or texture.
        self.m_thickness_tex = _texture(props, "thickness")
        if self.m_thickness_tex is not None:
            self.m_thickness = mi.Float(0.0)
        else:
            self.m_thickness = mi.Float(_positive_float(props, "thickness", 400.0, allow_zero=True))

        # Film index: number, spectrum texture or material name.
        self.m_film_tex = _texture(props, "film_ior")
        self.m_film_dispersion = None
        raw = props.get("film_ior", 1.37) if "film_ior" in props else 1.37
        if self.m_film_tex is not None:
            self.m_film_ior = mi.Float(0.0)
        elif isinstance(raw, str):
            try:
                disp = as_dispersion(raw)
            except ValueError as e:
                _fail(f"parameter 'film_ior': {e}")
            if isinstance(disp, Constant):
                self.m_film_ior = mi.Float(disp.n)
            else:
                self.m_film_dispersion = disp
                self.m_film_ior = mi.Float(0.0)
        else:
            self.m_film_ior = mi.Float(_positive_float(props, "film_ior", 1.37))

        self.m_substrate_ior = mi.Float(_positive_float(props, "substrate_ior", 1.6))
        self.m_substrate_k = mi.Float(_positive_float(props, "substrate_k", 0.0, allow_zero=True))
        self.m_ext_ior = mi.Float(_positive_float(props, "ext_ior", 1.0))
        self.m_wavelength = mi.Float(_positive_float(props, "wavelength", 550.0))

        flags = mi.BSDFFlags.DeltaReflection | mi.BSDFFlags.FrontSide
        self.m_components = [flags]
        self.m_flags = flags
        self._make_opaque()

    # -- parameters ---------------------------------------------------------

    def _make_opaque(self):
        # Opaque scalars become kernel inputs, not literals: changing them
        # (a wavelength sweep, a thickness fit) reuses the compiled kernel.
        dr.make_opaque(self.m_thickness, self.m_film_ior, self.m_substrate_ior,
                       self.m_substrate_k, self.m_ext_ior, self.m_wavelength)

    def traverse(self, callback):
        if self.m_thickness_tex is not None:
            callback.put("thickness", self.m_thickness_tex, mi.ParamFlags.Differentiable)
        else:
            callback.put("thickness", self.m_thickness, mi.ParamFlags.Differentiable)
        if self.m_film_tex is not None:
            callback.put("film_ior", self.m_film_tex, mi.ParamFlags.Differentiable)
        elif self.m_film_dispersion is None:
            callback.put("film_ior", self.m_film_ior, mi.ParamFlags.Differentiable)
        callback.put("substrate_ior", self.m_substrate_ior, mi.ParamFlags.Differentiable)
        callback.put("substrate_k", self.m_substrate_k, mi.ParamFlags.Differentiable)
        callback.put("ext_ior", self.m_ext_ior, mi.ParamFlags.NonDifferentiable)
        callback.put("wavelength", self.m_wavelength, mi.ParamFlags.NonDifferentiable)

    def parameters_changed(self, keys=[]):
        for name, value, allow_zero in (
            ("thickness", self.m_thickness, True),
            ("film_ior", self.m_film_ior, self.m_film_tex is not None or self.m_film_dispersion is not None),
            ("substrate_ior", self.m_substrate_ior, False),
            ("substrate_k", self.m_substrate_k, True),
            ("ext_ior", self.m_ext_ior, False),
            ("wavelength", self.m_wavelength, False),
        ):
            if name == "thickness" and self.m_thickness_tex is not None:
                continue
            v = dr.ravel(value)
            bad = dr.any((v < 0) | (v != v)) if allow_zero else dr.any((v <= 0) | (v != v))
            if bool(bad):
                _fail(f"parameter '{name}' must be {'>= 0' if allow_zero else '> 0'}, got {value}")
        self._make_opaque()

    # -- physics ------------------------------------------------------------

    def _wavelengths(self, si):
        if mi.is_spectral:
            return si.wavelengths
        return mi.UnpolarizedSpectrum(self.m_wavelength)

    def _film_index(self, si, wavelengths, active):
        if self.m_film_tex is not None:
            return self.m_film_tex.eval(si, active)
        if self.m_film_dispersion is not None:
            return self.m_film_dispersion(wavelengths)
        return mi.UnpolarizedSpectrum(self.m_film_ior)

    def _thickness(self, si, active):
        if self.m_thickness_tex is not None:
            return dr.maximum(self.m_thickness_tex.eval_1(si, active), 0.0)
        return self.m_thickness

    def _amplitudes(self, si, cos_theta, active):
        wavelengths = self._wavelengths(si)
        return optics.film_amplitudes(
            mi.UnpolarizedSpectrum(cos_theta),
            wavelengths,
            self._thickness(si, active),
            self._film_index(si, wavelengths, active),
            self.m_substrate_ior,
            self.m_substrate_k,
            self.m_ext_ior,
        )

    def _value(self, ctx, si, wo, active):
        if not mi.is_polarized:
            r_s, r_p = self._amplitudes(si, mi.Frame3f.cos_theta(si.wi), active)
            return mi.UnpolarizedSpectrum(0.5 * (r_s.abs2() + r_p.abs2()))

        # Light arrives along -wo_hat and leaves along +wi_hat (as in Mitsuba's conductor).
        radiance = ctx.mode == mi.TransportMode.Radiance
        wo_hat = wo if radiance else si.wi
        wi_hat = si.wi if radiance else wo
        r_s, r_p = self._amplitudes(si, mi.Frame3f.cos_theta(wo_hat), active)
        a, b, c, s = optics.mueller_entries(r_s, r_p)

        value = dr.zeros(mi.Spectrum)
        value[0, 0] = a
        value[0, 1] = b
        value[1, 0] = b
        value[1, 1] = a
        value[2, 2] = c
        value[2, 3] = s
        value[3, 2] = -s
        value[3, 3] = c

        # The Stokes reference axis of this matrix is perpendicular to the plane of reflection.
        n = mi.Vector3f(0, 0, 1)
        s_in = dr.cross(n, -wo_hat)
        s_out = dr.cross(n, wi_hat)
        collinear = dr.all(s_in == mi.Vector3f(0))
        s_in = dr.select(collinear, mi.Vector3f(1, 0, 0), dr.normalize(s_in))
        s_out = dr.select(collinear, mi.Vector3f(1, 0, 0), dr.normalize(s_out))
        return mi.mueller.rotate_mueller_basis(
            value,
            -wo_hat, s_in, mi.mueller.stokes_basis(-wo_hat),
            wi_hat, s_out, mi.mueller.stokes_basis(wi_hat),
        )

    # -- BSDF interface -----------------------------------------------------

    def sample(self, ctx, si, sample1, sample2, active=True):
        cos_theta_i = mi.Frame3f.cos_theta(si.wi)
        active = active & (cos_theta_i > 0)
        bs = dr.zeros(mi.BSDFSample3f)
        if not ctx.is_enabled(mi.BSDFFlags.DeltaReflection):
            return bs, dr.zeros(mi.Spectrum)
        bs.wo = mi.reflect(si.wi)
        bs.pdf = mi.Float(1.0)
        bs.eta = mi.Float(1.0)
        bs.sampled_component = mi.UInt32(0)
        bs.sampled_type = mi.UInt32(+mi.BSDFFlags.DeltaReflection)
        value = self._value(ctx, si, bs.wo, active)
        return bs, dr.select(active, value, dr.zeros(mi.Spectrum))

    def eval(self, ctx, si, wo, active=True):
        return dr.zeros(mi.Spectrum)

    def pdf(self, ctx, si, wo, active=True):
        return mi.Float(0.0)

    def eval_pdf(self, ctx, si, wo, active=True):
        return dr.zeros(mi.Spectrum), mi.Float(0.0)

    def to_string(self):
        film = (self.m_film_dispersion.name if self.m_film_dispersion is not None
                else "texture" if self.m_film_tex is not None else self.m_film_ior)
        thickness = "texture" if self.m_thickness_tex is not None else self.m_thickness
        return (f"ThinFilmBSDF[thickness={thickness} nm, film_ior={film}, "
                f"substrate_ior={self.m_substrate_ior}, substrate_k={self.m_substrate_k}, "
                f"ext_ior={self.m_ext_ior}, wavelength={self.m_wavelength} nm]")


_CLASSES: dict = {}


def variant_class(mixin, base: str, name: str):
    """A subclass of ``mi.<base>`` for the current Mitsuba variant, with ``mixin``'s methods.

    ``mi.BSDF``, ``mi.Texture`` … are different classes in every variant, and nanobind
    classes take one base, so Python plugins copy their methods into a per-variant subclass.
    """
    variant = mi.variant()
    if variant is None:
        raise RuntimeError(f"{name}: call mitsuba.set_variant(...) before using the plugin")
    key = (name, variant)
    if key not in _CLASSES:
        namespace = {k: v for k, v in vars(mixin).items() if k not in ("__dict__", "__weakref__")}
        _CLASSES[key] = type(name, (getattr(mi, base),), namespace)
    return _CLASSES[key]


def bsdf_class():
    """The plugin class for the current Mitsuba variant."""
    return variant_class(_ThinFilmMixin, "BSDF", "ThinFilmBSDF")


def register() -> None:
    """Make ``'type': 'thinfilm'`` loadable in the current Mitsuba variant (idempotent)."""
    cls = bsdf_class()
    mi.register_bsdf("thinfilm", lambda props: cls(props))
