"""thinfilm.scenes: the preset scene specs (TOML) shipped with the package.

``hemisphere``, ``cylinder`` and ``pyramid`` are the paper's objects. Load one with
:func:`thinfilm.generators.spec.load_spec` (``load_spec("cylinder")``) or on the command
line (``thinfilm generate cylinder --out DIR``); copy a file as a starting point for your
own spec.
"""

from importlib import resources
from pathlib import Path

__all__ = ["PRESETS", "preset_file"]

PRESETS = ("hemisphere", "cylinder", "pyramid")


def preset_file(name: str) -> Path:
    """Path of the TOML file of preset ``name`` (no validation; see ``load_spec``)."""
    return Path(str(resources.files(__name__) / f"{name}.toml"))
