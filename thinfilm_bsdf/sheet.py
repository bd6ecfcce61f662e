"""Mitsuba 3 plugin ``thinfilm_sheet``: a free-standing thin film or stack (a soap-bubble wall).

The same exterior medium lies on both sides of the film. Light is reflected (mirror
direction) or transmitted straight through (no lateral offset), both delta lobes, from
either side, with the interference colours of the film in both. It is Mitsuba's
``thindielectric`` with coherent interference in place of its incoherent sum of
multiple reflections.

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
     - Film thickness in nm (a texture, read with ``eval_1``, makes it vary over the surface:
       a draining bubble is thin at the top, thick at the bottom).
     - ``thickness``, differentiable
   * - ``film_ior``
     - float, spectrum, ``n+ki`` text or material name
     - 1.33
     - Film refractive index (``"H2O"`` is water with its dispersion; see
       :func:`thinfilm.bsdf.material_names`).
     - ``film_ior`` (float or spectrum), differentiable
   * - ``film_k``
     - float
     - 0
     - Film extinction k (absorbing for k > 0); not with a named material or ``n+ki`` text.
     - ``film_k``, differentiable
   * - ``stack``
     - string
     - (none)
     - A stack instead of one film, ``"INDEX:THICKNESS_NM, ..."`` listed from the front side
       (the side the surface normal points to); light arriving from the back meets the
       layers in reverse order. Not together with ``thickness``, ``film_ior``, ``film_k``.
     - ``layer_0.thickness``, ``layer_1.thickness``, … (differentiable); ``layer_<i>.ior``,
       ``layer_<i>.k`` for numeric indices
   * - ``thickness_scale``
     - float or texture
     - 1
     - Multiplies the thickness of every layer.
     - ``thickness_scale``, differentiable
   * - ``ext_ior``
     - float
     - 1.0
     - Index of the medium on both sides.
     - ``ext_ior``
   * - ``wavelength``
     - float
     - 550
     - Wavelength in nm used in ``mono`` variants.
     - ``wavelength``, not differentiable

Sampling chooses reflection with probability ``R / (R + T)`` (unpolarized reflectance and
transmittance averaged over the ray's wavelengths), so the sample weight is
``R + T`` (1 for a lossless film) in unpolarized variants. As in ``thindielectric``, the
transmission component is flagged ``Null`` (it does not bend the ray), and
``eval_null_transmission`` returns the transmittance. In polarized variants both lobes
carry the film's full Mueller matrices, rotated into Mitsuba's Stokes bases as
Mitsuba's ``dielectric`` does; with thickness 0 the transmission is the identity.
The optics are :func:`thinfilm.bsdf.optics.sheet_amplitudes`. In RGB variants the
reflectance and transmittance spectra are integrated against the colour basis of
:mod:`thinfilm.bsdf.rgb` (as the ``thinfilm`` plugin does).

Example
-------
>>> import mitsuba as mi                                    # doctest: +SKIP
>>> mi.set_variant("llvm_ad_spectral_polarized")            # doctest: +SKIP
>>> import thinfilm.bsdf; thinfilm.bsdf.register()          # doctest: +SKIP
>>> bubble = mi.load_dict({"type": "thinfilm_sheet", "thickness": 350.0,
...                        "film_ior": "H2O"})              # doctest: +SKIP
"""

from __future__ import annotations

import drjit as dr
import mitsuba as mi

from . import limits, optics, rgb
from .bsdf_common import (Film, broadcast_like, check_parameters, checked_float, mueller_spectrum,
                          to_stokes_bases, variant_class)

__all__ = ["sheet_class", "register"]

_NAME = "thinfilm_sheet"


