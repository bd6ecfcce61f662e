"""Mitsuba variants: the one the project renders captures in, and choosing one with a clear error.

Library code never sets a variant; entry points (the commands, test fixtures) call
:func:`use_variant`.
"""

from __future__ import annotations

from .errors import UserError

__all__ = ["RENDER_VARIANT", "use_variant"]

#: the variant datasets are rendered and re-rendered in: band by band, exact pixel-centre rays
RENDER_VARIANT = "llvm_ad_mono_polarized"


def use_variant(name: str = RENDER_VARIANT, where: str = "--variant"):
    """Set Mitsuba variant ``name`` and return the ``mitsuba`` module.

    Raises
    ------
    UserError
        One line when the variant is unknown, or cannot start on this machine (a CUDA variant
        without a GPU, an LLVM variant without libLLVM).
    """
    import mitsuba as mi

    if name not in mi.variants():
        raise UserError(f"{where}: unknown Mitsuba variant '{name}', expected one of {', '.join(mi.variants())}")
    try:
        mi.set_variant(name)
        if name.startswith(("llvm_", "cuda_")):
            import drjit as dr

            backend = dr.JitBackend.CUDA if name.startswith("cuda_") else dr.JitBackend.LLVM
            if not dr.has_backend(backend):
                raise RuntimeError("backend unavailable")
    except KeyboardInterrupt:
        raise
    except Exception as e:
        need = ("an NVIDIA GPU with CUDA" if name.startswith("cuda_") else
                "libLLVM (apt-get install libllvm19, or set DRJIT_LIBLLVM_PATH)")
        raise UserError(f"{where}: Mitsuba variant {name} cannot run on this machine: it needs {need} "
                        f"({str(e).splitlines()[0] if str(e) else type(e).__name__})") from None
    return mi
