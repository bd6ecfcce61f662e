"""The ranges of the plugins' parameters, shared with the generator's scene spec
(:data:`thinfilm.generators.spec_schema.LIMITS`). Imports nothing.

Each range is ``(low, high)``, inclusive, and every value must be finite:

* thickness: 0 to 100 µm. A film of 100 µm is no longer thin, and Mitsuba's single-precision
  floats keep the film's phase (``4π n d cos θ / λ``, about 10⁴ rad there) to about 10⁻³ rad;
  far beyond it the phase, and so the colour, is noise.
* refractive index ``n``: 0.01 to 100; extinction ``k``: 0 to 100.
* microfacet roughness ``alpha`` (``alpha_u``, ``alpha_v``): 0 (smooth) to 1, as the scene
  spec's ``film.roughness``. Past 1 the GGX and Beckmann lobes are no longer glossy
  reflection but a nearly uniform haze, which ``diffuse`` models better.
* wavelength: 1 nm to 100 µm.
* layers of a stack: at most :data:`MAX_STACK_LAYERS` (see there for the cost per layer).
"""

__all__ = ["THICKNESS_NM", "INDEX", "EXTINCTION", "ALPHA", "WAVELENGTH_NM", "MAX_STACK_LAYERS",
           "MAX_STACK_LAYERS_RGB"]

THICKNESS_NM = (0.0, 1e5)
INDEX = (0.01, 100.0)
EXTINCTION = (0.0, 100.0)
ALPHA = (0.0, 1.0)
WAVELENGTH_NM = (1.0, 1e5)

#: The most layers a ``stack`` may have (the plugins and the scene spec's ``film.layers``).
#: The layers are a Python loop that Dr.Jit unrolls into the kernel: its size, the time to
#: trace it and LLVM's time to compile it grow with the number of layers, and an RGB variant
#: evaluates the whole stack at each of its 8 groups of 3 quadrature wavelengths (24 nodes),
#: so its kernel is 8 times a spectral variant's. Measured on one CPU core (a 4 x 4 image,
#: 1 sample per pixel, ``path`` of depth 2), load and first render: see ``MAX_STACK_LAYERS``
#: in ``docs`` and the plugin's docstring.
MAX_STACK_LAYERS = 200
#: The most layers in an RGB variant, whose kernel holds the stack 8 times over (see above).
MAX_STACK_LAYERS_RGB = 32
