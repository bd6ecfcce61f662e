"""Shared pytest fixtures: Mitsuba variants, set for one test and restored after it.

In Mitsuba's manner, a test asks for the variant it runs in by a fixture: ``variant_NAME``
for one variant (``variant_llvm_ad_mono_polarized`` …), ``polarized_variant`` /
``unpolarized_variant`` to run over several, ``mitsuba_variant`` with an indirect
parametrization for a list of its own. A test that compares two variants takes one by
fixture and enters the other with the :func:`variant` context manager. The fixture sets the variant, registers the
project's plugins, yields the ``mitsuba`` module, then flushes Dr.Jit's memory cache and
restores the variant that was set before, so no variant leaks from one test into the next.
``render_variant_module`` does the same for a whole module (the capture generator's
variant, for module-scoped datasets). Test bodies never call ``mi.set_variant``.

Every variant used here ships in Mitsuba's wheels: a missing one is a failure, not a skip.
"""

import contextlib

import mitsuba
import pytest

from thinfilm.core.variants import RENDER_VARIANT


@contextlib.contextmanager
def variant(name):
    """Set ``name`` and register the plugins; restore the previous variant afterwards."""
    mi = mitsuba
    assert name in mi.variants(), f"Mitsuba variant {name} is missing from this installation"
    previous = mi.variant()
    mi.set_variant(name)
    import thinfilm.bsdf

    thinfilm.bsdf.register()
    try:
        yield mi
    finally:
        import drjit as dr

        dr.sync_thread()
        dr.flush_malloc_cache()
        if previous is not None and previous != name:
            mi.set_variant(previous)


def _variant_fixture(name):
    @pytest.fixture
    def fixture():
        with variant(name) as mi:
            yield mi

    fixture.__doc__ = f"Mitsuba in variant {name} (set for the test, restored after)."
    return fixture


for _name in ("llvm_ad_mono_polarized", "llvm_ad_mono", "llvm_ad_spectral_polarized", "llvm_ad_spectral",
              "llvm_ad_rgb", "scalar_spectral_polarized", "scalar_spectral", "scalar_rgb"):
    globals()[f"variant_{_name}"] = _variant_fixture(_name)


@pytest.fixture
def mitsuba_variant(request):
    """The variant named by an indirect parametrization
    (``@pytest.mark.parametrize("mitsuba_variant", [...], indirect=True)``)."""
    with variant(request.param) as mi:
        yield mi


@pytest.fixture(params=["llvm_ad_mono_polarized", "llvm_ad_spectral_polarized", "scalar_spectral_polarized"])
def polarized_variant(request):
    with variant(request.param) as mi:
        yield mi


@pytest.fixture(params=["llvm_ad_mono", "llvm_ad_spectral", "scalar_spectral"])
def unpolarized_variant(request):
    with variant(request.param) as mi:
        yield mi


@pytest.fixture(scope="module")
def render_variant_module():
    """The capture generator's variant for a whole module (module-scoped datasets)."""
    with variant(RENDER_VARIANT) as mi:
        yield mi


@pytest.fixture
def render_variant():
    """The capture generator's variant for one test."""
    with variant(RENDER_VARIANT) as mi:
        yield mi
