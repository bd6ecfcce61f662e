"""thinfilm.reconstruction: estimate normals, film index and thickness from captures.

Modules
-------
:mod:`~thinfilm.reconstruction.methods`
    The built-in methods as records of the estimator registry (``thinfilm methods``).
:mod:`~thinfilm.reconstruction.rgb_capture`, :mod:`~thinfilm.reconstruction.rgb_paper`,
:mod:`~thinfilm.reconstruction.rgb_coherent`, :mod:`~thinfilm.reconstruction.rgb_model`,
:mod:`~thinfilm.reconstruction.rgb_invert`
    Polarized RGB, known film index: the paper's method and the coherent default.
:mod:`~thinfilm.reconstruction.spectral`, :mod:`~thinfilm.reconstruction.spectral_checks`,
:mod:`~thinfilm.reconstruction.spectral_paper`, :mod:`~thinfilm.reconstruction.spectral_eikonal`,
:mod:`~thinfilm.reconstruction.spectral_fit`, :mod:`~thinfilm.reconstruction.spectral_model`,
:mod:`~thinfilm.reconstruction.peaks`
    s-polarized hyperspectral, film index estimated: the paper's method and the eikonal default.
:mod:`~thinfilm.reconstruction.lm`, :mod:`~thinfilm.reconstruction.surface`,
:mod:`~thinfilm.reconstruction.eikonal`, :mod:`~thinfilm.reconstruction.masks`
    Shared tools: the batched Levenberg-Marquardt solver, normal integration, the eikonal
    surface, object masks and azimuth disambiguation.

This package imports :mod:`thinfilm.core` and :mod:`thinfilm.bsdf`, never
:mod:`thinfilm.generators`.
"""
