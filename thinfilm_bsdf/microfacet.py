"""Rough thin films: microfacet reflection with the film's Mueller matrix.

A ``thinfilm`` BSDF with ``alpha > 0`` is Mitsuba's ``roughconductor`` with the bare
conductor's Fresnel term replaced by the film's reflection Mueller matrix:

* microfacet normals ``m`` come from Mitsuba's own :class:`mitsuba.MicrofacetDistribution`
  (GGX or Beckmann, visible or all normals), drawn with the same random numbers;
* the sampling weight is ``F G1(wo, m)`` (visible normals) or
  ``F G(wi, wo, m) (wi·m) / (cos θi cos θm)``; the density carries the half-vector Jacobian
  ``1 / (4 wo·m)``; ``eval`` is ``F D G / (4 cos θi)``;
* ``F`` is the film's matrix at the microfacet's angle of incidence, its Stokes reference
  axes perpendicular to the plane of reflection about ``m``, rotated into Mitsuba's Stokes
  bases of the incident and outgoing rays, with ``wi``/``wo`` exchanged in importance
  transport, as ``roughconductor`` does with ``mueller::specular_reflection``.

With ``thickness = 0`` a rough film is therefore ``roughconductor`` with
``eta = substrate_ior, k = substrate_k``, sample by sample. The film itself enters only
through the plugin's ``film_entries(si, cos_theta, count, active)`` (its Mueller entries at the
ray's wavelengths, or integrated against the colour basis in RGB variants), so film stacks
and RGB variants are rough in the same way.

Example
-------
>>> import mitsuba as mi                                    # doctest: +SKIP
>>> mi.set_variant("llvm_ad_spectral_polarized")            # doctest: +SKIP
>>> import thinfilm.bsdf; thinfilm.bsdf.register()          # doctest: +SKIP
>>> rough = mi.load_dict({"type": "thinfilm", "thickness": 400.0, "film_ior": "MgF2",
...                       "alpha": 0.15, "distribution": "ggx"})  # doctest: +SKIP

References
----------
B. Walter, S. Marschner, H. Li, K. Torrance, "Microfacet models for refraction through
rough surfaces", EGSR 2007. E. Heitz, E. d'Eon, "Importance sampling microfacet-based BSDFs
using the distribution of visible normals", EGSR 2014.
"""

from __future__ import annotations

import drjit as dr
import mitsuba as mi

from . import limits
from .bsdf_common import (check_texture, checked_float, clamped, fail, mueller_spectrum, texture_parameter,
                          to_stokes_bases)

__all__ = ["Roughness", "sample", "evaluate", "pdf", "evaluate_pdf"]

_DISTRIBUTIONS = {"ggx": "GGX", "beckmann": "Beckmann"}


