"""Reconstruction beyond the presets: new generator shapes against analytic geometry, the
Airy form and the Stokes-cube fit against tmm, the film index on either side of the
substrate's from the physics of the spectra, the global azimuth disambiguation on analytic
normal fields (tori, ridges, creases, sheets), the joint choice of thickness basins, masks,
coarse integration, and the paper's methods refusing films above their substrate's index."""

from __future__ import annotations

import math
import warnings
from pathlib import Path

import numpy as np
import pytest
import tmm

from thinfilm.core.errors import UserError

WL = np.arange(400.0, 721.0, 4.0)


def _angle_deg(a, b):
    a = a / np.linalg.norm(a, axis=-1, keepdims=True)
    b = b / np.linalg.norm(b, axis=-1, keepdims=True)
    return np.degrees(np.arctan2(np.linalg.norm(np.cross(a, b), axis=-1), np.sum(a * b, axis=-1)))


def _tmm_rs_rp(theta_deg, d_nm, n2, n3, wavelengths=WL):
    """R_s, R_p spectra of one film from tmm (the independent reference)."""
    th = math.radians(theta_deg)
    out = []
    for pol in ("s", "p"):
        out.append(np.array([tmm.coh_tmm(pol, [1.0, n2, n3], [np.inf, d_nm, np.inf], th, lam)["R"]
                             for lam in wavelengths]))
    return out


def _rotation(deg):
    """The spec's ``rotate_deg``: x, then y, then z about the fixed axes (SciPy's extrinsic
    Euler angles, an independent reference for the generator's matrices)."""
    from scipy.spatial.transform import Rotation

    return Rotation.from_euler("xyz", deg, degrees=True).as_matrix()


# --- generator shapes: ray-cast ground truth against analytic geometry ---------------------------

def _cast(shape, resolution=48):
    from thinfilm.generators.scene import build_scene
    from thinfilm.generators.spec import load_spec

    _, gt = build_scene(load_spec({"shape": shape, "rig": {"resolution": resolution}, "noise": {"model": "none"}}))
    frame = gt["frame"]
    x, y = frame.pixel_centres()
    p = np.stack([x, y, frame.camera_z - gt["depth"]], axis=-1)
    return gt, p


def _analytic_normal(kind, p, shape):
    """Outward normal of the analytic surface at points ``p`` (world frame: the shape is built
    about its own origin and not moved)."""
    R = _rotation(shape.get("rotate_deg", [0.0, 0.0, 0.0]))
    q = p @ R                                    # local coordinates (R orthonormal)
    if kind == "torus":
        rho = np.hypot(q[..., 0], q[..., 1])[..., None]
        centre = shape["major_radius"] * np.concatenate([q[..., :2] / rho, np.zeros_like(rho)], axis=-1)
        n = q - centre
    elif kind == "ellipsoid":
        n = q / np.asarray(shape["semi_axes"]) ** 2
    elif kind == "capsule":                      # axis along local y (built about z, turned)
        h = 0.5 * shape["length"]
        on_axis = np.stack([np.zeros(q.shape[:-1]), np.clip(q[..., 1], -h, h), np.zeros(q.shape[:-1])], -1)
        n = q - on_axis
    else:
        raise AssertionError(kind)
    return (n / np.linalg.norm(n, axis=-1, keepdims=True)) @ R.T


@pytest.mark.slow
@pytest.mark.parametrize("shape", [
    {"kind": "torus", "major_radius": 1.0, "minor_radius": 0.35},
    {"kind": "torus", "major_radius": 1.0, "minor_radius": 0.4, "rotate_deg": [40.0, 0.0, 25.0]},
    {"kind": "ellipsoid", "semi_axes": [1.0, 0.6, 0.5], "rotate_deg": [30.0, -20.0, 40.0]},
    {"kind": "capsule", "radius": 0.5, "length": 1.5, "rotate_deg": [20.0, 0.0, 35.0]},
], ids=["torus", "torus-tilted", "ellipsoid", "capsule"])
def test_mesh_shapes_shade_with_their_analytic_normals(render_variant, shape):
    gt, p = _cast(shape)
    m = gt["mask"]
    assert m.sum() > 300
    err = _angle_deg(gt["normal"][m], _analytic_normal(shape["kind"], p[m], shape))
    # smooth shading of a 256-section mesh: the interpolated normal is within a fraction of a
    # degree of the surface's at the hit point (which lies on a flat facet)
    assert np.median(err) < 0.3 and np.percentile(err, 99) < 1.5


