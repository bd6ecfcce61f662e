"""thinfilm.generators: synthetic thin-film captures with exact ground truth.

Modules
-------
:mod:`~thinfilm.generators.spec`, :mod:`~thinfilm.generators.spec_schema`
    Scene specs (TOML, presets, ``--set`` overrides) → a validated, typed ``SceneSpec``.
:mod:`~thinfilm.generators.shapes`, :mod:`~thinfilm.generators.frame`, :mod:`~thinfilm.generators.thickness`
    The object, the orthographic view, the film thickness over the image.
:mod:`~thinfilm.generators.scene`
    Mitsuba scenes (object, lighting dome, camera), and ``normal_map_scene`` to re-render
    estimated normal and thickness fields through the same plugin and rig.
:mod:`~thinfilm.generators.ground_truth`
    Ground truth by ray casting the camera's pixel-centre rays.
:mod:`~thinfilm.generators.render`
    Band-integrated Stokes cubes (``render_stokes_cube``).
:mod:`~thinfilm.generators.captures`, :mod:`~thinfilm.generators.noise`
    What the two cameras record; the ``camera`` noise model.
:mod:`~thinfilm.generators.generate`
    ``generate_dataset`` and the ``thinfilm generate`` command.
:mod:`~thinfilm.generators.textures`
    The ``imagespace`` Mitsuba texture.

Nothing here imports Mitsuba at import time; rendering needs the variant
:data:`thinfilm.core.variants.RENDER_VARIANT`, which entry points select. This package
imports :mod:`thinfilm.core` and :mod:`thinfilm.bsdf`, never :mod:`thinfilm.reconstruction`.
"""

__all__ = ["captures", "frame", "generate", "ground_truth", "noise", "render", "scene", "shapes", "spec",
           "spec_schema", "textures", "thickness"]
