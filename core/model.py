"""The observation model: the captures a rig records of a thin-film surface.

One model of a pixel for the whole project. Given the rig of a dataset (its projection and
view rays, the lighting, the polarizer angles, the bands and their passbands, the camera and
the illuminant), a film or a stack (:class:`thinfilm.core.film.Film`), and per pixel a
normal and the layer thicknesses, it gives the expected, noise-free captures of a single
specular reflection, in reflectance units, as the dataset files hold them:

``stokes``
    The band-integrated linear Stokes cube ``S0, S1, S2`` (H, W, B), in the camera's Stokes
    frame (:mod:`thinfilm.core.conventions`: ``S1 = I(0°) − I(90°)``, 0° along image +x).
``spectral_s``
    ``S0 + sqrt(S1² + S2²)`` per band, what a hyperspectral camera behind a rotating polarizer
    reports as the s-polarized reflectance (:func:`thinfilm.core.conventions.s_polarized`).
``polarized_rgb``
    Per polarizer angle the white-balanced camera RGB of the intensity behind it
    (:func:`polarized_rgb_from_stokes`: the camera weights of
    :func:`thinfilm.core.colorimetry.camera_weights` and Malus' law).

The physics is :func:`thinfilm.bsdf.optics.stack_amplitudes` (the project's one copy of it),
evaluated in Dr.Jit kernels; the bands are integrated with the generator's own quadrature
(:func:`thinfilm.core.bands.passband_quadrature`), so a prediction from the ground truth of a
noise-free dataset of a convex object reproduces its captures.

A pixel
-------
The light reaching the camera along a pixel's view ray ``v`` (unit vector from the surface
towards the camera) comes by specular reflection about the normal ``n`` from the direction
``w = 2 (n·v) n − v``, at incidence ``cos θ_i = n·v``. Under unpolarized light of radiance
``L(w)`` the reflected Stokes vector in the s/p frame is ``L (a, b, 0)`` with
``a = (R_s + R_p)/2`` and ``b = (R_s − R_p)/2``; rotated into the camera's frame, whose
reference axis ``e1`` is the camera's x axis made perpendicular to ``v``, it is
``L (a, b cos 2ψ, b sin 2ψ)`` with ``ψ`` the angle of the s-direction ``n × v`` from ``e1``
towards ``e2 = v × e1``. For the orthographic camera ``v = +z`` and ``ψ = φ − 90°``, so
``(S1, S2) = −b (cos 2φ, sin 2φ)`` (:func:`thinfilm.core.conventions.specular_stokes`).

Estimators describe a pixel by a :class:`PixelState` in the pixel's own incidence frame:
``cos θ_i``, ``(cos 2ψ, sin 2ψ)``, the light ``L`` and the layers' thicknesses and index
offsets. :func:`state_from_normals` makes one from normals; :data:`PARAMETRIZATIONS` hold the
per-pixel unknowns of the fits (for example ``(v1, v2, d)`` with
``(v1, v2) = sin² θ_i (cos 2φ_i, sin 2φ_i)``, smooth through normal incidence, where the
azimuth is undefined).

Lighting: the uniform, unpolarized dome of radiance 1, with its hole of angular radius
``dome_hole_deg`` around the camera direction (+z) where no light comes from. What the model
leaves out: light reflected more than once (concave objects), the microfacet lobe of a rough
film (it models the macro surface's specular reflection), and anything behind the film.

Derivatives
-----------
Every quantity is traced by Dr.Jit, so it is differentiable by automatic differentiation in
the normals, every layer's thickness and every layer's index (an offset added to its
dispersion). :meth:`ObservationModel.normal_equations` gives the Gauss-Newton normal
equations of a fit of per-pixel unknowns to captures, all pixels in one kernel: a lane per
pixel that loops over the bands (and the sub-wavelengths of each band), with the Jacobian
taken by forward-mode AD inside the loop. Backends: ``"llvm"`` (CPU) or ``"cuda"`` (GPU),
chosen by one argument; ``precision`` ``"double"`` or ``"single"`` (faster, and what GPUs
prefer; ample for fits: thickness resolution 1e-3 nm at 5 µm).

Examples
--------
>>> import numpy as np
>>> from thinfilm.core.film import Film
>>> rig = Rig(wavelengths_nm=(450.0, 550.0, 650.0))
>>> model = ObservationModel(rig, Film.single(1.37, 400.0, substrate_ior=1.6))
>>> n = np.array([[np.sin(0.5), 0.0, np.cos(0.5)]])            # zenith 0.5 rad, azimuth 0
>>> s = model.stokes(n, np.array([400.0]))
>>> from thinfilm.bsdf import optics
>>> Rs, Rp = optics.reflectances(np.cos(0.5), np.array(rig.wavelengths_nm), 400.0, 1.37, 1.6)
>>> bool(np.allclose(s["S0"][0], (Rs + Rp) / 2) and np.allclose(s["S1"][0], -(Rs - Rp) / 2))
True
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field

import numpy as np

from thinfilm.bsdf import optics

from .bands import band_windows, passband_quadrature
from .colorimetry import DEFAULT_CAMERA, DEFAULT_ILLUMINANT, camera_weights
from .conventions import malus_intensity, s_polarized
from .errors import UserError

__all__ = [
    "BACKENDS",
    "PRECISIONS",
    "QUADRATURES",
    "Rig",
    "PixelState",
    "ObservationModel",
    "Observations",
    "Spectrometer",
    "Parametrization",
    "PARAMETRIZATIONS",
    "state_from_normals",
    "view_frames",
    "polarized_rgb_from_stokes",
    "captures_from_stokes",
    "predict",
]

#: Dr.Jit backends the model runs on
BACKENDS = ("llvm", "cuda")
#: floating-point precisions of the kernels
PRECISIONS = ("double", "single")
#: how bands are integrated: the rig's passbands (the generator's), or point samples at the
#: band centres (cheaper; for searches whose fringes the passband does not damp)
QUADRATURES = ("passband", "centre")

_U_EPS = 1e-9


# ---------------------------------------------------------------------------------------------
# The rig
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Rig:
    """What a dataset's cameras and lights are (``meta.json``).

    Attributes
    ----------
    wavelengths_nm : tuple of float
        Band centres, increasing.
    band_fwhm_nm : float
        Passband width (0: point samples at the centres).
    passband : {"gaussian", "box"}
    polarizer_angles_deg : tuple of int
        The polarization camera's angles.
    camera, illuminant : str
        Colour-science names or CSV paths (:mod:`thinfilm.core.colorimetry`).
    dome_hole_deg : float
        Angular radius of the hole in the lighting dome around +z.
    projection : str
        ``"orthographic"`` (view rays along +z, the image plane's x axis as the Stokes
        reference).
    """

    wavelengths_nm: tuple
    band_fwhm_nm: float = 0.0
    passband: str = "gaussian"
    polarizer_angles_deg: tuple = (0, 45, 90, 135)
    camera: str = DEFAULT_CAMERA
    illuminant: str = DEFAULT_ILLUMINANT
    dome_hole_deg: float = 0.0
    projection: str = "orthographic"

    def __post_init__(self):
        wl = tuple(float(v) for v in np.asarray(self.wavelengths_nm, dtype=np.float64).ravel())
        object.__setattr__(self, "wavelengths_nm", wl)
        object.__setattr__(self, "polarizer_angles_deg", tuple(int(a) for a in self.polarizer_angles_deg))
        if not wl or any(not (math.isfinite(v) and v > 0) for v in wl) or any(b <= a for a, b in zip(wl, wl[1:])):
            raise ValueError(f"wavelengths_nm must be increasing wavelengths > 0, got {list(wl)[:8]}")
        if not (math.isfinite(self.band_fwhm_nm) and self.band_fwhm_nm >= 0):
            raise ValueError(f"band_fwhm_nm must be >= 0, got {self.band_fwhm_nm}")
        if not (math.isfinite(self.dome_hole_deg) and 0 <= self.dome_hole_deg < 90):
            raise ValueError(f"dome_hole_deg must be in [0, 90), got {self.dome_hole_deg}")
        if self.projection != "orthographic":
            raise ValueError(f"projection {self.projection!r} is not modelled (orthographic only)")

    @classmethod
    def from_meta(cls, meta: dict, where: str = "meta.json", polarizer_angles_deg=None) -> "Rig":
        """The rig of a ``meta.json``. Missing entries (an imported capture's) take the
        defaults: point-sampled bands, the default camera and illuminant, no dome hole.

        Raises
        ------
        UserError
            When the wavelengths are missing or the projection is not one the model knows.
        """
        wl = meta.get("wavelengths_nm") or []
        if len(wl) < 1:
            raise UserError(f"{where}: no 'wavelengths_nm'; the observation model needs the bands")
        projection = meta.get("projection", {"type": "orthographic"})
        kind = projection.get("type", "orthographic") if isinstance(projection, dict) else str(projection)
        if kind != "orthographic":
            raise UserError(f"{where}: projection '{kind}' is not modelled; expected 'orthographic'")
        angles = polarizer_angles_deg if polarizer_angles_deg is not None else meta.get(
            "polarizer_angles_deg", (0, 45, 90, 135))
        try:
            return cls(wavelengths_nm=tuple(wl), band_fwhm_nm=float(meta.get("band_fwhm_nm", 0.0) or 0.0),
                       passband=str(meta.get("passband", "gaussian")),
                       polarizer_angles_deg=tuple(angles),
                       camera=str(meta.get("camera", DEFAULT_CAMERA)),
                       illuminant=str(meta.get("illuminant", DEFAULT_ILLUMINANT)),
                       dome_hole_deg=float(meta.get("dome_hole_deg", 0.0) or 0.0))
        except (TypeError, ValueError) as e:
            raise UserError(f"{where}: {e}") from None

    @classmethod
    def of_dataset(cls, dataset) -> "Rig":
        """The rig of a :class:`thinfilm.core.io.Dataset` (its polarizer angles from the layers
        read, when there are any)."""
        angles = dataset.polarizer_angles_deg or None
        return cls.from_meta(dataset.meta, str(dataset.path / "meta.json"), angles)

    def quadrature(self, mode: str = "passband"):
        """``(sub_nm (K,), weights (B, K))`` of the bands (:func:`passband_quadrature`);
        ``mode = "centre"`` point-samples the band centres."""
        if mode not in QUADRATURES:
            raise ValueError(f"quadrature must be one of {QUADRATURES}, got {mode!r}")
        return _quadrature(self.wavelengths_nm, self.band_fwhm_nm if mode == "passband" else 0.0, self.passband)

    def camera_weights(self) -> np.ndarray:
        """(B, 3) white-balanced camera weights of the bands
        (:func:`thinfilm.core.colorimetry.camera_weights`)."""
        return camera_weights(np.asarray(self.wavelengths_nm), self.camera, self.illuminant)


@functools.lru_cache(maxsize=32)
def _quadrature(wavelengths_nm: tuple, band_fwhm_nm: float, passband: str):
    sub, w = passband_quadrature(np.asarray(wavelengths_nm), band_fwhm_nm, passband)
    sub.setflags(write=False)
    w.setflags(write=False)
    return sub, w


def view_frames(rig: Rig, shape):
    """Per pixel the unit view vector towards the camera and the Stokes reference axis:
    two (H, W, 3) arrays (orthographic: +z and image +x everywhere)."""
    h, w = shape
    v = np.zeros((h, w, 3))
    v[..., 2] = 1.0
    e1 = np.zeros((h, w, 3))
    e1[..., 0] = 1.0
    return v, e1


# ---------------------------------------------------------------------------------------------
# A pixel
# ---------------------------------------------------------------------------------------------


@dataclass
class PixelState:
    """One pixel's reflection in its own incidence frame (arrays of any backend, per pixel).

    Attributes
    ----------
    cos_i : cosine of the incidence angle (``n·v``), in [0, 1].
    c2, s2 : ``cos 2ψ``, ``sin 2ψ`` of the s-direction's angle ``ψ`` in the camera's Stokes
        frame.
    light : radiance of the light the pixel reflects (1 under the dome, 0 in its hole).
    thickness_nm : list, one entry per layer (from the exterior down).
    index_offset : list, one entry per layer added to its index ``n(λ)`` (0: as given).
    """

    cos_i: object
    c2: object
    s2: object
    light: object
    thickness_nm: list
    index_offset: list = field(default_factory=list)


def state_from_normals(normals, views, e1, thickness_nm, dome_hole_deg: float = 0.0, index_offset=None,
                       ops=np) -> PixelState:
    """A :class:`PixelState` from normals, view vectors and Stokes reference axes (each a
    3-tuple of arrays, or an (N, 3) NumPy array), and the thicknesses (a list per layer).

    Pixels that face away from the view (``n·v <= 0``) or hold non-finite normals get no light.
    """
    def comp(a, i):
        return a[..., i] if isinstance(a, np.ndarray) else a[i]

    nx, ny, nz = (comp(normals, i) for i in range(3))
    vx, vy, vz = (comp(views, i) for i in range(3))
    ex, ey, ez = (comp(e1, i) for i in range(3))
    cos_i = nx * vx + ny * vy + nz * vz
    # s-direction n x v, and the camera frame e1 (perpendicular to v), e2 = v x e1
    sx, sy, sz = ny * vz - nz * vy, nz * vx - nx * vz, nx * vy - ny * vx
    ev = ex * vx + ey * vy + ez * vz
    ex, ey, ez = ex - ev * vx, ey - ev * vy, ez - ev * vz
    e2x, e2y, e2z = vy * ez - vz * ey, vz * ex - vx * ez, vx * ey - vy * ex
    cs = sx * ex + sy * ey + sz * ez
    sn = sx * e2x + sy * e2y + sz * e2z
    norm2 = cs * cs + sn * sn
    tiny = norm2 <= 1e-30
    safe = ops.where(tiny, 1.0, norm2) if ops is np else ops.select(tiny, 1.0, norm2)
    c2 = (cs * cs - sn * sn) / safe
    s2 = 2.0 * cs * sn / safe
    # the light comes from the mirror direction w = 2 (n.v) n - v; none from the dome's hole
    wz = 2.0 * cos_i * nz - vz
    lit = (cos_i > 0) & (wz <= math.cos(math.radians(dome_hole_deg)) if dome_hole_deg > 0 else cos_i > 0)
    if ops is np:
        finite = np.isfinite(cos_i)
        light = np.where(lit & finite, 1.0, 0.0)
        cos_i = np.where(finite, np.clip(cos_i, 0.0, 1.0), 1.0)
        c2 = np.where(tiny | ~finite, 1.0, c2)
        s2 = np.where(tiny | ~finite, 0.0, s2)
    else:
        light = ops.select(lit, 1.0, 0.0)
        cos_i = ops.clip(cos_i, 0.0, 1.0)
        c2 = ops.select(tiny, 1.0, c2)
        s2 = ops.select(tiny, 0.0, s2)
    return PixelState(cos_i, c2, s2, light, list(thickness_nm), list(index_offset or []))


@dataclass(frozen=True)
class Parametrization:
    """Per-pixel unknowns of a fit and how they make a :class:`PixelState`.

    Attributes
    ----------
    name : registry name (:data:`PARAMETRIZATIONS`).
    names : the unknowns, in the order of the columns of ``x``.
    unpack : ``unpack(x, fixed, layers, dr) -> PixelState`` with ``x`` a list of Dr.Jit
        arrays (one per unknown) and ``fixed`` a dict of Dr.Jit arrays (per-pixel constants:
        ``c2``, ``s2``, ``light``, ``thickness_nm.<i>`` for layers that are not unknowns).
    """

    name: str
    names: tuple
    unpack: object = field(repr=False, compare=False)


def _thicknesses(x, fixed, layers, first):
    """The layers' thicknesses: ``fixed["thickness_nm.<i>"]`` where given, else the next
    column of ``x`` from ``first``; returns them and the next column."""
    out = []
    j = first
    for i in range(layers):
        key = f"thickness_nm.{i}"
        if key in fixed:
            out.append(fixed[key])
        else:
            out.append(x[j])
            j += 1
    return out, j


def _offsets(x, fixed, layers, first):
    """The layers' index offsets: the remaining columns of ``x`` (one per layer, in order),
    else ``fixed["index_offset.<i>"]``, else 0."""
    out = []
    j = first
    for i in range(layers):
        if j < len(x):
            out.append(x[j])
            j += 1
        else:
            out.append(fixed.get(f"index_offset.{i}", 0.0))
    return out


def _double_angle(x, fixed, layers, dr):
    v1, v2 = x[0], x[1]
    u = dr.sqrt(v1 * v1 + v2 * v2)
    uc = dr.minimum(dr.maximum(u, _U_EPS), 1.0)
    thickness, j = _thicknesses(x, fixed, layers, 2)
    # (cos 2ψ, sin 2ψ) = -(v1, v2) / u: S1 = -(b / u) v1 stays smooth through normal incidence
    inv = 1.0 / uc
    return PixelState(dr.sqrt(1.0 - uc), -v1 * inv, -v2 * inv, fixed.get("light", 1.0), thickness,
                      _offsets(x, fixed, layers, j))


def _zenith(x, fixed, layers, dr):
    theta = x[0]
    thickness, j = _thicknesses(x, fixed, layers, 1)
    return PixelState(dr.cos(theta), fixed.get("c2", 1.0), fixed.get("s2", 0.0), fixed.get("light", 1.0),
                      thickness, _offsets(x, fixed, layers, j))


#: built-in parametrizations: ``"double_angle"``: ``(v1, v2, thickness_nm.*)`` with
#: ``(v1, v2) = sin² θ_i (cos 2φ_i, sin 2φ_i)`` (``φ_i`` the azimuth of the plane of incidence
#: about the view ray, from the Stokes reference axis; ``ψ = φ_i - 90°``); ``"zenith"``:
#: ``(θ_i, thickness_nm.*)`` with the plane of incidence fixed (``c2``, ``s2`` in ``fixed``).
#: Either may end with ``index_offset.*`` unknowns (one per layer, in order); ``fixed`` may give
#: ``thickness_nm.<i>`` (that layer is then no unknown) and ``index_offset.<i>``.
PARAMETRIZATIONS = {
    "double_angle": Parametrization("double_angle", ("v1", "v2", "thickness_nm"), _double_angle),
    "zenith": Parametrization("zenith", ("zenith_rad", "thickness_nm"), _zenith),
}


# ---------------------------------------------------------------------------------------------
# Captures from a Stokes cube
# ---------------------------------------------------------------------------------------------


def polarized_rgb_from_stokes(stokes: dict, wavelengths_nm, polarizer_angles_deg, camera: str,
                              illuminant: str) -> dict:
    """Noise-free polarization-camera images of a band Stokes cube: angle (int degrees) →
    (..., 3) linear, white-balanced camera RGB of I(α) = ½ (S0 + S1 cos 2α + S2 sin 2α)
    (:func:`thinfilm.core.colorimetry.camera_weights`, Malus' law)."""
    w = camera_weights(np.asarray(wavelengths_nm, dtype=np.float64), camera, illuminant)
    rgb_stokes = [np.asarray(stokes[k]) @ w for k in ("S0", "S1", "S2")]  # linear: RGB of each
    angles = list(polarizer_angles_deg)
    images = malus_intensity(*rgb_stokes, angles)
    return {int(round(a)) % 360: img for a, img in zip(angles, images)}


def captures_from_stokes(stokes: dict, wavelengths_nm, polarizer_angles_deg, camera: str, illuminant: str):
    """Noise-free captures of both cameras from a band Stokes cube (``S0``, ``S1``, ``S2``:
    (..., B) in reflectance units): ``(polarized_rgb, spectral_s)``."""
    polarized = polarized_rgb_from_stokes(stokes, wavelengths_nm, polarizer_angles_deg, camera, illuminant)
    return polarized, s_polarized(stokes["S0"], stokes["S1"], stokes["S2"])


# ---------------------------------------------------------------------------------------------
# The model
# ---------------------------------------------------------------------------------------------


class _Types:
    """The Dr.Jit array types of one backend and precision."""

    def __init__(self, backend: str, precision: str):
        import importlib

        import drjit as dr

        if backend not in BACKENDS:
            raise ValueError(f"backend must be one of {BACKENDS}, got {backend!r}")
        if precision not in PRECISIONS:
            raise ValueError(f"precision must be one of {PRECISIONS}, got {precision!r}")
        jit = dr.JitBackend.CUDA if backend == "cuda" else dr.JitBackend.LLVM
        if not dr.has_backend(jit):
            raise UserError(f"the Dr.Jit {backend.upper()} backend is not available on this machine"
                            + (" (no CUDA GPU)" if backend == "cuda" else " (is libLLVM installed?)"))
        mod = importlib.import_module(f"drjit.{backend}.ad")
        self.dr = dr
        self.Float = mod.Float64 if precision == "double" else mod.Float32
        self.UInt32 = mod.UInt32
        self.np_float = np.float64 if precision == "double" else np.float32

    def upload(self, a):
        return self.Float(np.ascontiguousarray(np.asarray(a, dtype=np.float64).ravel(), dtype=self.np_float))


class ObservationModel:
    """The expected captures of a rig looking at a film (see the module docstring).

    Parameters
    ----------
    rig : :class:`Rig`
    film : :class:`thinfilm.core.film.Film`
        A single film or a stack (indices known; the thicknesses come per pixel).
    backend : {"llvm", "cuda"}
    precision : {"double", "single"}
    quadrature : {"passband", "centre"}
        Band integration (see :data:`QUADRATURES`).
    lossless : bool, optional
        Whether every medium is lossless with an index at least the exterior's, so that the
        kernels may keep the normal components real (half the arithmetic); default: decided
        from the film. Pass False when index offsets may take an index below the exterior's.
    """

    def __init__(self, rig: Rig, film, backend: str = "llvm", precision: str = "double",
                 quadrature: str = "passband", lossless: bool | None = None):
        self.rig = rig
        self.film = film
        self.backend = backend
        self.precision = precision
        self.quadrature = quadrature
        self.bands = len(rig.wavelengths_nm)
        if quadrature == "centre" or rig.band_fwhm_nm == 0:
            # point samples: band b is sub-wavelength b (no (B, B) identity of weights, which a
            # spectrometer's thousands of samples would make gigabytes)
            if quadrature not in QUADRATURES:
                raise ValueError(f"quadrature must be one of {QUADRATURES}, got {quadrature!r}")
            self.sub_nm, self.weights = np.asarray(rig.wavelengths_nm, dtype=np.float64), None
            self.windows = np.stack([np.arange(self.bands), np.arange(self.bands) + 1], axis=1)
        else:
            self.sub_nm, self.weights = rig.quadrature(quadrature)
            self.windows = band_windows(self.weights)
        self.layers = len(film.layers)
        if any(layer.material is None for layer in film.layers):
            raise ValueError("the observation model needs every layer's index")
        lam = self.sub_nm
        self._n = [layer.n_k(lam) for layer in film.layers]
        self._sub = film.substrate_n_k(lam)
        self._ext = float(film.ext_ior)
        # lossless media of indices at least the exterior's: real normal components (half the
        # kernel's arithmetic); index offsets must then keep every index there
        auto = bool(all(not np.any(k) and np.min(n) >= self._ext for n, k in [*self._n, self._sub]))
        self.lossless = auto if lossless is None else bool(lossless) and auto
        self._t = None

    # -- Dr.Jit --------------------------------------------------------------------------------

    @property
    def types(self) -> _Types:
        if self._t is None:
            t = _Types(self.backend, self.precision)
            t.lam = t.upload(self.sub_nm)
            # a table per layer, or one opaque value where the index does not vary over the
            # sub-wavelengths: the kernel then computes its interfaces once per lane, not per band
            def table(v):
                v = np.asarray(v, dtype=np.float64)
                if not np.any(v):
                    return None
                if np.all(v == v[0]):
                    return t.dr.opaque(t.Float, float(v[0]))
                return t.upload(v)

            t.n = [(table(n), table(k)) for n, k in self._n]
            t.sub = tuple(table(v) for v in self._sub)
            # each band's weights, padded to the longest window: gathered by band * width + j
            width = int(np.max(np.diff(self.windows, axis=1)))
            idx = self.windows[:, :1] + np.arange(width)[None, :]
            valid = idx < self.windows[:, 1:2]
            if self.weights is None:
                flat = np.ones(self.bands)
            else:
                flat = np.where(valid, self.weights[np.arange(self.bands)[:, None],
                                                    np.minimum(idx, self.sub_nm.size - 1)], 0.0)
            t.win_w = t.upload(flat)
            t.win_width = width
            t.win_first = t.UInt32(self.windows[:, 0].astype(np.uint32))
            t.win_count = t.UInt32(np.diff(self.windows, axis=1)[:, 0].astype(np.uint32))
            self._t = t
        return self._t

    def sub_stokes(self, state: PixelState, k):
        """``(S0, S1, S2)`` of the pixels of ``state`` (Dr.Jit arrays) at sub-wavelength index
        ``k`` (a ``UInt32`` array or an int): the optics core's amplitudes of the stack at the
        pixel's incidence, rotated into the camera's Stokes frame."""
        t = self.types
        dr, Float = t.dr, t.Float
        lam = dr.gather(Float, t.lam, k)
        layers = []
        def at(tab):
            if tab is None:
                return 0.0
            return tab if dr.width(tab) == 1 else dr.gather(Float, tab, k)

        for i, (n_tab, k_tab) in enumerate(t.n):
            n = at(n_tab)
            if i < len(state.index_offset):
                n = n + state.index_offset[i]
            layers.append((n, at(k_tab), state.thickness_nm[i]))
        n3, k3 = at(t.sub[0]), at(t.sub[1])
        r_s, r_p = optics.stack_amplitudes(state.cos_i, lam, layers, n3, k3, self._ext, lossless=self.lossless)
        Rs, Rp = r_s.abs2(), r_p.abs2()
        a = 0.5 * (Rs + Rp) * state.light
        b = 0.5 * (Rs - Rp) * state.light
        return a, b * state.c2, b * state.s2

    def _band_stokes(self, state_fn, band):
        """``(S0, S1, S2)`` of band ``band`` (UInt32 per lane): the band's sub-wavelengths
        summed with their weights in a symbolic loop; ``state_fn()`` makes the lanes' state
        (called inside the loop so that its AD graph is the loop body's)."""
        t = self.types
        dr, Float, UInt32 = t.dr, t.Float, t.UInt32
        first = dr.gather(UInt32, t.win_first, band)
        count = dr.gather(UInt32, t.win_count, band)
        if t.win_width == 1:
            return self.sub_stokes(state_fn(), first)

        def body(j, s0, s1, s2):
            w = dr.gather(Float, t.win_w, band * t.win_width + j)
            a, b, c = self.sub_stokes(state_fn(), first + j)
            return j + 1, s0 + w * a, s1 + w * b, s2 + w * c

        zero = dr.zeros(Float, dr.width(band))
        out = dr.while_loop((dr.zeros(UInt32, dr.width(band)), zero, zero, zero),
                            lambda j, *acc: j < count, body)
        return out[1:]

    def _tangents(self, fn, X, wrt):
        """``fn(columns)`` (a tuple of Dr.Jit arrays) and its derivatives by the columns
        ``wrt`` of ``X``, by forward-mode AD traced into the caller's kernel:
        ``(values, tangents)`` with ``tangents[j][m] = ∂ values[m] / ∂ X[wrt[j]]`` (detached)."""
        t = self.types
        dr, Float = t.dr, t.Float
        if not wrt:
            return [dr.detach(v) for v in fn(list(X))], []
        cols = list(X)
        leaves = []
        for j in wrt:
            cols[j] = Float(X[j])
            leaves.append(cols[j])
        dr.enable_grad(*leaves)
        outs = fn(cols)
        tangents = []
        for leaf in leaves:
            dr.set_grad(leaf, 1.0)
            dr.forward_to(*outs, flags=dr.ADFlag.ClearInterior)
            tangents.append([dr.grad(o) for o in outs])
            for o in outs:
                dr.set_grad(o, 0.0)
            dr.set_grad(leaf, 0.0)
        return [dr.detach(o) for o in outs], [[dr.detach(g) for g in row] for row in tangents]

    @staticmethod
    def _lane_shape(x, wrt):
        """``(n, Q)`` of lanes ``x`` (n, P): their number and that of the columns differentiated
        (``wrt``; None: all)."""
        shape = np.shape(x)
        if len(shape) != 2:
            raise ValueError(f"x must be (n, P), got shape {shape}")
        return shape[0], shape[1] if wrt is None else len(list(wrt))

    def _lanes(self, x, parametrization, fixed, rows, wrt, repeat=1):
        """Upload the lanes' inputs once and return ``at(k, lane_of)``: values and tangents of
        (S0, S1, S2) at sub-wavelength ``k`` for the lanes, plus the lanes' observation rows.
        ``repeat``: each input row feeds ``repeat`` consecutive lanes (one per band)."""
        t = self.types
        dr, Float, UInt32 = t.dr, t.Float, t.UInt32
        par = PARAMETRIZATIONS[parametrization] if isinstance(parametrization, str) else parametrization
        x = np.asarray(x, dtype=np.float64)
        if x.ndim != 2:
            raise ValueError(f"x must be (n, P), got shape {x.shape}")
        n, P = x.shape
        rows = np.arange(n) if rows is None else np.asarray(rows, dtype=np.int64)
        fixed = {} if fixed is None else fixed
        names = sorted(fixed)
        cols = [x[:, j] for j in range(P)] + [np.broadcast_to(np.asarray(fixed[k], dtype=np.float64), (n,))
                                              for k in names] + [rows.astype(np.float64)]
        table = np.stack(cols, axis=1)
        ncol = table.shape[1]
        flat = t.upload(table)
        lane = dr.arange(UInt32, n * repeat)
        src = (lane // repeat) * ncol if repeat > 1 else lane * ncol
        g = [dr.gather(Float, flat, src + c) for c in range(ncol)]
        X, F = g[:P], dict(zip(names, g[P:P + len(names)]))
        row = UInt32(g[-1])
        wrt = list(range(P)) if wrt is None else list(wrt)

        def at(k):
            return self._tangents(lambda c: self.sub_stokes(par.unpack(c, F, self.layers, dr), k), X, wrt)

        return at, row, len(wrt), lane

    def normal_equations(self, observations: "Observations", x, parametrization="double_angle", fixed=None,
                         rows=None, derivatives: bool = True, wrt=None):
        """Gauss-Newton normal equations of a fit of per-pixel unknowns to captures.

        Residuals ``r = w (observed - predicted)`` (:class:`Observations`), predicted through
        :meth:`sub_stokes` and the bands' quadrature, the Jacobian ``J = ∂r/∂x`` by
        forward-mode AD; one kernel, a lane per row of ``x`` looping over the bands. With
        weights ``1/σ`` of the data's noise, ``H`` is the Fisher information of the lane's
        unknowns (the Cramér-Rao bound is its inverse).

        Parameters
        ----------
        observations : :class:`Observations`
        x : (n, P) unknowns, columns as ``parametrization`` names them (n = 0: empty results,
            no kernel).
        parametrization : str or :class:`Parametrization`
        fixed : dict name → (n,) per-lane constants (``c2``, ``s2``, ``light``,
            ``thickness_nm.<i>``, ``index_offset.<i>``).
        rows : (n,) int, the observation row of each lane (default ``0 … n-1``): several
            lanes may fit the same pixel (candidates).
        derivatives : bool
            False: the cost alone (``H`` and ``g`` are None).
        wrt : columns of ``x`` to differentiate (default all); ``H`` and ``g`` are over them.

        Returns
        -------
        H : (n, Q, Q) ``JᵀJ``; g : (n, Q) ``Jᵀr``; cost : (n,) ``Σ r²``.
        """
        n, Q = self._lane_shape(x, wrt if derivatives else ())
        if n == 0:
            # no lanes: empty sums, no kernel (Dr.Jit cannot mix arrays of width 0 and 1)
            if not derivatives:
                return None, None, np.zeros(0)
            return np.zeros((0, Q, Q)), np.zeros((0, Q)), np.zeros(0)
        t = self.types
        dr, Float, UInt32 = t.dr, t.Float, t.UInt32
        at, row, Q, _ = self._lanes(x, parametrization, fixed, rows, (wrt if derivatives else ()))
        dev = observations.device(t)
        if observations.kind == "polarized_rgb":
            acc = self._rgb_accumulate(at, n, Q)
            r, J = observations.residuals_rgb(acc, row, dev, dr, Float)
            sums = _normal_terms(r, J, Q)
        else:
            bands = dr.opaque(UInt32, self.bands)

            def body(b, *sums):
                vals, tans = self._band_values(at, b, Q)
                r, J = observations.residuals_band(vals, tans, row, b, dev, dr, Float)
                return (b + 1, *(s_ + d_ for s_, d_ in zip(sums, _normal_terms(r, J, Q))))

            count = Q * (Q + 1) // 2 + Q + 1
            zero = dr.zeros(Float, n)
            sums = dr.while_loop((dr.zeros(UInt32, n),) + (zero,) * count, lambda b, *a: b < bands, body)[1:]
        dr.eval(*sums)
        sums = [np.asarray(v, dtype=np.float64) for v in sums]
        cost = sums[-1]
        if not derivatives:
            return None, None, cost
        H = np.empty((n, Q, Q))
        k = 0
        for a in range(Q):
            for c in range(a, Q):
                H[:, a, c] = H[:, c, a] = sums[k]
                k += 1
        return H, np.stack(sums[k:k + Q], axis=1), cost

    def evaluate(self, kind: str, x, parametrization="double_angle", fixed=None, derivatives: bool = False,
                 wrt=None, angles_deg=None, bias_sigma=None):
        """Predicted captures of lanes and, optionally, their Jacobian by AD.

        Parameters
        ----------
        kind : {"stokes", "spectral_s", "sp", "polarized_rgb"}
            What is predicted per lane: ``stokes`` (3 B values: S0 of every band, then S1,
            then S2), ``spectral_s`` (B), ``sp`` (2 B: ``S0 + S1`` then ``S0 − S1``, the s and
            p spectra along the plane of incidence of ``c2 = 1, s2 = 0``), ``polarized_rgb``
            (3 A: per angle of ``angles_deg`` (default the rig's) R, G, B).
        x, parametrization, fixed, wrt : as :meth:`normal_equations`.
        bias_sigma : for ``spectral_s``, as :class:`Observations`.

        Returns
        -------
        values : (n, M); with ``derivatives`` also ``jacobian`` (n, M, Q).
        """
        if kind not in ("stokes", "spectral_s", "sp", "polarized_rgb"):
            raise ValueError(f"kind must be stokes, spectral_s, sp or polarized_rgb, got {kind!r}")
        n, Q = self._lane_shape(x, wrt if derivatives else ())
        if n == 0:
            # no lanes: empty predictions of the kind's width, no kernel
            if kind == "polarized_rgb":
                M = 3 * np.size(angles_deg if angles_deg is not None else self.rig.polarizer_angles_deg)
            else:
                M = {"stokes": 3, "spectral_s": 1, "sp": 2}[kind] * self.bands
            return np.zeros((0, M)) if not derivatives else (np.zeros((0, M)), np.zeros((0, M, Q)))
        t = self.types
        dr, Float, UInt32 = t.dr, t.Float, t.UInt32
        if kind == "polarized_rgb":
            angles = np.radians(np.asarray(angles_deg if angles_deg is not None else self.rig.polarizer_angles_deg,
                                           dtype=np.float64))
            at, row, Q, _ = self._lanes(x, parametrization, fixed, None, (wrt if derivatives else ()))
            acc = self._rgb_accumulate(at, n, Q)
            outs = []
            for alpha in angles:
                ca, sa = 0.5 * math.cos(2 * alpha), 0.5 * math.sin(2 * alpha)
                for c in range(3):
                    outs.append([0.5 * acc[9 * q + c] + ca * acc[9 * q + 3 + c] + sa * acc[9 * q + 6 + c]
                                 for q in range(Q + 1)])
            dr.eval(*[v for o in outs for v in o])
            vals = np.stack([np.asarray(o[0], dtype=np.float64) for o in outs], axis=1)
            if not derivatives:
                return vals
            jac = np.stack([np.stack([np.asarray(o[q + 1], dtype=np.float64) for o in outs], axis=1)
                            for q in range(Q)], axis=2)
            return vals, jac
        B = self.bands
        at, row, Q, lane = self._lanes(x, parametrization, fixed, None, (wrt if derivatives else ()), repeat=B)
        b = lane - (lane // B) * B
        vals, tans = self._band_values(at, b, Q)
        if kind == "stokes":
            comps = [[vals[m]] + [tans[q][m] for q in range(Q)] for m in range(3)]
        elif kind == "sp":
            comps = [[vals[0] + vals[1]] + [tans[q][0] + tans[q][1] for q in range(Q)],
                     [vals[0] - vals[1]] + [tans[q][0] - tans[q][1] for q in range(Q)]]
        else:
            lin2 = vals[1] * vals[1] + vals[2] * vals[2]
            if bias_sigma is not None:
                bias = np.broadcast_to(np.asarray(bias_sigma, dtype=np.float64), (n,))
                lin2 = lin2 + dr.gather(Float, t.upload((0.5 * np.pi) * bias ** 2), lane // B)
            lin = dr.sqrt(lin2)
            inv = dr.select(lin > 0, 1.0 / dr.select(lin > 0, lin, 1.0), 0.0)
            comps = [[vals[0] + lin] + [tans[q][0] + (vals[1] * tans[q][1] + vals[2] * tans[q][2]) * inv
                                        for q in range(Q)]]
        dr.eval(*[v for c in comps for v in c])
        arr = [[np.asarray(v, dtype=np.float64).reshape(n, B) for v in c] for c in comps]
        values = np.concatenate([c[0] for c in arr], axis=1)
        if not derivatives:
            return values
        jac = np.stack([np.concatenate([c[q + 1] for c in arr], axis=1) for q in range(Q)], axis=2)
        return values, jac

    def _band_values(self, at, b, P):
        """Values and tangents of the band Stokes at band ``b`` (a UInt32 per lane): a symbolic
        loop over the band's sub-wavelengths (or one evaluation for point-sampled bands)."""
        t = self.types
        dr, Float, UInt32 = t.dr, t.Float, t.UInt32
        first = dr.gather(UInt32, t.win_first, b)
        if t.win_width == 1:
            return at(first)
        count = dr.gather(UInt32, t.win_count, b)

        def body(j, *acc):
            w = dr.gather(Float, t.win_w, b * t.win_width + j)
            vals, tans = at(first + j)
            flat = list(vals) + [v for row in tans for v in row]
            return (j + 1, *(a + w * v for a, v in zip(acc, flat)))

        m = dr.width(b)
        zero = dr.zeros(Float, m)
        out = dr.while_loop((dr.zeros(UInt32, m),) + (zero,) * (3 + 3 * P), lambda j, *a: j < count, body)[1:]
        vals = list(out[:3])
        tans = [list(out[3 + 3 * p:6 + 3 * p]) for p in range(P)]
        return vals, tans

    def _rgb_accumulate(self, at, n, P):
        """Camera-RGB Stokes (3 components × 3 channels) and their tangents of every lane: one
        symbolic loop over all sub-wavelengths with the weights ``Σ_b W[b, k] C[b, c]``.
        Returns ``[S0 R, S0 G, S0 B, S1 R, …, S2 B]`` then the same for each tangent."""
        t = self.types
        dr, Float, UInt32 = t.dr, t.Float, t.UInt32
        if getattr(t, "rgb_w", None) is None:
            cw = self.rig.camera_weights()
            t.rgb_w = t.upload(cw if self.weights is None else self.weights.T @ cw)      # (K, 3)
        subs = dr.opaque(UInt32, self.sub_nm.size)

        def body(k, *acc):
            vals, tans = at(k)
            wc = [dr.gather(Float, t.rgb_w, k * 3 + c) for c in range(3)]
            flat = [w * v for v in vals for w in wc] + [w * v for row in tans for v in row for w in wc]
            return (k + 1, *(a + f for a, f in zip(acc, flat)))

        zero = dr.zeros(Float, n)
        out = dr.while_loop((dr.zeros(UInt32, n),) + (zero,) * (9 + 9 * P), lambda k, *a: k < subs, body)[1:]
        return list(out)

    # -- NumPy ---------------------------------------------------------------------------------

    def stokes(self, normals, thickness_nm, views=None, e1=None, index_offset=None, chunk: int = 1 << 22) -> dict:
        """The band Stokes cube of pixels.

        Parameters
        ----------
        normals : (N, 3) unit normals in the camera frame.
        thickness_nm : (N,) for a single film or the top layer of a stack (the other layers
            scaled with it, :meth:`thinfilm.core.film.Film.thickness_scale`), or (N, L).
        views, e1 : (N, 3) view vectors and Stokes reference axes; default the rig's
            (:func:`view_frames`).
        index_offset : (L,) offsets added to the layers' indices (default 0).

        Returns
        -------
        dict ``S0``, ``S1``, ``S2`` → (N, B) float64.
        """
        normals = np.asarray(normals, dtype=np.float64).reshape(-1, 3)
        n = normals.shape[0]
        d = self._layer_thickness(thickness_nm, n)
        if views is None or e1 is None:
            v, e = view_frames(self.rig, (1, n))
            views = v.reshape(-1, 3) if views is None else views
            e1 = e.reshape(-1, 3) if e1 is None else e1
        ok = np.all(np.isfinite(normals), axis=1) & np.all(np.isfinite(d), axis=1)
        normals = np.where(ok[:, None], normals, 0.0)
        d = np.where(ok[:, None], d, 0.0)
        t = self.types
        dr, Float, UInt32 = t.dr, t.Float, t.UInt32
        B = self.bands
        out = {k: np.empty((n, B)) for k in ("S0", "S1", "S2")}
        offsets = [float(v) for v in (index_offset if index_offset is not None else [])]
        per = max(1, chunk // B)
        for s in range(0, n, per):
            e = min(n, s + per)
            m = (e - s) * B
            lane = dr.arange(UInt32, m)
            pix = lane // B
            band = lane - pix * B
            cols = np.concatenate([normals[s:e], np.asarray(views)[s:e], np.asarray(e1)[s:e], d[s:e]], axis=1)
            flat = t.upload(cols)
            ncol = cols.shape[1]

            def state_fn(pix=pix, flat=flat, ncol=ncol):
                g = [dr.gather(Float, flat, pix * ncol + c) for c in range(ncol)]
                return state_from_normals(g[0:3], g[3:6], g[6:9], g[9:], self.rig.dome_hole_deg,
                                          offsets, ops=dr)

            S = self._band_stokes(state_fn, band)
            dr.eval(*S)
            for key, val in zip(("S0", "S1", "S2"), S):
                out[key][s:e] = np.asarray(val, dtype=np.float64).reshape(e - s, B)
        return out

    def captures(self, normals, thickness_nm, **kwargs) -> dict:
        """The captures of pixels: ``{"polarized_rgb": {angle: (N, 3)}, "spectral_s": (N, B),
        "stokes": {"S0", "S1", "S2": (N, B)}}`` (arguments as :meth:`stokes`)."""
        s = self.stokes(normals, thickness_nm, **kwargs)
        rgb, spectral = captures_from_stokes(s, self.rig.wavelengths_nm, self.rig.polarizer_angles_deg,
                                             self.rig.camera, self.rig.illuminant)
        return {"polarized_rgb": rgb, "spectral_s": spectral, "stokes": s}

    def _layer_thickness(self, thickness_nm, n) -> np.ndarray:
        d = np.asarray(thickness_nm, dtype=np.float64)
        if d.ndim == 1 or (d.ndim == 2 and d.shape[1] == 1 and self.layers == 1):
            d = d.reshape(-1)
            if d.size != n:
                raise ValueError(f"thickness_nm has {d.size} values for {n} pixels")
            if self.layers == 1:
                return d[:, None]
            scale = np.where(np.isfinite(d), self.film.thickness_scale(np.nan_to_num(d)), np.nan)
            return scale[:, None] * np.array([layer.thickness_nm for layer in self.film.layers])[None, :]
        if d.shape != (n, self.layers):
            raise ValueError(f"thickness_nm must be ({n},) or ({n}, {self.layers}) for a film of "
                             f"{self.layers} layers, got {d.shape}")
        return d


def _normal_terms(r, J, P):
    """Per-lane terms of the normal equations from residuals ``r`` (list) and their Jacobian
    rows ``J[p][m] = ∂r_m/∂x_p``: the upper triangle of JᵀJ, Jᵀr, and Σ r²."""
    out = []
    for a in range(P):
        for c in range(a, P):
            out.append(sum(J[a][m] * J[c][m] for m in range(len(r))))
    for a in range(P):
        out.append(sum(J[a][m] * r[m] for m in range(len(r))))
    out.append(sum(v * v for v in r))
    return out


class Observations:
    """Captures of some pixels, as a fit compares them with the model: rows of observed values
    and the weights of their residuals ``w (observed - predicted)``.

    Parameters
    ----------
    kind : {"stokes", "spectral_s", "sp", "polarized_rgb"}
    data : for ``stokes`` a tuple ``(S0, S1, S2)`` of (N, B) arrays; for ``spectral_s`` an
        (N, B) array; for ``sp`` an (N, 2 B) array of the s then the p spectra (predicted as
        ``S0 ± S1`` of a plane of incidence with ``c2 = 1, s2 = 0``); for ``polarized_rgb`` an
        (N, A, 3) array (angles ``angles_deg``).
    weights : for ``stokes`` a pair ``(w0, w1)`` (weights of the S0 and of the S1, S2
        residuals), for the others one weight; each a number, (N,) or (N, B) (``stokes``,
        ``spectral_s``) or (N, A, 3) (``polarized_rgb``).
    angles_deg : polarizer angles of ``polarized_rgb``.
    bias_sigma : for ``spectral_s``, optional (N,) noise of the measured S1, S2: the model is
        then the expectation of ``S0 + |(S1, S2)|`` under that noise, ``S0 + sqrt(S1² + S2² +
        (π/2) σ²)`` (the mean of a Rice distribution, within 0.09 σ), which near normal
        incidence, where the light is barely polarized, lies above ``R_s``.
    """

    KINDS = ("stokes", "spectral_s", "sp", "polarized_rgb")

    def __init__(self, kind: str, data, weights=1.0, angles_deg=None, bias_sigma=None):
        if kind not in self.KINDS:
            raise ValueError(f"kind must be one of {self.KINDS}, got {kind!r}")
        self.kind = kind
        if kind == "stokes":
            arrays = [np.asarray(a, dtype=np.float64) for a in data]
            n, b = arrays[0].shape
            w0, w1 = weights if isinstance(weights, (tuple, list)) else (weights, weights)
            wts = [np.broadcast_to(np.asarray(w, dtype=np.float64).reshape(np.shape(w) + (1,) * (2 - np.ndim(w))),
                                   (n, b)) for w in (w0, w1, w1)]
        elif kind in ("spectral_s", "sp"):
            arrays = [np.asarray(data, dtype=np.float64)]
            n, b = arrays[0].shape
            if kind == "sp":
                if b % 2:
                    raise ValueError("sp observations hold the s then the p spectrum: an even width")
                b //= 2
                arrays = [arrays[0][:, :b], arrays[0][:, b:]]
            w = np.asarray(weights, dtype=np.float64)
            wts = [np.broadcast_to(w.reshape(w.shape + (1,) * (2 - w.ndim)), (n, b))] * len(arrays)
        else:
            a3 = np.asarray(data, dtype=np.float64)
            n, na, _ = a3.shape
            if angles_deg is None or len(angles_deg) != na:
                raise ValueError("polarized_rgb observations need one angle per image")
            self.angles = np.radians(np.asarray(angles_deg, dtype=np.float64))
            arrays = [a3.reshape(n, na * 3)]
            w = np.asarray(weights, dtype=np.float64)
            wts = [np.broadcast_to(w.reshape(w.shape + (1,) * (3 - w.ndim)), (n, na, 3)).reshape(n, na * 3)]
            b = na * 3
        self.n, self.width = n, b
        self.arrays, self.wts = arrays, wts
        self.bias = None if bias_sigma is None else np.broadcast_to(np.asarray(bias_sigma, dtype=np.float64), (n,))
        self._device = {}

    def device(self, t):
        """The rows uploaded once per backend and precision."""
        key = (t.Float.__module__, t.Float.__name__)
        if key not in self._device:
            # weights that are the same over a row are read once per lane, not once per value
            per_row = [bool(np.all(w == w[:, :1])) for w in self.wts]
            dev = {"data": [t.upload(a) for a in self.arrays],
                   "w": [t.upload(w[:, 0] if r else w) for w, r in zip(self.wts, per_row)], "per_row": per_row}
            if self.bias is not None:
                dev["bias2"] = t.upload((0.5 * np.pi) * self.bias ** 2)
            self._device[key] = dev
        return self._device[key]

    @staticmethod
    def _weight(dev, m, row, j, dr, Float):
        return dr.gather(Float, dev["w"][m], row if dev["per_row"][m] else j)

    def residuals_band(self, vals, tans, row, b, dev, dr, Float):
        """Residuals and Jacobian rows of band ``b`` from the band's predicted Stokes values and
        tangents (``stokes``, ``spectral_s``)."""
        j = row * self.width + b
        if self.kind == "stokes":
            r, J = [], [[] for _ in tans]
            for m in range(3):
                w = self._weight(dev, m, row, j, dr, Float)
                r.append(w * (dr.gather(Float, dev["data"][m], j) - vals[m]))
                for p, tp in enumerate(tans):
                    J[p].append(-w * tp[m])
            return r, J
        if self.kind == "sp":
            r, J = [], [[] for _ in tans]
            for m, sign in ((0, 1.0), (1, -1.0)):
                w = self._weight(dev, m, row, j, dr, Float)
                r.append(w * (dr.gather(Float, dev["data"][m], j) - (vals[0] + sign * vals[1])))
                for p, tp in enumerate(tans):
                    J[p].append(-w * (tp[0] + sign * tp[1]))
            return r, J
        s0, s1, s2 = vals
        lin2 = s1 * s1 + s2 * s2
        if "bias2" in dev:
            lin2 = lin2 + dr.gather(Float, dev["bias2"], row)
        lin = dr.sqrt(lin2)
        inv = dr.select(lin > 0, 1.0 / dr.select(lin > 0, lin, 1.0), 0.0)
        w = self._weight(dev, 0, row, j, dr, Float)
        r = [w * (dr.gather(Float, dev["data"][0], j) - (s0 + lin))]
        J = [[-w * (tp[0] + (s1 * tp[1] + s2 * tp[2]) * inv)] for tp in tans]
        return r, J

    def residuals_rgb(self, acc, row, dev, dr, Float):
        """Residuals and Jacobian rows of the polarizer images from the camera-RGB Stokes
        accumulated over the sub-wavelengths (:meth:`ObservationModel._rgb_accumulate`)."""
        P = len(acc) // 9 - 1
        vals = acc[:9]
        tans = [acc[9 + 9 * p:18 + 9 * p] for p in range(P)]
        r, J = [], [[] for _ in range(P)]
        for ai, alpha in enumerate(self.angles):
            ca, sa = 0.5 * math.cos(2 * alpha), 0.5 * math.sin(2 * alpha)
            for c in range(3):
                j = row * self.width + ai * 3 + c
                w = self._weight(dev, 0, row, j, dr, Float)
                pred = 0.5 * vals[c] + ca * vals[3 + c] + sa * vals[6 + c]
                r.append(w * (dr.gather(Float, dev["data"][0], j) - pred))
                for p in range(P):
                    J[p].append(-w * (0.5 * tans[p][c] + ca * tans[p][3 + c] + sa * tans[p][6 + c]))
        return r, J


# ---------------------------------------------------------------------------------------------
# A spectrometer
# ---------------------------------------------------------------------------------------------


class Spectrometer:
    """A spectrometer's reading of a flat film: the unpolarized reflectance ``(R_s + R_p)/2``
    at one angle of incidence, point-sampled at given wavelengths, and its derivatives by AD
    in the thickness and in an offset added to the film's index.

    The rig is an :class:`ObservationModel` with point-sampled bands at the wavelengths, and a
    pixel the ``zenith`` parametrization at the angle of incidence, plane of incidence along the
    reference axis; ``S0`` is the unpolarized reflectance. What an instrument adds (background,
    response, the width of its pixels) is the caller's (:mod:`thinfilm.reconstruction.spectrum_fit`).

    Parameters
    ----------
    film : :class:`thinfilm.core.film.Film`
        A single film (its thickness is given per call).
    wavelengths_nm : (n,) increasing wavelengths.
    angle_deg : angle of incidence in the exterior medium, degrees.
    backend, precision : see :class:`ObservationModel`.

    Examples
    --------
    >>> from thinfilm.core.film import Film
    >>> from thinfilm.bsdf import optics
    >>> lam = np.linspace(450.0, 800.0, 8)
    >>> spot = Spectrometer(Film.single(1.33, substrate_ior=1.0), lam, angle_deg=30.0)
    >>> R, dR = spot.reflectance([1200.0], derivatives=True)
    >>> Rs, Rp = optics.reflectances(np.cos(np.radians(30.0)), lam, 1200.0, 1.33, 1.0)
    >>> bool(np.allclose(R[0], (Rs + Rp) / 2, rtol=0, atol=1e-12)), dR.shape
    (True, (1, 8, 1))
    """

    def __init__(self, film, wavelengths_nm, angle_deg: float = 0.0, backend: str = "llvm",
                 precision: str = "double"):
        lam = np.asarray(wavelengths_nm, dtype=np.float64).ravel()
        if not film.is_single:
            raise ValueError("a spectrometer reading is modelled for a single film")
        if not (math.isfinite(angle_deg) and 0.0 <= angle_deg < 90.0):
            raise ValueError(f"angle_deg must be in [0, 90), got {angle_deg}")
        self.film = film
        self.wavelengths_nm = lam
        self.angle_rad = math.radians(angle_deg)
        self._args = (Rig(wavelengths_nm=tuple(lam)), film, backend, precision, "centre")
        self._models = {}
        self._n_min = float(np.min(film.layers[0].n_k(lam)[0]))

    def _model(self, index_offset) -> ObservationModel:
        # an offset taking the film below the exterior's index needs complex normal components
        lossless = (index_offset is None or np.size(index_offset) == 0
                    or self._n_min + float(np.min(index_offset)) >= self.film.ext_ior)
        if lossless not in self._models:
            self._models[lossless] = ObservationModel(*self._args, lossless=None if lossless else False)
        return self._models[lossless]

    def reflectance(self, thickness_nm, index_offset=None, derivatives: bool = False):
        """The reflectance of films of thicknesses ``thickness_nm`` (K,) with index offsets
        ``index_offset`` (K,) or None: (K, n); with ``derivatives`` also (K, n, Q), the
        derivatives by the thickness and (where offsets are given) by the offset."""
        d = np.asarray(thickness_nm, dtype=np.float64).ravel()
        cols = [np.full(d.size, self.angle_rad), d]
        if index_offset is not None:
            cols.append(np.broadcast_to(np.asarray(index_offset, dtype=np.float64).ravel(), d.shape))
        x = np.stack(cols, axis=1)
        model = self._model(index_offset)
        n = self.wavelengths_nm.size
        if not derivatives:
            return model.evaluate("stokes", x, "zenith")[:, :n]
        values, jac = model.evaluate("stokes", x, "zenith", derivatives=True, wrt=list(range(1, x.shape[1])))
        return values[:, :n], jac[:, :n, :]


# ---------------------------------------------------------------------------------------------
# The entry point
# ---------------------------------------------------------------------------------------------


def predict(dataset, normals, thickness_nm, film=None, backend: str = "llvm", precision: str = "double") -> dict:
    """The captures the dataset's rig would record of a surface.

    Parameters
    ----------
    dataset : :class:`thinfilm.core.io.Dataset`
        From :func:`thinfilm.core.io.read_dataset`; its ``meta.json`` gives the rig (and the
        film, unless ``film`` is given).
    normals : (H, W, 3)
        Unit normals in the camera frame; pixels whose normal is not finite or faces away
        from the camera predict 0 (background).
    thickness_nm : (H, W), or (H, W, L) for a stack of L layers
        (H, W) for a stack is its top layer's thickness, the other layers scaled with it.
    film : :class:`thinfilm.core.film.Film`, optional
        Default: the dataset's (:meth:`thinfilm.core.io.Dataset.film`).
    backend, precision : see :class:`ObservationModel`.

    Returns
    -------
    dict
        ``polarized_rgb`` ({angle_deg: (H, W, 3)}), ``spectral_s`` ((H, W, B)) and ``stokes``
        ({"S0", "S1", "S2": (H, W, B)}), NumPy float64 arrays in reflectance units.
    """
    normals = np.asarray(normals, dtype=np.float64)
    if normals.ndim != 3 or normals.shape[2] != 3:
        raise ValueError(f"normals must be (H, W, 3), got {normals.shape}")
    h, w = normals.shape[:2]
    d = np.asarray(thickness_nm, dtype=np.float64)
    if d.shape[:2] != (h, w):
        raise ValueError(f"thickness_nm must be ({h}, {w}) or ({h}, {w}, layers), got {d.shape}")
    film = film if film is not None else dataset.film()
    model = ObservationModel(Rig.of_dataset(dataset), film, backend, precision)
    views, e1 = view_frames(model.rig, (h, w))
    cap = model.captures(normals.reshape(-1, 3), d.reshape(h * w, -1) if d.ndim == 3 else d.reshape(-1),
                         views=views.reshape(-1, 3), e1=e1.reshape(-1, 3))
    B = len(model.rig.wavelengths_nm)
    return {"polarized_rgb": {a: img.reshape(h, w, 3) for a, img in cap["polarized_rgb"].items()},
            "spectral_s": cap["spectral_s"].reshape(h, w, B),
            "stokes": {k: v.reshape(h, w, B) for k, v in cap["stokes"].items()}}