@pytest.mark.slow
def test_torus_facing_the_camera_shows_its_hole(render_variant):
    gt, p = _cast({"kind": "torus", "major_radius": 1.0, "minor_radius": 0.35})
    from scipy import ndimage

    m = gt["mask"]
    holes = ndimage.binary_fill_holes(m) & ~m
    assert holes.sum() > 0.5 * math.pi * (0.65 / 1.35 * 0.9 * 24) ** 2    # the hole, seen through
    # at the hole's edge the normals point into the hole: an occluding contour inside the object
    edge = m & ndimage.binary_dilation(holes)
    r = np.hypot(p[..., 0], p[..., 1])
    radial = (gt["normal"][..., 0] * p[..., 0] + gt["normal"][..., 1] * p[..., 1]) / np.maximum(r, 1e-9)
    assert np.mean(radial[edge] < -0.5) > 0.9


@pytest.mark.slow
def test_sheet_cap_and_group(render_variant):
    sheet = {"kind": "sheet", "size": 2.0, "wavelength": 1.0, "amplitude": 0.06, "direction_deg": 30.0}
    gt, p = _cast(sheet)
    m = gt["mask"]
    a = math.radians(30.0)
    u = p[..., 0] * math.cos(a) + p[..., 1] * math.sin(a)
    k = 2 * math.pi
    # default phase 90 degrees: a crest through the centre, z = A cos(k u)
    np.testing.assert_allclose(p[..., 2][m], 0.06 * np.cos(k * u[m]), atol=2e-3)
    dz = -0.06 * k * np.sin(k * u)
    n = np.stack([-dz * math.cos(a), -dz * math.sin(a), np.ones_like(dz)], -1)
    assert np.percentile(_angle_deg(gt["normal"][m], n[m]), 99) < 0.5
    assert m.mean() > 0.6                              # the whole square faces the camera

    gt, p = _cast({"kind": "cap", "radius": 1.0, "height": 0.3})
    m = gt["mask"]
    # the rim of a cap of height h sits at sqrt(2 r h - h²) and is tilted acos(1 - h/r)
    rim = math.sqrt(2 * 0.3 - 0.09)
    assert np.max(np.hypot(p[..., 0], p[..., 1])[m]) == pytest.approx(rim, abs=2 * 2 * rim / 0.9 / 48)
    assert np.max(gt["zenith"][m]) == pytest.approx(math.degrees(math.acos(0.7)), abs=2.0)

    from scipy import ndimage

    gt, _ = _cast({"kind": "group", "parts": [{"kind": "hemisphere", "radius": 0.5, "offset": [-1.0, 0.0, 0.0]},
                                             {"kind": "ellipsoid", "semi_axes": [0.4, 0.3, 0.3],
                                              "offset": [1.0, 0.2, 0.0]}]})
    assert ndimage.label(gt["mask"])[1] == 2


def test_group_specs_validate_and_round_trip(tmp_path):
    from thinfilm.generators.spec import load_spec

    spec = load_spec({"shape": {"kind": "group", "parts": [{"kind": "torus", "offset": [0.5, 0.0, 0.0]},
                                                           {"kind": "cap", "height": 0.4}]}})
    assert spec.shape.params["parts"][1] == {"kind": "cap", "radius": 1.0, "height": 0.4,
                                             "rotate_deg": [0.0, 0.0, 0.0], "offset": [0.0, 0.0, 0.0]}
    path = tmp_path / "g.toml"
    path.write_text(spec.to_toml())
    assert load_spec(path) == spec
    with pytest.raises(UserError, match=r"'shape.parts\[0\].kind' must be one of"):
        load_spec({"shape": {"kind": "group", "parts": [{"kind": "mesh"}]}})
    with pytest.raises(UserError, match=r"'shape.parts' must be a list of shape tables"):
        load_spec({"shape": {"kind": "group", "parts": []}})
    with pytest.raises(UserError, match=r"'shape.semi_axes' must be a list of 3 lengths in scene units"):
        load_spec({"shape": {"kind": "ellipsoid", "semi_axes": [1.0, 0.0, 1.0]}})


def test_standard_suite_specs_load():
    import tomllib
    from pathlib import Path

    from thinfilm import scenes
    from thinfilm.generators.spec import load_spec

    suite_path = Path(scenes.__file__).parent / "suites" / "standard.toml"
    suite = tomllib.loads(suite_path.read_text())
    names = [s["name"] for s in suite["scenes"]]
    assert len(names) == len(set(names)) >= 16
    kinds = set()
    for s in suite["scenes"]:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            spec = load_spec(suite_path.parent / s["spec"], overrides=s.get("overrides", []))
        kinds.add(spec.shape.kind)
        assert set(s["kinds"]) <= {"rgb", "spectral"}
    assert {"torus", "capsule", "ellipsoid", "cap", "sheet", "group", "pyramid", "hemisphere", "cylinder"} <= kinds


# --- the Airy form and the Stokes-cube fit against tmm ----------------------------------------------