class Roughness:
    """The microfacet parameters of a ``thinfilm`` BSDF, read from its properties.

    Parameters as in Mitsuba's ``roughconductor``: ``alpha`` or ``alpha_u`` and
    ``alpha_v`` (a float from 0 to 1, :data:`.limits.ALPHA`, or a texture, whose stored values are
    checked and whose values read are clamped into that range; all zero, the default, is a
    smooth film),
    ``distribution`` (``"ggx"``, the default, or ``"beckmann"``) and ``sample_visible``
    (default true). Attributes: ``is_rough`` (bool), ``flags`` (the lobe's BSDF flags).
    """

    def __init__(self, props):
        has_uv = "alpha_u" in props or "alpha_v" in props
        if has_uv and not ("alpha_u" in props and "alpha_v" in props):
            fail("parameters 'alpha_u' and 'alpha_v' must be given together")
        if has_uv and "alpha" in props:
            fail("give either 'alpha' or 'alpha_u' and 'alpha_v', not both")
        self.names = ("alpha_u", "alpha_v") if has_uv else ("alpha",)
        self.values = {}
        rough = False
        for name in self.names:
            tex = texture_parameter(props, name)
            if tex is not None:
                check_texture(tex, name, limits.ALPHA)
                self.values[name] = tex
                rough = True
            else:
                value = checked_float(props, name, 0.0, limits.ALPHA)
                self.values[name] = mi.Float(value)
                rough = rough or value > 0
        self.is_rough = rough
        self.anisotropic = has_uv

        name = props.get("distribution", "ggx") if "distribution" in props else "ggx"
        if not isinstance(name, str) or name.lower() not in _DISTRIBUTIONS:
            fail(f"parameter 'distribution' must be 'ggx' or 'beckmann', got {name!r}")
        self.distribution_name = name.lower()
        self.type = getattr(mi.MicrofacetType, _DISTRIBUTIONS[self.distribution_name])
        visible = props.get("sample_visible", True) if "sample_visible" in props else True
        if not isinstance(visible, bool):
            fail(f"parameter 'sample_visible' must be a boolean, got {visible!r}")
        self.sample_visible = visible

        flags = mi.BSDFFlags.GlossyReflection | mi.BSDFFlags.FrontSide
        if self.anisotropic:
            flags = flags | mi.BSDFFlags.Anisotropic
        self.flags = flags

    def scalars(self):
        """The exposed scalar roughness values by name (none for a smooth film)."""
        if not self.is_rough:
            return {}
        return {n: self.values[n] for n in self.names if not isinstance(self.values[n], mi.Texture)}

    def opaque(self):
        """The scalar roughness values, to be made opaque (kernel inputs, not literals)."""
        return list(self.scalars().values())

    def traverse(self, callback):
        """Expose ``alpha`` (or ``alpha_u``, ``alpha_v``) of a rough film, as ``roughconductor``."""
        if not self.is_rough:
            return
        for name in self.names:
            callback.put(name, self.values[name],
                         mi.ParamFlags.Differentiable | mi.ParamFlags.Discontinuous)

    def checks(self):
        """``(name, value, allow_zero)`` for the plugin's check of updated scalar parameters."""
        return [(name, value, limits.ALPHA) for name, value in self.scalars().items()]

    def distribution(self, si, active):
        """Mitsuba's microfacet distribution at ``si`` (roughness textures read with ``eval_1``)."""
        def value(name):
            v = self.values[name]
            return clamped(v.eval_1(si, active), limits.ALPHA) if isinstance(v, mi.Texture) else v

        if self.anisotropic:
            alpha_u, alpha_v = value("alpha_u"), value("alpha_v")
        else:
            # One variable for both axes: Mitsuba then treats the distribution as isotropic.
            alpha_u = alpha_v = value("alpha")
        return mi.MicrofacetDistribution(self.type, alpha_u, alpha_v, self.sample_visible)

    def describe(self) -> str:
        alphas = ", ".join(
            f"{n}={'texture' if isinstance(self.values[n], mi.Texture) else self.values[n]}"
            for n in self.names)
        return f"{alphas}, distribution={self.distribution_name}, sample_visible={self.sample_visible}"


def _skip(ctx, active) -> bool:
    """``roughconductor``'s early exit: glossy reflection disabled, or an inactive scalar lane."""
    if not ctx.is_enabled(mi.BSDFFlags.GlossyReflection):
        return True
    return not dr.is_jit_v(mi.Float) and not bool(active)


def _film_fresnel(bsdf, ctx, si, wo, m, active):
    """The film's reflection term for light mirrored about the microfacet normal ``m``.

    Unpolarized variants: the mean reflectance at ``cos θ = wi·m``. Polarized variants: the
    Mueller matrix at ``cos θ = wo_hat·m``, light arriving along ``-wo_hat`` and leaving along
    ``wi_hat``, rotated from the frame of the plane of reflection into Mitsuba's Stokes bases.
    """
    if not mi.is_polarized:
        return bsdf.film_entries(si, dr.dot(si.wi, m), 1, active)[0]

    radiance = ctx.mode == mi.TransportMode.Radiance
    wo_hat = wo if radiance else si.wi
    wi_hat = si.wi if radiance else wo
    a, b, c, s = bsdf.film_entries(si, dr.dot(wo_hat, m), 4, active)
    # The Stokes reference axis of this matrix is perpendicular to the plane of reflection about m.
    return to_stokes_bases(mueller_spectrum(a, b, c, s), wo_hat, wi_hat, normal=m)


def _scaled(F, weight, active):
    """``F * weight`` (every Mueller entry scaled by the spectrum ``weight``), zero where inactive."""
    if mi.is_polarized:
        for i in range(4):
            for j in range(4):
                F[i, j] = F[i, j] * weight
        return dr.select(active, F, dr.zeros(mi.Spectrum))
    return dr.select(active, mi.Spectrum(F * weight), dr.zeros(mi.Spectrum))


