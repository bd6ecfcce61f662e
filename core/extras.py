"""Optional parts of the package (pip *extras*) and the one message for a missing one.

``pip install thinfilm`` brings what the BSDF, the capture generator, the reconstruction
and the evaluation need. The rest comes with an extra:

========== ======================================= ====================================================
extra      packages                                what needs it
========== ======================================= ====================================================
cluster    dask, distributed                       ``--workers N`` (N > 0) and ``--scheduler`` of
                                                   ``thinfilm benchmark`` and ``thinfilm generate --sweep``
import     spectral, tifffile, imagecodecs         ``thinfilm import polarization`` and ``thinfilm
                                                   import spectral`` (TIFF, PNG, ENVI files), the raw
                                                   mosaic ``raw.tiff`` of ``rig.sensor = "dofp-rgb"``
docs       sphinx, numpydoc, myst-parser, ...      building the documentation
test       pytest, tmm, hypothesis, selenium, ...  the test suite (with the cluster and import extras)
all        all of the above
========== ======================================= ====================================================

Code that needs an optional module imports it where it is used, through
:func:`require_extra`: when the module is missing, the command line prints one line naming
the extra and exits with code 2 (a :class:`~thinfilm.core.errors.UserError`), e.g.
``thinfilm: error: --scheduler: needs the 'cluster' extra (dask, distributed): pip install
'thinfilm[cluster]'``.

Examples
--------
>>> require_extra("json", "cluster").__name__       # an installed module is returned
'json'
>>> try:
...     require_extra("no_such_module_xyz", "import", argument="layout")
... except UserError as e:
...     print(e)
layout: needs the 'import' extra (spectral, tifffile, imagecodecs): pip install 'thinfilm[import]'
"""

from __future__ import annotations

import importlib

from .errors import UserError

__all__ = ["EXTRAS", "require_extra", "has_module", "missing_extra_message"]

#: extra -> the packages it installs (as in ``pyproject.toml``) that the code imports
EXTRAS = {
    "cluster": ("dask", "distributed"),
    "import": ("spectral", "tifffile", "imagecodecs"),
}


def missing_extra_message(extra: str) -> str:
    """``needs the 'EXTRA' extra (packages): pip install 'thinfilm[EXTRA]'``."""
    packages = EXTRAS.get(extra, ())
    listed = f" ({', '.join(packages)})" if packages else ""
    return f"needs the '{extra}' extra{listed}: pip install 'thinfilm[{extra}]'"


def has_module(module: str) -> bool:
    """Whether ``module`` can be imported (it is imported to find out)."""
    try:
        importlib.import_module(module)
    except ImportError:
        return False
    return True


def require_extra(module: str, extra: str, argument: str | None = None, what: str | None = None):
    """Import and return ``module`` (e.g. ``"distributed"``, ``"spectral.io.envi"``), which the
    extra ``extra`` installs.

    Raises
    ------
    UserError
        One line when the module (or the package it belongs to) is not installed:
        ``[what ]needs the 'EXTRA' extra (...): pip install 'thinfilm[EXTRA]'``, about
        ``argument`` (the Python name of the option that asked for it) when given. An error
        raised while an installed module imports (a broken installation) is not masked.
    """
    if extra not in EXTRAS:
        raise ValueError(f"require_extra: unknown extra {extra!r} (one of {', '.join(EXTRAS)})")
    try:
        return importlib.import_module(module)
    except ImportError as e:
        missing = getattr(e, "name", None)
        top = module.split(".")[0]
        if missing is not None and not (missing == module or module.startswith(missing + ".")
                                         or missing == top):
            raise  # an installed package that fails to import one of its own dependencies
        head = f"{what} " if what else ""
        raise UserError(head + missing_extra_message(extra), argument=argument) from None