@pytest.mark.parametrize("n2, n3", [(1.38, 1.6), (2.3, 1.5), (1.55, 1.6)])
def test_the_spectral_fits_model_matches_tmm(n2, n3):
    """The s and p spectra the spectral fits compare with (the observation model, in single
    precision) against tmm."""
    from thinfilm.reconstruction.spectral_model import rs_spectra

    for theta, d in ((0.0, 450.0), (35.0, 610.0), (72.0, 300.0)):
        sp = rs_spectra(np.radians([theta]), [d], n2, n3, WL, with_p=True)[0]
        ref_s, ref_p = _tmm_rs_rp(theta, d, n2, n3)
        np.testing.assert_allclose(sp[:WL.size], ref_s, rtol=4e-6, atol=1e-7)  # float32
        np.testing.assert_allclose(sp[WL.size:], ref_p, rtol=4e-6, atol=1e-7)


@pytest.mark.parametrize("copies", [1, 64])
def test_stokes_fit_recovers_zenith_azimuth_axis_and_thickness_from_tmm_spectra(copies):
    """The s and p spectra fix the zenith at every pixel, also near normal incidence where
    the s spectrum's peak barely changes with the angle (paper Sec. 6.1's weak spot). With
    64 copies of each pixel as with one."""
    from thinfilm.reconstruction import spectral_model as sm
    from thinfilm.reconstruction.spectral_stokes import angles_to_x, fit_stokes_pixels, x_to_angles

    n2, n3 = 1.38, 1.6
    cases = [(3.0, 40.0, 420.0), (8.0, 130.0, 520.0), (30.0, 75.0, 610.0), (62.0, 170.0, 380.0)]
    S0, S1, S2 = [], [], []
    for theta, phi, d in cases:
        Rs, Rp = _tmm_rs_rp(theta, d, n2, n3)
        P = 0.5 * (Rs - Rp)
        S0.append(0.5 * (Rs + Rp))
        S1.append(-P * math.cos(math.radians(2 * phi)))
        S2.append(-P * math.sin(math.radians(2 * phi)))
    S0, S1, S2 = (np.tile(np.array(a), (copies, 1)) for a in (S0, S1, S2))
    th0 = np.radians([c[0] for c in cases]) + np.radians([2.0, -2.0, 1.5, -1.0])
    x0 = angles_to_x(th0, np.radians([c[1] + 10.0 for c in cases]), [c[2] + 6.0 for c in cases])
    fit = fit_stokes_pixels(S0, S1, S2, np.tile(x0, (copies, 1)), n2, n3, WL, iterations=30)
    th, phi, d = x_to_angles(fit.x)
    np.testing.assert_allclose(np.degrees(th), [c[0] for c in cases] * copies, atol=0.01)
    np.testing.assert_allclose(np.mod(np.degrees(phi), 180.0), [c[1] for c in cases] * copies, atol=0.05)
    np.testing.assert_allclose(d, [c[2] for c in cases] * copies, atol=0.01)
    # the s peak alone: 3° and 8° differ by 2 % in peak reflectance (a few noise levels)
    r3, r8 = sm.peak_reflectance(np.radians([3.0, 8.0]), n3)
    assert abs(r8 - r3) / r3 < 0.025


def test_azimuth_axis_from_stokes_when_p_exceeds_s_in_some_bands():
    from thinfilm.reconstruction.spectral_stokes import axis_from_stokes

    P = np.array([[0.02, 0.015, -0.004, 0.01, 0.02]])          # R_p > R_s in one band
    phi = math.radians(25.0)
    S1, S2 = -P * math.cos(2 * phi), -P * math.sin(2 * phi)
    got, strength = axis_from_stokes(S1, S2)
    assert math.degrees(got[0]) == pytest.approx(25.0, abs=1e-9) and strength[0] > 0


# --- the film index, on either side of the substrate's -------------------------------------------

def _object_spectra(n2, n3, thetas, with_p, seed=0):
    rng = np.random.default_rng(seed)
    rows = []
    for i, theta in enumerate(thetas):
        d = 350.0 + 300.0 * rng.random()
        Rs, Rp = _tmm_rs_rp(theta, d, n2, n3)
        rows.append(np.concatenate([Rs, Rp]) if with_p else Rs)
    S = np.array(rows)
    return S + 2e-4 * S.max() * rng.standard_normal(S.shape)


@pytest.mark.parametrize("n2, n3", [(1.38, 1.6), (2.3, 1.5), (1.55, 1.6), (1.7, 1.6)])
@pytest.mark.parametrize("with_p", [False, True])
def test_film_index_and_its_side_from_pixels_at_oblique_angles_only(n2, n3, with_p):
    """No near-normal pixel (a pyramid's faces): the side is read from the spectra's physics."""
    from thinfilm.reconstruction.spectral_fit import estimate_film_ior_either_side

    thetas = np.linspace(30.0, 50.0, 40)
    n2_est, info = estimate_film_ior_either_side(_object_spectra(n2, n3, thetas, with_p), WL, n3)
    assert info["film_ior_above_substrate"] == (n2 > n3)
    assert n2_est == pytest.approx(n2, abs=0.005)