def sample(bsdf, ctx, si, sample2, active):
    """Sample the glossy lobe: returns ``(BSDFSample3f, weight)`` as ``roughconductor``."""
    bs = dr.zeros(mi.BSDFSample3f)
    cos_theta_i = mi.Frame3f.cos_theta(si.wi)
    active = active & (cos_theta_i > 0)
    if _skip(ctx, active):
        return bs, dr.zeros(mi.Spectrum)

    distr = bsdf.m_rough.distribution(si, active)
    m, bs.pdf = distr.sample(si.wi, sample2)
    bs.wo = mi.reflect(si.wi, m)
    bs.eta = mi.Float(1.0)
    bs.sampled_component = mi.UInt32(0)
    bs.sampled_type = mi.UInt32(+mi.BSDFFlags.GlossyReflection)
    active = active & (bs.pdf != 0) & (mi.Frame3f.cos_theta(bs.wo) > 0)

    if bsdf.m_rough.sample_visible:
        weight = distr.smith_g1(bs.wo, m)
    else:
        weight = (distr.G(si.wi, bs.wo, m) * dr.dot(si.wi, m)
                  / (cos_theta_i * mi.Frame3f.cos_theta(m)))
    bs.pdf = bs.pdf / (4.0 * dr.dot(bs.wo, m))  # Jacobian of the half-vector mapping

    F = _film_fresnel(bsdf, ctx, si, bs.wo, m, active)
    return bs, _scaled(F, mi.UnpolarizedSpectrum(weight), active)


def evaluate(bsdf, ctx, si, wo, active):
    """``F D G / (4 cos θi)`` (the cosine-weighted BSDF, as Mitsuba's ``eval``)."""
    cos_theta_i = mi.Frame3f.cos_theta(si.wi)
    cos_theta_o = mi.Frame3f.cos_theta(wo)
    active = active & (cos_theta_i > 0) & (cos_theta_o > 0)
    if _skip(ctx, active):
        return dr.zeros(mi.Spectrum)

    H = dr.normalize(wo + si.wi)
    distr = bsdf.m_rough.distribution(si, active)
    D = distr.eval(H)
    active = active & (D != 0)
    G = distr.G(si.wi, wo, H)
    result = mi.UnpolarizedSpectrum(D * G / (4.0 * cos_theta_i))

    F = _film_fresnel(bsdf, ctx, si, wo, H, active)
    return _scaled(F, result, active)


def _pdf_mask(si, wo, H, active):
    """Directions whose micro- and macro-surface agree on the side (as ``smith_g1`` demands)."""
    return (active & (mi.Frame3f.cos_theta(si.wi) > 0) & (mi.Frame3f.cos_theta(wo) > 0)
            & (dr.dot(si.wi, H) > 0) & (dr.dot(wo, H) > 0))


def pdf(bsdf, ctx, si, wo, active):
    """Solid-angle density of :func:`sample` at ``wo``."""
    m = dr.normalize(wo + si.wi)
    active = _pdf_mask(si, wo, m, active)
    if _skip(ctx, active):
        return mi.Float(0.0)

    distr = bsdf.m_rough.distribution(si, active)
    if bsdf.m_rough.sample_visible:
        result = distr.eval(m) * distr.smith_g1(si.wi, m) / (4.0 * mi.Frame3f.cos_theta(si.wi))
    else:
        result = distr.pdf(si.wi, m) / (4.0 * dr.dot(wo, m))
    return dr.select(active, result, 0.0)


def evaluate_pdf(bsdf, ctx, si, wo, active):
    """:func:`evaluate` and :func:`pdf` together, sharing ``D`` and ``G1(wi)``."""
    cos_theta_i = mi.Frame3f.cos_theta(si.wi)
    H = dr.normalize(wo + si.wi)
    active = _pdf_mask(si, wo, H, active)
    if _skip(ctx, active):
        return dr.zeros(mi.Spectrum), mi.Float(0.0)

    distr = bsdf.m_rough.distribution(si, active)
    D = distr.eval(H)
    active = active & (D != 0)
    smith_g1_wi = distr.smith_g1(si.wi, H)
    G = smith_g1_wi * distr.smith_g1(wo, H)
    value = mi.UnpolarizedSpectrum(D * G / (4.0 * cos_theta_i))

    F = _film_fresnel(bsdf, ctx, si, wo, H, active)
    if bsdf.m_rough.sample_visible:
        pdf_value = D * smith_g1_wi / (4.0 * cos_theta_i)
    else:
        pdf_value = distr.pdf(si.wi, H) / (4.0 * dr.dot(wo, H))
    return _scaled(F, value, active), dr.select(active, pdf_value, 0.0)
