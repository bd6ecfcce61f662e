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
    from . import signals

    with signals.deferred():  # Ctrl-C while Dr.Jit and Mitsuba initialise: raised after it
        return _use_variant(name, where)


def _use_variant(name, where):
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
        from . import signals

        if signals.received() is not None:
            raise KeyboardInterrupt from None  # an interrupted import, not a missing library
        need = ("an NVIDIA GPU with CUDA" if name.startswith("cuda_") else
                "libLLVM (apt-get install libllvm19, or set DRJIT_LIBLLVM_PATH)")
        raise UserError(f"{where}: Mitsuba variant {name} cannot run on this machine: it needs {need} "
                        f"({str(e).splitlines()[0] if str(e) else type(e).__name__})") from None
    _route_mitsuba_log(mi)
    return mi


_appender = None


def _route_mitsuba_log(mi) -> None:
    """Mitsuba's log warnings become Python warnings (:class:`ThinfilmWarning`, ``Mitsuba: ...``)
    instead of lines printed straight to the terminal, so a command prints each as one
    ``thinfilm: warning:`` line when it succeeds, and only its error when it fails. Errors
    reach us as exceptions; information and debug messages are dropped."""
    global _appender
    if _appender is not None:
        return
    import re
    import warnings

    from .errors import ThinfilmWarning

    class _WarningAppender(mi.Appender):
        def append(self, level, text):
            if level == mi.LogLevel.Warn:
                text = re.sub(r"^\S+ \S+ WARN\s+", "", str(text)).strip()
                warnings.warn(f"Mitsuba: {text}", ThinfilmWarning, stacklevel=2)

        def log_progress(self, *args):
            pass

    try:
        logger = mi.logger() if hasattr(mi, "logger") else mi.Thread.thread().logger()
        appender = _WarningAppender()
        logger.clear_appenders()
        logger.add_appender(appender)
    except Exception:  # an older Mitsuba without these bindings: keep its own log
        return
    _appender = appender