def test_paper_spectral_check_reads_the_spectra_not_near_normal_pixels():
    from thinfilm.reconstruction.spectral_checks import check_peak_assumption

    thetas = np.linspace(30.0, 50.0, 40)
    check_peak_assumption(_object_spectra(1.38, 1.6, thetas, False), WL, 1.6)          # no dip below R0: fine
    with pytest.raises(UserError, match=r"above the substrate's \(1\.5\).*needs n2 < n3") as e:
        check_peak_assumption(_object_spectra(2.3, 1.5, thetas, False), WL, 1.5)
    assert "\n" not in str(e.value)


@pytest.mark.slow
def test_paper_spectral_method_reads_a_rough_films_smeared_fringes_as_what_they_are(tmp_path):
    """The quick benchmark's rough hemisphere (alpha 0.02, 64 px): the microfacets smear the
    fringes, and the minima's reading of the s spectra fits 1.2-1.8 times better than the
    maxima's, yet the film (1.37 on 1.6) is below its substrate: the paper's method runs.
    A film above its substrate, rough or not, is still refused."""
    pytest.importorskip("mitsuba")
    from thinfilm.cli import main
    from thinfilm.reconstruct import reconstruct

    rough = tmp_path / "rough"
    assert main(["generate", "hemisphere", "--out", str(rough), "--resolution", "64",
                 "--set", "film.roughness=0.02"]) == 0
    est, _ = reconstruct("spectral", rough, "kobayashi")
    assert est.valid.sum() > 0.5 * est.info["object_pixels"]
    high = tmp_path / "high"
    spec = Path(__file__).resolve().parents[1] / "scenes" / "standard" / "high_index.toml"
    assert main(["generate", str(spec), "--out", str(high), "--resolution", "48", "--set", "film.roughness=0.05"]) == 0
    with pytest.raises(UserError, match=r"above the substrate's \(1\.5\)"):
        reconstruct("spectral", high, "kobayashi")


def test_paper_rgb_method_refuses_a_film_above_its_substrate():
    from thinfilm.core.film import Film
    from thinfilm.reconstruction.rgb_paper import check_film_below_substrate

    check_film_below_substrate(Film.single(1.38, None, 1.6))
    with pytest.raises(UserError, match=r"film index 2\.3 >= substrate index 1\.5; the paper's method") as e:
        check_film_below_substrate(Film.single(2.3, None, 1.5))
    assert "\n" not in str(e.value)


# --- the azimuth's sign for the whole object ---------------------------------------------------------

def _signs_error(normals, mask, sigma_v=0.002, seed=0, max_pixels=12000):
    """Run the global disambiguation on the axis and zenith of an analytic normal field with
    noise in the measured (doubled-angle) polarization; the error of the result (degrees)."""
    from thinfilm.reconstruction.azimuth import resolve_azimuth_global

    rng = np.random.default_rng(seed)
    th = np.arccos(np.clip(normals[..., 2], -1, 1))
    phi = np.arctan2(normals[..., 1], normals[..., 0])
    u = np.sin(th) ** 2
    v = np.stack([u * np.cos(2 * phi), u * np.sin(2 * phi)], -1) + sigma_v * rng.standard_normal(mask.shape + (2,))
    un = np.clip(np.hypot(v[..., 0], v[..., 1]), 0, 1)
    thn = np.arcsin(np.sqrt(un))
    phin = np.mod(0.5 * np.arctan2(v[..., 1], v[..., 0]), np.pi)
    az = resolve_azimuth_global(np.degrees(phin), np.degrees(thn), mask, np.clip(un / (25 * sigma_v), 0, 1),
                                max_pixels=max_pixels)
    a = np.radians(az)
    n = np.stack([np.sin(thn) * np.cos(a), np.sin(thn) * np.sin(a), np.cos(thn)], -1)
    return _angle_deg(n[mask], normals[mask])


