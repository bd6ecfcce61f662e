"""Shared pytest fixtures: Mitsuba variants, with the thinfilm plugin registered."""

import mitsuba
import pytest


def _set_variant(name):
    """Every variant used here ships in Mitsuba's wheels: a missing one is a failure, not a skip."""
    mi = mitsuba
    assert name in mi.variants(), f"Mitsuba variant {name} is missing from this installation"
    mi.set_variant(name)
    import thinfilm.bsdf

    thinfilm.bsdf.register()
    return mi


@pytest.fixture
def use_variant():
    """Call with a variant name: sets it, registers the plugin, returns the mitsuba module."""
    return _set_variant


@pytest.fixture(params=["llvm_ad_mono_polarized", "llvm_ad_spectral_polarized", "scalar_spectral_polarized"])
def polarized_variant(request):
    return _set_variant(request.param)


@pytest.fixture(params=["llvm_ad_mono", "llvm_ad_spectral", "scalar_spectral"])
def unpolarized_variant(request):
    return _set_variant(request.param)
