"""thinfilm.generators: synthetic thin-film captures with exact ground truth.

Modules
-------
:mod:`~thinfilm.generators.spec`
    Scene specs (TOML, presets, ``--set`` overrides) → resolved, validated dictionaries.
:mod:`~thinfilm.generators.scene`
    Mitsuba scenes (shapes, image-space thickness, lighting dome, orthographic camera),
    ground truth by ray casting, and ``normal_map_scene`` to re-render estimated normal and
    thickness fields through the same plugin and rig.
:mod:`~thinfilm.generators.render`
    Band-integrated Stokes cubes (``render_stokes_cube``) and the camera captures computed
    from them (``captures_from_stokes``).
:mod:`~thinfilm.generators.noise`
    The ``camera`` noise model.
:mod:`~thinfilm.generators.generate`
    ``generate_dataset`` and the ``thinfilm generate`` command.

Nothing here imports Mitsuba at import time; rendering needs the
``llvm_ad_mono_polarized`` variant, which entry points select
(:func:`thinfilm.generators.generate.set_variant`).
"""

__all__ = ["generate", "noise", "render", "scene", "spec", "textures"]