def _torus_field(res, tilt_deg, R=1.0, r=0.38):
    """Normals of a torus seen by an orthographic camera along -z (ray-marched analytically:
    the nearest hit of each pixel's ray)."""
    rot = _rotation([tilt_deg, 0.0, 0.0])
    half = (R + r) * 1.05
    xs = np.linspace(-half, half, res)
    X, Y = np.meshgrid(xs, -xs)
    normals = np.zeros((res, res, 3))
    mask = np.zeros((res, res), dtype=bool)
    zs = np.linspace(2.0, -2.0, 1601)
    for i in range(res):
        p = np.stack([np.broadcast_to(X[i][:, None], (res, zs.size)), np.broadcast_to(Y[i][:, None], (res, zs.size)),
                      np.broadcast_to(zs[None, :], (res, zs.size))], -1) @ rot       # into the torus frame
        f = (np.hypot(p[..., 0], p[..., 1]) - R) ** 2 + p[..., 2] ** 2 - r * r
        inside = f < 0
        hit = inside.any(axis=1)
        k = np.argmax(inside, axis=1)
        q = p[np.arange(res), k]
        rho = np.hypot(q[:, 0], q[:, 1])
        c = np.stack([R * q[:, 0] / rho, R * q[:, 1] / rho, np.zeros(res)], -1)
        n = (q - c) @ rot.T
        n /= np.linalg.norm(n, axis=1, keepdims=True)
        ok = hit & (n[:, 2] > 0.02)
        normals[i, ok] = n[ok]
        mask[i] = ok
    return normals, mask


@pytest.mark.parametrize("tilt", [0.0, 35.0, 55.0])
def test_global_azimuth_on_a_torus(tilt):
    """The hole's edge is an occluding contour too, and the ring's top a ridge the normals turn
    round on: both halves of the tube get their own, right sign (propagating inwards from the
    outer silhouette alone turns the inner half over)."""
    normals, mask = _torus_field(72, tilt)
    err = _signs_error(normals, mask)
    assert np.mean(err) < 1.0 and np.mean(err > 10.0) < 0.01


def test_global_azimuth_on_a_large_torus_solved_on_blocks():
    normals, mask = _torus_field(180, 30.0)
    assert mask.sum() > 12000                  # the half-resolution path
    err = _signs_error(normals, mask)
    assert np.mean(err) < 1.0 and np.mean(err > 10.0) < 0.01


def test_global_azimuth_on_a_cylinder_ridge_and_pyramid_creases():
    y, x = np.mgrid[40:-40:-1, -40:40].astype(float) + 0.5
    # a lying cylinder: normals (x/R, 0, sqrt(1 - (x/R)²)), a ridge along the axis
    Rc = 36.0
    mask = np.abs(x) < Rc
    nz = np.sqrt(np.clip(1 - (x / Rc) ** 2, 0, None))
    cyl = np.stack([x / Rc, np.zeros_like(x), nz], -1)
    err = _signs_error(cyl, mask & (nz > 0.05))
    assert np.mean(err) < 1.0
    # a pyramid: four flat faces at 40°, creases along the diagonals
    t = math.radians(40.0)
    face = np.where(np.abs(x) > np.abs(y), np.where(x > 0, 0, 2), np.where(y > 0, 1, 3))
    ang = face * np.pi / 2
    pyr = np.stack([math.sin(t) * np.cos(ang), math.sin(t) * np.sin(ang), np.full(x.shape, math.cos(t))], -1)
    err = _signs_error(pyr, (np.abs(x) < 38) & (np.abs(y) < 38))
    assert np.mean(err > 10.0) < 0.01


def test_global_azimuth_on_a_sheet_with_a_crest_in_the_middle():
    """No occluding contour: the convex choice (the middle bulges), right for this sheet."""
    y, x = np.mgrid[40:-40:-1, -40:40].astype(float) / 40.0
    k, A = 2 * np.pi, 0.06 * 40
    dz = -A * k * np.sin(k * x) / 40.0          # z = A cos(k x), pixel units
    n = np.stack([-dz, np.zeros_like(dz), np.ones_like(dz)], -1)
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    err = _signs_error(n, np.ones(x.shape, dtype=bool))
    assert np.mean(err) < 1.0


