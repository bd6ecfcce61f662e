"""Stokes fit, DoLP/AoLP and the polarization conventions of docs/design.md, *Conventions*."""

import numpy as np
import pytest

from thinfilm.core.errors import UserError
from thinfilm.core.conventions import (
    aolp_deg,
    check_polarizer_angles,
    dolp,
    fit_stokes,
    malus_intensity,
    stokes_from_polarizer_images,
)


def _malus(S0, S1, S2, angles):
    """Intensity behind an ideal polarizer written out independently of the module."""
    a = np.radians(np.asarray(angles, dtype=float))
    return np.stack([0.5 * (S0 + S1 * np.cos(2 * t) + S2 * np.sin(2 * t)) for t in a])


@pytest.mark.parametrize("angles", [[0, 45, 90, 135], [0, 60, 120], [10, 35, 80, 100, 170, 200]])
def test_fit_recovers_analytic_stokes(angles):
    rng = np.random.default_rng(1)
    S0 = rng.uniform(0.1, 1.0, (5, 7, 3))
    lin = rng.uniform(0.0, 1.0, S0.shape) * S0
    ang = rng.uniform(0, np.pi, S0.shape)
    S1, S2 = lin * np.cos(2 * ang), lin * np.sin(2 * ang)
    got = fit_stokes(_malus(S0, S1, S2, angles), angles)
    for g, ref in zip(got, (S0, S1, S2)):
        assert g.shape == ref.shape
        np.testing.assert_allclose(g, ref, atol=1e-12)


def test_four_angle_fit_is_the_design_definition():
    """S1 = I(0) - I(90), S2 = I(45) - I(135), S0 = mean sum: exactly, even for data that do not
    obey Malus' law (the 4-angle design is orthogonal)."""
    rng = np.random.default_rng(2)
    I = rng.uniform(0, 1, (4, 6))
    S0, S1, S2 = fit_stokes(I, [0, 45, 90, 135])
    np.testing.assert_allclose(S1, I[0] - I[2], atol=1e-14)
    np.testing.assert_allclose(S2, I[1] - I[3], atol=1e-14)
    np.testing.assert_allclose(S0, 0.5 * I.sum(axis=0), atol=1e-14)


def test_malus_law_for_linearly_polarized_light():
    """Fully polarized light at β through a polarizer at α: I = cos²(α - β) (Malus).
    The fit must give DoLP 1 and AoLP β, angles counted from +x towards +y."""
    for beta in (0.0, 30.0, 90.0, 121.0, 179.0):
        angles = [0, 45, 90, 135]
        I = np.array([np.cos(np.radians(a - beta)) ** 2 for a in angles])
        S0, S1, S2 = fit_stokes(I, angles)
        assert S0 == pytest.approx(1.0, abs=1e-12)
        assert dolp(S0, S1, S2) == pytest.approx(1.0, abs=1e-12)
        assert aolp_deg(S1, S2) == pytest.approx(beta % 180.0, abs=1e-9)
        # the module's own Malus function agrees with the law too
        np.testing.assert_allclose(malus_intensity(S0, S1, S2, angles), I, atol=1e-12)


def test_dolp_range_and_degenerate_pixels():
    S0 = np.array([1.0, 0.0, 0.5, 1.0, -1e-3])
    S1 = np.array([0.3, 0.0, 0.6, 0.0, 0.0])   # third: noise pushed |S12| above S0
    S2 = np.array([0.4, 0.0, 0.0, 0.0, 0.1])
    rho = dolp(S0, S1, S2)
    np.testing.assert_allclose(rho, [0.5, 0.0, 1.0, 0.0, 0.0])
    assert np.all((rho >= 0) & (rho <= 1))
    assert np.all((aolp_deg(S1, S2) >= 0) & (aolp_deg(S1, S2) < 180))


@pytest.mark.parametrize("angles", [[0, 90], [0, 90, 180], [45, 225, 135, 315], []])
def test_too_few_distinct_angles_is_a_user_error(angles):
    with pytest.raises(UserError, match="3 polarizer angles"):
        check_polarizer_angles(angles, "polarized_rgb.exr")


def test_stokes_from_dataset_layers():
    with pytest.raises(UserError, match="no polarizer layers"):
        stokes_from_polarizer_images({})
    imgs = {a: np.full((2, 2, 3), v) for a, v in ((0, 1.0), (45, 0.5), (90, 0.0), (135, 0.5))}
    S0, S1, S2 = stokes_from_polarizer_images(imgs)
    np.testing.assert_allclose(S1, 1.0)
    np.testing.assert_allclose(S2, 0.0, atol=1e-15)
    np.testing.assert_allclose(S0, 1.0)


def test_specular_reflection_peaks_along_the_s_direction():
    """For a specular pixel of normal n seen along v = +z, the transmitted intensity must peak
    at the s-direction, the image angle of n × v (perpendicular to the plane of incidence):
    φ + 90° in the frame of docs/design.md, *Conventions*. The reference direction is computed
    here from vector geometry; the model's Stokes come from the optics core."""
    from thinfilm.core.film import Film
    from thinfilm.reconstruction.rgb_model import FilmCamera

    model = FilmCamera(np.arange(400.0, 721.0, 8.0), Film.single(1.37, None, 1.6))
    rng = np.random.default_rng(3)
    zen = rng.uniform(5, 80, 50)
    az = rng.uniform(0, 360, 50)
    t, p = np.radians(zen), np.radians(az)
    n = np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], axis=-1)
    s_dir = np.cross(n, [0.0, 0.0, 1.0])
    s_angle = np.mod(np.degrees(np.arctan2(s_dir[:, 1], s_dir[:, 0])), 180.0)
    # Bare substrate (thickness 0): R_s > R_p at every band, so the peak is the s-direction.
    angles = list(range(0, 180, 15))
    I = model.polarized_rgb(zen, az, np.zeros(50), angles)
    S0, S1, S2 = fit_stokes(np.stack([I[a] for a in angles]), angles)
    got = aolp_deg(S1.mean(axis=-1), S2.mean(axis=-1))
    diff = np.abs((got - s_angle + 90.0) % 180.0 - 90.0)
    assert diff.max() < 1e-9
    assert np.allclose((s_angle - az) % 180.0, 90.0)