class _ThinFilmSheetMixin:
    """Free-standing thin-film BSDF (see the module docstring for the parameter table)."""

    def __init__(self, props):
        mi.BSDF.__init__(self, props)
        self.m_rgb = rgb.colour_basis() if mi.is_rgb else None
        self.m_film = Film(props, plugin=_NAME, default_ior=1.33)
        self.m_ext_ior = mi.Float(checked_float(props, "ext_ior", 1.0, limits.INDEX, plugin=_NAME))
        self.m_wavelength = mi.Float(checked_float(props, "wavelength", 550.0, limits.WAVELENGTH_NM,
                                                   plugin=_NAME, unit="nm"))
        self.m_film.check_wavelengths(self.m_wavelength, _NAME)

        sides = mi.BSDFFlags.FrontSide | mi.BSDFFlags.BackSide
        self.m_components = [mi.BSDFFlags.DeltaReflection | sides, mi.BSDFFlags.Null | sides]
        self.m_flags = self.m_components[0] | self.m_components[1]
        self._make_opaque()

    # -- parameters ---------------------------------------------------------

    def _make_opaque(self):
        dr.make_opaque(*self.m_film.opaque(), self.m_ext_ior, self.m_wavelength)

    def traverse(self, callback):
        self.m_film.traverse(callback)
        callback.put("ext_ior", self.m_ext_ior, mi.ParamFlags.NonDifferentiable)
        callback.put("wavelength", self.m_wavelength, mi.ParamFlags.NonDifferentiable)

    def parameters_changed(self, keys=[]):
        check_parameters(_NAME, self.m_film.checks() + [("ext_ior", self.m_ext_ior, limits.INDEX),
                                                        ("wavelength", self.m_wavelength,
                                                         limits.WAVELENGTH_NM)])
        self.m_film.check_wavelengths(self.m_wavelength, _NAME)
        self._make_opaque()

    # -- physics ------------------------------------------------------------

    def _wavelengths(self, si):
        """The wavelengths (nm) of the ray (the ``wavelength`` parameter in mono variants)."""
        if mi.is_spectral:
            return si.wavelengths
        return mi.UnpolarizedSpectrum(self.m_wavelength)

    def _mueller_entries(self, si, cos_theta, wavelengths, active):
        """Reflection and transmission Mueller entries ``((a, b, c, s), (a_t, b_t, c_t, s_t))``
        of the sheet (s/p frame; :func:`optics.mueller_entries`,
        :func:`optics.transmission_mueller_entries`), one value per wavelength.

        ``cos_theta`` is the signed cosine of the direction the light arrives from: positive
        on the front side (the layers in the order given), negative on the back side (the
        layers reversed). Transmission is the same from both sides.
        """
        layers = self.m_film.layers(si, wavelengths, active)
        if len(layers) > 1:
            # From the back the light meets the layers in reverse order (per lane).
            front = cos_theta >= 0
            order = []
            for top, bottom in zip(layers, reversed(layers)):
                order.append(tuple(
                    dr.select(front, broadcast_like(x, wavelengths), broadcast_like(y, wavelengths))
                    for x, y in zip(top, bottom)))
            layers = order
        r_s, r_p, t_s, t_p = optics.sheet_amplitudes(
            broadcast_like(dr.abs(cos_theta), wavelengths), wavelengths, layers, self.m_ext_ior)
        return optics.mueller_entries(r_s, r_p), optics.transmission_mueller_entries(t_s, t_p)

    def _lobes(self, ctx, si, active):
        """The reflection and transmission values (Mueller matrices in Mitsuba's Stokes bases in
        polarized variants, spectra otherwise) for light leaving along ``si.wi``, and the mean
        unpolarized reflectance and transmittance over the ray's wavelengths."""
        cos_theta_i = mi.Frame3f.cos_theta(si.wi)
        if self.m_rgb is not None:
            # RGB variants: reflection and transmission entries integrated against the colour
            # basis, as the thinfilm plugin does (thinfilm.bsdf.rgb); unpolarized needs only
            # the first of each.
            def entries(lam):
                refl, trans = self._mueller_entries(si, cos_theta_i, lam, active)
                return (*refl, *trans) if mi.is_polarized else (refl[0], trans[0])

            count = 8 if mi.is_polarized else 2
            values = rgb.integrate(self.m_rgb, entries, count, mi.UnpolarizedSpectrum)
            refl, trans = (values[:4], values[4:]) if mi.is_polarized else ((values[0],), (values[1],))
        else:
            refl, trans = self._mueller_entries(si, cos_theta_i, self._wavelengths(si), active)
        R, T = dr.mean(refl[0], axis=0), dr.mean(trans[0], axis=0)
        if not mi.is_polarized:
            return refl[0], trans[0], R, T
        # Light arrives along -wo_hat and leaves along +wi_hat (as in Mitsuba's dielectric).
        radiance = ctx.mode == mi.TransportMode.Radiance
        wo_r = mi.reflect(si.wi)
        wo_t = -si.wi
        value_r = to_stokes_bases(mueller_spectrum(*refl), *((wo_r, si.wi) if radiance else (si.wi, wo_r)))
        value_t = to_stokes_bases(mueller_spectrum(*trans), *((wo_t, si.wi) if radiance else (si.wi, wo_t)))
        return value_r, value_t, R, T

    # -- BSDF interface -----------------------------------------------------

    def sample(self, ctx, si, sample1, sample2, active=True):
        has_r = ctx.is_enabled(mi.BSDFFlags.DeltaReflection, 0)
        has_t = ctx.is_enabled(mi.BSDFFlags.Null, 1)
        bs = dr.zeros(mi.BSDFSample3f)
        if not (has_r or has_t):
            return bs, dr.zeros(mi.Spectrum)

        value_r, value_t, R, T = self._lobes(ctx, si, active)
        if has_r and has_t:
            total = R + T
            prob_r = dr.select(total > 0, R / dr.select(total > 0, total, 1.0), 1.0)
            selected_r = (sample1 <= prob_r) & active
            bs.pdf = dr.select(selected_r, prob_r, 1.0 - prob_r)
        else:
            selected_r = mi.Bool(has_r) & active
            bs.pdf = mi.Float(1.0)

        bs.wo = dr.select(selected_r, mi.reflect(si.wi), -si.wi)
        bs.eta = mi.Float(1.0)
        bs.sampled_component = dr.select(selected_r, mi.UInt32(0), mi.UInt32(1))
        bs.sampled_type = dr.select(selected_r, mi.UInt32(+mi.BSDFFlags.DeltaReflection),
                                    mi.UInt32(+mi.BSDFFlags.Null))
        weight = dr.select(selected_r, value_r, value_t) / dr.select(bs.pdf > 0, bs.pdf, 1.0)
        active = active & (bs.pdf > 0)
        return bs, dr.select(active, mi.Spectrum(weight), dr.zeros(mi.Spectrum))

    def eval(self, ctx, si, wo, active=True):
        return dr.zeros(mi.Spectrum)

    def pdf(self, ctx, si, wo, active=True):
        return mi.Float(0.0)

    def eval_pdf(self, ctx, si, wo, active=True):
        return dr.zeros(mi.Spectrum), mi.Float(0.0)

    def eval_null_transmission(self, si, active=True):
        _, value_t, _, _ = self._lobes(mi.BSDFContext(), si, active)
        return dr.select(active, mi.Spectrum(value_t), dr.zeros(mi.Spectrum))

    def to_string(self):
        return (f"ThinFilmSheetBSDF[{self.m_film.describe()}, ext_ior={self.m_ext_ior}, "
                f"wavelength={self.m_wavelength} nm]")


def sheet_class():
    """The ``thinfilm_sheet`` plugin class for the current Mitsuba variant."""
    return variant_class(_ThinFilmSheetMixin, "BSDF", "ThinFilmSheetBSDF")


def register() -> None:
    """Make ``'type': 'thinfilm_sheet'`` loadable in the current Mitsuba variant (idempotent)."""
    cls = sheet_class()
    mi.register_bsdf(_NAME, lambda props: cls(props))