def _low_wave(slope, cross, res=80, periods=2.5, angle_deg=20.0):
    """Normals of a wavy sheet ``z = A cos(k u)`` (or ``A cos(k u) cos(k v)``, an egg crate)
    with the largest slope ``slope``, its waves turned ``angle_deg`` in the image."""
    y, x = np.mgrid[res // 2:-res // 2:-1, -res // 2:res // 2].astype(float)
    a = math.radians(angle_deg)
    u, v = x * math.cos(a) + y * math.sin(a), -x * math.sin(a) + y * math.cos(a)
    k = 2 * np.pi * periods / res
    amp = slope / k
    if cross:
        gu, gv = -amp * k * np.sin(k * u) * np.cos(k * v), -amp * k * np.cos(k * u) * np.sin(k * v)
    else:
        gu, gv = -amp * k * np.sin(k * u), np.zeros_like(u)
    gx, gy = gu * math.cos(a) - gv * math.sin(a), gu * math.sin(a) + gv * math.cos(a)
    n = np.stack([-gx, -gy, np.ones_like(gx)], -1)
    return n / np.linalg.norm(n, axis=-1, keepdims=True), np.ones(x.shape, dtype=bool)


@pytest.mark.parametrize("slope, cross, sigma_v", [(0.2, False, 0.004), (0.15, False, 0.002), (0.2, True, 0.005)])
def test_global_azimuth_on_low_waves(slope, cross, sigma_v):
    """Low waves (zenith 9-11°) with noisy axes: the ridges and valleys, where the axes are
    noise, are told from folds by the smoothness of the whole sheet; the priors (the middle
    bulges, the edges lie lower) only choose between the sheet and its mirror image, which
    the data cannot tell apart. With priors a tenth as strong as an occluding contour's, the
    regions oriented by single flips and by pairwise couplings through the free pixels, a
    fifth to two fifths of these waves were turned over."""
    normals, mask = _low_wave(slope, cross)
    err = _signs_error(normals, mask, sigma_v=sigma_v)
    err_mirror = _signs_error(normals * np.array([-1.0, -1.0, 1.0]), mask, sigma_v=sigma_v)
    if np.mean(err_mirror) < np.mean(err):
        err = err_mirror
    assert np.mean(err) < 2.0 and np.mean(err > 5.0) < 0.02


@pytest.mark.parametrize("bridge, turned_over", [(8, False), (0, True)])
def test_global_azimuth_bridges_a_long_waves_wide_ridge(bridge, turned_over, monkeypatch):
    """A low, long wave (1.5 periods over the image, slope 0.25) with noisy axes: about its
    ridges and valleys the band where polarization says nothing is wider than the 8 px of the
    second-order triples, so without the wider triples across such bands (``bridge``) a fifth
    of the sheet is turned over at a valley; with them, under a tenth."""
    import functools

    import thinfilm.reconstruction.azimuth as azimuth

    monkeypatch.setattr(azimuth, "coupling_matrix", functools.partial(azimuth.coupling_matrix, bridge=bridge))
    normals, mask = _low_wave(0.25, False, periods=1.5)
    err = min((_signs_error(truth, mask, sigma_v=0.008) for truth in (normals, normals * np.array([-1.0, -1.0, 1.0]))),
              key=np.mean)
    assert (np.mean(err > 5.0) > 0.15) == turned_over
    if not turned_over:
        assert np.mean(err) < 3.0 and np.mean(err > 5.0) < 0.1


@pytest.mark.parametrize("rows", [1, 2])
def test_global_azimuth_on_an_image_one_or_two_pixels_high(rows):
    """A strip across a lying cylinder, one or two pixels high (image gradients need three):
    the normals point out at both ends, left of the ridge and right of it."""
    from thinfilm.reconstruction.azimuth import resolve_azimuth_global

    x = np.arange(-4, 5, dtype=float)
    zen = np.tile(np.degrees(np.arcsin(np.abs(x) / 4.2)), (rows, 1))
    az = resolve_azimuth_global(np.zeros_like(zen), zen, np.ones(zen.shape, dtype=bool))
    assert az.shape == zen.shape
    np.testing.assert_array_equal(az[:, x < 0], 180.0)
    np.testing.assert_array_equal(az[:, x > 0], 0.0)


def test_global_azimuth_says_where_only_the_convex_prior_decides():
    """A sheet (no occluding contour) and a torus facing the camera beside it: the sheet's
    pixels are the fraction whose sign the convex prior alone chose; a torus alone has none."""
    from thinfilm.reconstruction.azimuth import resolve_azimuth_global

    def run(normals, mask):
        th = np.degrees(np.arccos(np.clip(normals[..., 2], -1, 1)))
        phi = np.mod(np.degrees(np.arctan2(normals[..., 1], normals[..., 0])), 180.0)
        return resolve_azimuth_global(np.where(mask, phi, np.nan), np.where(mask, th, np.nan), mask,
                                      return_info=True)[1]["sign_by_prior"]

    torus, tmask = _torus_field(48, 0.0)
    assert run(torus, tmask) == 0.0
    y, x = np.mgrid[24:-24:-1, -24:24].astype(float) / 24.0
    dz = -0.06 * 2 * np.pi * np.sin(2 * np.pi * x)          # z = 0.06 cos(2 pi x), slope per unit
    sheet = np.stack([-dz, np.zeros_like(dz), np.ones_like(dz)], -1)
    sheet /= np.linalg.norm(sheet, axis=-1, keepdims=True)
    both = np.concatenate([sheet, np.zeros((48, 4, 3)), torus], axis=1)
    bmask = np.concatenate([np.ones((48, 48), bool), np.zeros((48, 4), bool), tmask], axis=1)
    assert run(both, bmask) == pytest.approx(48 * 48 / bmask.sum())


# --- thickness basins chosen together -------------------------------------------------------------------

def test_choose_smooth_outvotes_noise_between_near_equal_basins():
    from thinfilm.reconstruction.candidates import choose_smooth

    rng = np.random.default_rng(1)
    mask = np.ones((30, 30), dtype=bool)
    n = mask.sum()
    truth = 500.0 + 2.0 * np.arange(n) / 30          # a gentle ramp
    values = np.stack([truth, truth + 180.0, truth - 170.0], axis=1)
    # the right basin fits a little better on average, the noise flips a third of the pixels
    costs = np.stack([np.zeros(n), np.full(n, 1.0), np.full(n, 1.5)], axis=1) + 1.5 * rng.standard_normal((n, 3))
    alone = np.argmin(costs, axis=1)
    assert np.mean(alone != 0) > 0.25
    chosen = choose_smooth(values, costs, mask, sigma=10.0)
    assert np.mean(chosen != 0) < 0.01


# --- masks and integration ---------------------------------------------------------------------------------

def test_mask_keeps_dark_film_rings_and_leaves_background_holes_out():
    from thinfilm.reconstruction.masks import mask_from_intensity

    rng = np.random.default_rng(0)
    y, x = np.mgrid[-40:40, -40:40] + 0.5
    r = np.hypot(x, y)
    img = 1e-4 * (1 + 0.3 * rng.random(r.shape))                 # background
    obj = (r < 32) & (r > 10)                                     # a ring: its hole shows background
    img[obj] = 0.05
    dark = obj & (np.abs(r - 20) < 1.0)                           # a film near its AR minimum
    img[dark] = 1e-3
    m = mask_from_intensity(img)
    assert m[dark].all() and m[obj].all()
    assert not m[r < 9].any() and not m[r > 33].any()


def test_integration_at_half_resolution_matches_the_full_solution():
    from thinfilm.reconstruction.surface import height_to_normals, integrate_normals

    y, x = np.mgrid[90:-90:-1, -90:90].astype(float)
    mask = x ** 2 + y ** 2 < 85 ** 2
    z = np.sqrt(np.clip(95.0 ** 2 - x ** 2 - y ** 2, 1, None))
    n = np.stack([x / z, y / z, np.ones_like(x)], -1)
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    w = np.where(mask, n[..., 2] ** 2, 0.0)
    full = integrate_normals(n, mask, w, smoothness=2.0, max_direct=None)
    half = integrate_normals(n, mask, w, smoothness=2.0, max_direct=10000)
    inner = mask & (x ** 2 + y ** 2 < 75 ** 2)
    e_full = _angle_deg(height_to_normals(full, mask)[inner], n[inner])
    e_half = _angle_deg(height_to_normals(half, mask)[inner], n[inner])
    assert np.mean(e_half) < np.mean(e_full) + 0.2 and np.percentile(e_half, 99) < 1.0


# --- end to end on noiseless Stokes cubes (optics core, no rendering) ----------------------------------

def _stokes_hemisphere(res, n2, n3, d_nm):
    from thinfilm.bsdf.optics import reflectances

    yy, xx = np.mgrid[0:res, 0:res]
    r = 0.46 * res
    x, y = (xx - (res - 1) / 2) / r, ((res - 1) / 2 - yy) / r
    mask = x * x + y * y < 1
    nz = np.sqrt(np.clip(1 - x * x - y * y, 0, None))
    normals = np.stack([x, y, nz], -1)
    normals /= np.linalg.norm(normals, axis=-1, keepdims=True)
    Rs, Rp = reflectances(np.clip(normals[..., 2], 0, 1)[..., None], WL, d_nm, n2, n3)
    phi = np.arctan2(normals[..., 1], normals[..., 0])[..., None]
    P = 0.5 * (Rs - Rp)
    stokes = {"S0": 0.5 * (Rs + Rp), "S1": -P * np.cos(2 * phi), "S2": -P * np.sin(2 * phi)}
    stokes = {k: np.where(mask[..., None], v, 0.0) for k, v in stokes.items()}
    return stokes, mask, normals


@pytest.mark.parametrize("n2, n3", [(1.37, 1.6), (2.1, 1.6)])
def test_default_spectral_method_on_noiseless_stokes_hemispheres(n2, n3):
    from thinfilm.core.conventions import s_polarized
    from thinfilm.reconstruction.spectral import reconstruct_spectral
    from thinfilm.reconstruction.spectral_stokes import reconstruct_stokes

    stokes, mask, normals = _stokes_hemisphere(64, n2, n3, 430.0)
    est = reconstruct_spectral(None, WL, n3, stokes=stokes, method=reconstruct_stokes)
    v = est.valid & mask
    assert v.sum() > 0.97 * mask.sum()
    err = _angle_deg(est.normals[v], normals[v])
    assert np.mean(err) < 0.3 and np.percentile(err, 95) < 1.0
    assert est.film_ior == pytest.approx(n2, abs=1e-3)
    assert np.median(np.abs(est.thickness_nm[v] - 430.0)) < 0.2
    assert est.info["film_ior_above_substrate"] == (n2 > n3)


@pytest.mark.slow
def test_a_sheet_and_its_mirror_image_give_the_same_captures(render_variant):
    """Why a sheet's global sign is a prior's choice: shifting its waves by half a period is
    the mirror image z -> -z, whose normals differ by twice their zenith, yet the dome and the
    camera see the same Stokes cube (no occluding contour, no inter-reflection at these
    slopes)."""
    from thinfilm.generators.generate import simulate
    from thinfilm.generators.spec import load_spec

    sims = []
    for phase in (30.0, 210.0):
        spec = load_spec({"shape": {"kind": "sheet", "amplitude": 0.09, "wavelength": 1.0, "phase_deg": phase,
                                    "direction_deg": 20.0},
                          "film": {"ior": 1.38, "thickness": {"profile": "uniform", "value": 450.0}},
                          "rig": {"resolution": 32, "wavelengths_nm": {"start": 400.0, "stop": 720.0, "step": 32.0}},
                          "noise": {"model": "none"}})
        sims.append(simulate(spec))
    a, b = sims
    m = a["ground_truth"]["mask"] & b["ground_truth"]["mask"]
    assert m.mean() > 0.5
    for k in ("S0", "S1", "S2"):
        np.testing.assert_allclose(a["stokes_exact"][k][m], b["stokes_exact"][k][m], atol=1e-7)
    assert np.median(_angle_deg(a["ground_truth"]["normal"][m], b["ground_truth"]["normal"][m])) > 20.0


@pytest.mark.slow
def test_rgb_default_on_a_torus_facing_the_camera(render_variant, tmp_path):
    """A torus tilted 6° (a held-out random scene): the tube's top is a ring where the
    polarization says nothing, and the hole's rim, steep and dark, barely fits. The inner
    half of the tube gets its sign from the hole's rim and across that ring. With the free
    pixels between regions approximated pairwise it was turned over (18° mean, 73° p95);
    each group of them is now completed for every sign choice of the regions it touches."""
    from thinfilm.core.io import read_dataset
    from thinfilm.evaluation import geometry_error_maps
    from thinfilm.generators.generate import generate_dataset
    from thinfilm.generators.spec import load_spec
    from thinfilm.reconstruct import reconstruct

    spec = load_spec({"seed": 761595008,
                      "shape": {"kind": "torus", "major_radius": 1.0, "minor_radius": 0.4767,
                                "rotate_deg": [6.33, 0.0, 67.0]},
                      "film": {"ior": 1.337, "thickness": {"profile": "uniform", "value": 347.0}},
                      "substrate": {"ior": 1.651},
                      "rig": {"camera": "Nikon 5100 (NPL)", "illuminant": "A"}, "noise": {"bits": 10}},
                     resolution=96)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        generate_dataset(spec, tmp_path / "ds", progress=False)
        est, _ = reconstruct("rgb", tmp_path / "ds", None)
    gt = read_dataset(tmp_path / "ds", need=("ground_truth",), optional=()).ground_truth
    maps = geometry_error_maps(gt, est)
    sel = gt["mask"] & est.valid
    assert sel.sum() > 0.9 * gt["mask"].sum()
    err = maps["normal_error_deg"][sel]
    # the random-scene sweep's bars (benchmarks/sweep_random_scenes.py)
    assert np.mean(err) < 4.0 and np.percentile(err, 95) < 10.0
    assert np.mean(maps["thickness_error_nm"][sel]) < 15.0


@pytest.mark.parametrize("shape, size", [((40, 33), 7), ((9, 8), 3), ((12, 15), 5)])
def test_masked_median_equals_numpy_nanmedian(shape, size):
    """The masked median filter equals NumPy's ``nanmedian`` over each window with the pixels
    outside the mask set to NaN, at every mask pixel; other pixels keep their value."""
    from thinfilm.reconstruction.masks import masked_median

    rng = np.random.default_rng(size)
    v = rng.normal(size=shape)
    m = rng.random(shape) < 0.6
    pad = size // 2
    padded = np.pad(np.where(m, v, np.nan), pad, constant_values=np.nan)
    win = np.lib.stride_tricks.sliding_window_view(padded, (size, size)).reshape(*shape, -1)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        ref = np.nanmedian(win, axis=-1)
    out = masked_median(v, m, size)
    np.testing.assert_array_equal(out[m], ref[m])
    np.testing.assert_array_equal(out[~m], v[~m])
