"""thinfilm: spectral, polarized thin-film rendering and reconstruction.

Subpackages: :mod:`thinfilm.bsdf` (optics core and Mitsuba plugin),
:mod:`thinfilm.scenes`, :mod:`thinfilm.generators`, :mod:`thinfilm.reconstruction`.
"""

import glob as _glob
import os as _os

__version__ = "0.1.0"
__all__ = ["__version__"]


def _prefer_llvm19():
    """Point Dr.Jit at Debian's libLLVM 19 when present: the LLVM 14/15 libraries of some
    images abort in Mitsuba's llvm_* variants. A user's own DRJIT_LIBLLVM_PATH wins."""
    if "DRJIT_LIBLLVM_PATH" not in _os.environ:
        found = sorted(_glob.glob("/usr/lib/*/libLLVM-19.so") + _glob.glob("/usr/lib/*/libLLVM.so.19*"))
        if found:
            _os.environ["DRJIT_LIBLLVM_PATH"] = found[0]


_prefer_llvm19()
