"""The ranges of the plugins' parameters, shared with the generator's scene spec
(:data:`thinfilm.generators.spec_schema.LIMITS`). Imports nothing.

Each range is ``(low, high)``, inclusive, and every value must be finite:

* thickness: 0 to 100 µm. A film of 100 µm is no longer thin, and Mitsuba's single-precision
  floats keep the film's phase (``4π n d cos θ / λ``, about 10⁴ rad there) to about 10⁻³ rad;
  far beyond it the phase, and so the colour, is noise.
* refractive index ``n``: 0.01 to 100; extinction ``k``: 0 to 100 (a substrate's up to 10⁶: a very
  large k models an ideal mirror).
* microfacet roughness ``alpha`` (``alpha_u``, ``alpha_v``): 0 (smooth) to 1, as the scene
  spec's ``film.roughness``. Past 1 the GGX and Beckmann lobes are no longer glossy
  reflection but a nearly uniform haze, which ``diffuse`` models better.
* wavelength: 1 nm to 100 µm.
* layers of a stack: at most 200 in ``mono`` variants, 100 in spectral and 20 in RGB variants
  (:data:`MAX_STACK_LAYERS`, where the cost per layer is measured).
"""

__all__ = ["THICKNESS_NM", "INDEX", "EXTINCTION", "SUBSTRATE_EXTINCTION", "ALPHA", "WAVELENGTH_NM", "MAX_STACK_LAYERS",
           "MAX_STACK_LAYERS_SPECTRAL", "MAX_STACK_LAYERS_RGB", "max_stack_layers"]

THICKNESS_NM = (0.0, 1e5)
INDEX = (0.01, 100.0)
EXTINCTION = (0.0, 100.0)
#: a substrate may be far more absorbing than a film: a very large k models an ideal mirror
SUBSTRATE_EXTINCTION = (0.0, 1e6)
ALPHA = (0.0, 1.0)
WAVELENGTH_NM = (1.0, 1e5)

#: The most layers a ``stack`` may have in a ``mono`` variant (one wavelength per ray), and in the
#: scene spec's ``film.layers`` (the generator renders in ``llvm_ad_mono_polarized``).
#:
#: Why layers cost: the plugin's loop over the layers is Python, so Dr.Jit unrolls it into the
#: kernel, once per wavelength a ray carries: 1 in ``mono``, 4 in spectral variants, and in RGB
#: variants the whole stack at each of the 24 quadrature nodes of the colour basis (8 groups of
#: 3, :func:`thinfilm.bsdf.rgb.integrate`). Tracing that kernel is quick; LLVM's time to
#: compile it grows faster than its size. Measured (``llvm_ad_*``, a 4 x 4 image, 1 sample per
#: pixel, ``path`` of depth 2, a fresh kernel cache, on a shared 2-core machine), first render,
#: which compiles, and a second render, which reuses the kernel:
#:
#: * ``llvm_ad_mono_polarized``, 200 layers: 8.5 s (second 0.13 s);
#: * ``llvm_ad_spectral_polarized``, 1, 10, 20, 40, 100, 200 layers: 1.0, 1.6, 2.5, 4.8, 14.2,
#:   57.2 s (second 0.01 to 0.35 s);
#: * ``llvm_ad_rgb``, 1, 10, 20, 32, 40 layers: 0.6, 5.7, 15.8, 30.9, 52.4 s (second 0.02 to
#:   0.46 s);
#:
#: about 0.1 s per layer in a spectral variant up to 40 layers and 0.5 - 1 s per layer in an RGB
#: variant (where 60 layers take about 90 s and 200 several minutes). The limits keep a first
#: render of a stack under about 15 s: 200 layers in ``mono``, 100 in spectral, 20 in RGB variants.
MAX_STACK_LAYERS = 200
#: The most layers in a spectral variant (4 wavelengths per ray; see :data:`MAX_STACK_LAYERS`).
MAX_STACK_LAYERS_SPECTRAL = 100
#: The most layers in an RGB variant (24 quadrature wavelengths; see :data:`MAX_STACK_LAYERS`).
MAX_STACK_LAYERS_RGB = 20


def max_stack_layers(variant: str) -> int:
    """The most layers a ``stack`` may have in the Mitsuba variant named ``variant``."""
    if "_rgb" in variant:
        return MAX_STACK_LAYERS_RGB
    if "_spectral" in variant:
        return MAX_STACK_LAYERS_SPECTRAL
    return MAX_STACK_LAYERS
