"""Film descriptions: the one way of turning a film into numbers.

A :class:`Film` is a stack of layers (:class:`thinfilm.bsdf.materials.Layer`: a material,
which is a number, a dispersion model or a shipped material with its extinction k, and a
thickness) from the exterior down, on a substrate ``n3 + i k3``, seen from an exterior medium of real index
``n1``. A single film is a stack of one. The capture generator, the reconstruction forward
models, the evaluation, the Mitsuba plugin dictionaries and ``meta.json`` all use it.

Index values (:func:`as_index`) may be given as

* a number (``1.37``), or a string of one (``"1.37"``);
* a complex index ``"n+ki"`` (``"1.65+0.01i"``, k >= 0 absorbing);
* a shipped material name (``"MgF2"``; :func:`thinfilm.bsdf.material_names`), which
  brings its own dispersion and extinction;
* a refractiveindex.info material (``"TiO2"``, ``"main/TiO2/Sarkar"``:
  :func:`thinfilm.bsdf.materials.database_material`), written back as its full page, and
  listed with the database version under ``film.material_sources`` of :meth:`Film.to_meta`;
* a Cauchy table ``{"cauchy": [A, B, C]}``, ``n = A + B/λ² + C/λ⁴`` with λ in **µm**, the one
  unit of Cauchy coefficients everywhere (:class:`thinfilm.bsdf.Cauchy`, :func:`cauchy_index`;
  ``thinfilm fit-spectrum --film-ior cauchy:A,B[,C]``); B and C plainly given with λ in nm
  are refused;
* a table ``{"n": 1.65, "k": 0.01}``.

**Effective index.** Where one number is needed for a dispersive index (the paper's
non-dispersive formulas, warnings, the film-index error of the evaluation), it is the real
part at :data:`REFERENCE_WAVELENGTH_NM` = 550 nm, the middle of the visible range: one
choice, made here (:meth:`Film.effective_index`).

``meta.json`` keeps the single-film keys ``film_ior``, ``substrate_ior`` and ``substrate_k``
(readers of older datasets use them) and adds ``film``, the full description
(:meth:`Film.to_meta`, :meth:`Film.from_meta`).

Examples
--------
>>> film = Film.single("MgF2", 100.0, substrate_ior=1.6)     # a quarter wave at 551 nm
>>> round(film.effective_index(), 4)
1.3785
>>> Rs, Rp = film.reflectances(1.0, 551.4)
>>> round(float(Rs), 5), round(((1.6 - 1.3785 ** 2) / (1.6 + 1.3785 ** 2)) ** 2, 5)
(0.00736, 0.00736)
>>> Film.from_meta(film.to_meta()) == film
True
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from thinfilm.bsdf.materials import Layer

from .errors import UserError

__all__ = [
    "REFERENCE_WAVELENGTH_NM",
    "CAUCHY_MAX_B_UM2",
    "CAUCHY_MAX_C_UM4",
    "cauchy_index",
    "Layer",
    "Film",
    "as_index",
    "index_to_json",
]

#: wavelength (nm) at which a dispersive index is read when one number is needed
REFERENCE_WAVELENGTH_NM = 550.0

#: the largest ``|B|`` (µm²) and ``|C|`` (µm⁴) of a Cauchy model. Transparent materials have B of
#: about 0.003–0.1 µm² and C below 0.01 µm⁴ (B = 1 µm² alone adds 6 to the index at 400 nm),
#: so a larger value is one given with λ in nm (B nm² = 1e-6 µm², C nm⁴ = 1e-12 µm⁴)
CAUCHY_MAX_B_UM2 = 1.0
CAUCHY_MAX_C_UM4 = 1.0


def cauchy_index(coefficients, where: str = "Cauchy model", unit: str = "um", other_form: str | None = None):
    """A Cauchy model ``n = A + B/λ² + C/λ⁴`` (:class:`thinfilm.bsdf.Cauchy`, λ in µm) from
    ``A, B[, C]``.

    Parameters
    ----------
    coefficients : sequence of 1 to 3 numbers, A > 0.
    unit : ``"um"`` (the project's unit) or ``"nm"``: the λ unit that B and C are given in
        (B nm² = 1e-6 µm², C nm⁴ = 1e-12 µm⁴).
    where : what the message of a :class:`UserError` names (a file and field, an option).
    other_form : how to write the coefficients in the other unit, for the message that
        refuses values plainly in that unit (e.g. ``"cauchy-nm:1.5,4000"``).

    Raises
    ------
    UserError
        One line: not 1 to 3 finite numbers, A <= 0, ``|B|`` > :data:`CAUCHY_MAX_B_UM2` or ``|C|`` >
        :data:`CAUCHY_MAX_C_UM4` in µm (plainly nm), a non-zero ``|B|`` or ``|C|`` below 1 in nm (plainly
        µm: it would change no index by 1e-5).

    Examples
    --------
    >>> cauchy_index([1.45, 0.004, 0.0001])
    Cauchy(A=1.45, B=0.004, C=0.0001)
    >>> n_nm = cauchy_index([1.45, 4000.0, 1e8], unit="nm")     # the same model, λ in nm
    >>> round(float(n_nm(500.0)), 10), round(1.45 + 0.004 / 0.5**2 + 0.0001 / 0.5**4, 10)
    (1.4676, 1.4676)
    """
    from thinfilm.bsdf.materials import Cauchy

    if unit not in ("um", "nm"):
        raise ValueError(f"cauchy_index: unit must be 'um' or 'nm', got {unit!r}")
    coef = list(coefficients) if isinstance(coefficients, (list, tuple)) else None
    if not coef or len(coef) > 3 or not all(_is_number(c) for c in coef):
        raise UserError(f"{where}: expected Cauchy constants A, B[, C] (n = A + B/λ² + C/λ⁴), "
                        f"got {coefficients!r}"[:300])
    a, b, c = [float(v) for v in coef] + [0.0] * (3 - len(coef))
    if a <= 0:
        raise UserError(f"{where}: the Cauchy constant A must be positive, got {a:g}")
    hint = f"; {other_form}" if other_form else ""
    if unit == "nm":
        if 0 < abs(b) < 1 or 0 < abs(c) < 1:
            raise UserError(f"{where}: Cauchy B = {b:g} nm², C = {c:g} nm⁴ are given with λ in µm, not nm "
                            f"(with λ in nm, B is about 3e3 to 1e5 nm²){hint}")
        b, c = b * 1e-6, c * 1e-12
        if abs(b) > CAUCHY_MAX_B_UM2 or abs(c) > CAUCHY_MAX_C_UM4:
            raise UserError(f"{where}: expected |B| <= {CAUCHY_MAX_B_UM2 * 1e6:g} nm² and |C| <= "
                            f"{CAUCHY_MAX_C_UM4 * 1e12:g} nm⁴, got B = {b * 1e6:g}, C = {c * 1e12:g}")
    elif abs(b) > CAUCHY_MAX_B_UM2 or abs(c) > CAUCHY_MAX_C_UM4:
        raise UserError(f"{where}: Cauchy B = {b:g} µm², C = {c:g} µm⁴ are given with λ in nm, not µm "
                        f"(B and C are in µm² and µm⁴: B is about 0.003 to 0.1, |B| <= {CAUCHY_MAX_B_UM2:g} "
                        f"and |C| <= {CAUCHY_MAX_C_UM4:g}){hint}")
    return Cauchy(a, b, c)

def as_index(value, where: str = "refractive index"):
    """A dispersion model (``thinfilm.bsdf`` ``Constant``, ``Cauchy`` or ``Tabulated``) from
    any of the forms of the module docstring; :class:`UserError` naming ``where`` otherwise.

    Examples
    --------
    >>> as_index("1.65+0.01i")
    Constant(n=1.65, k=0.01)
    >>> as_index({"n": 2.0, "k": 0})
    Constant(n=2.0, k=0.0)
    """
    from thinfilm.bsdf.materials import Cauchy, Constant, Tabulated, as_dispersion

    if isinstance(value, (Constant, Cauchy, Tabulated)):
        return value
    disp = None
    if isinstance(value, dict) and set(value) == {"cauchy"}:
        return cauchy_index(value["cauchy"], where,
                            other_form="divide B by 1e6 and C by 1e12 for λ in µm")
    if isinstance(value, dict) and set(value) <= {"n", "k"} and "n" in value:
        n, k = value["n"], value.get("k", 0.0)
        if _is_number(n) and _is_number(k):
            disp = Constant(float(n), float(k))
    elif not isinstance(value, bool):
        try:
            disp = as_dispersion(value)
        except (ValueError, TypeError) as e:
            raise UserError(f"{where}: {e}") from None
    if disp is None:
        raise UserError(f"{where}: expected a number, 'n+ki', a material name or "
                        f"{{cauchy = [A, B, C]}}, got {value!r}")
    if isinstance(disp, Constant):
        if not (math.isfinite(disp.n) and disp.n > 0):
            raise UserError(f"{where}: the index must be a number > 0, got {disp.n:g}")
        if not (math.isfinite(disp.k) and disp.k >= 0):
            raise UserError(f"{where}: the extinction k must be >= 0 (k > 0 absorbs), got {disp.k:g}")
    return disp


def _is_number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def index_to_json(index):
    """The JSON form of an index model (the inverse of :func:`as_index`): a number, a
    material name, ``{"n", "k"}`` or ``{"cauchy": [A, B, C]}``."""
    from thinfilm.bsdf.materials import Cauchy, Constant, Tabulated

    if index is None:
        return None
    if isinstance(index, Constant):
        return float(index.n) if index.k == 0 else {"n": float(index.n), "k": float(index.k)}
    if isinstance(index, Tabulated):
        return index.name
    if isinstance(index, Cauchy):
        return {"cauchy": [float(index.A), float(index.B), float(index.C)]}
    raise TypeError(f"not an index model: {index!r}")


@dataclass(frozen=True)
class Film:
    """Layers from the exterior down on a substrate, lit from an exterior medium.

    Attributes
    ----------
    layers : tuple of :class:`Layer` (one for a single film).
    substrate : index model of the substrate (``n3 + i k3``).
    ext_ior : real index of the exterior medium (1 for air).
    """

    layers: tuple
    substrate: object
    ext_ior: float = 1.0

    # -- construction -------------------------------------------------------------------------

    @classmethod
    def single(cls, film_ior=1.37, thickness_nm=None, substrate_ior=1.6, substrate_k=0.0,
               ext_ior=1.0, where: str = "film") -> "Film":
        """A single film; indices in any form of :func:`as_index` (``substrate_k`` adds an
        extinction to a numeric substrate index). ``film_ior = None``: the index is unknown
        (a method that estimates it)."""
        film = None if film_ior is None else as_index(film_ior, f"{where}: film index")
        sub = as_index(substrate_ior, f"{where}: substrate index")
        if substrate_k:
            from thinfilm.bsdf.materials import Constant

            if not isinstance(sub, Constant) or sub.k:
                raise UserError(f"{where}: substrate k given twice")
            sub = as_index({"n": sub.n, "k": substrate_k}, f"{where}: substrate k")
        if thickness_nm is not None:
            thickness_nm = float(thickness_nm)
            if not (math.isfinite(thickness_nm) and thickness_nm >= 0):
                raise UserError(f"{where}: thickness must be a number of nm >= 0, got {thickness_nm}")
        if not (_is_number(ext_ior) and ext_ior > 0):
            raise UserError(f"{where}: exterior index must be a number > 0, got {ext_ior!r}")
        return cls((Layer(film, thickness_nm),), sub, float(ext_ior))

    @classmethod
    def from_meta(cls, meta: dict, where: str = "meta.json") -> "Film":
        """The film of a ``meta.json`` (or ``estimate.json``): its ``film`` entry, else the
        single-film keys ``film_ior``, ``substrate_ior``, ``substrate_k``."""
        desc = meta.get("film")
        if isinstance(desc, dict):
            layers = desc.get("layers")
            if not isinstance(layers, list) or not layers:
                raise UserError(f"{where}: 'film.layers' must be a non-empty list")
            out = []
            for i, layer in enumerate(layers):
                if not isinstance(layer, dict) or "ior" not in layer:
                    raise UserError(f"{where}: 'film.layers[{i}]' must be a table with 'ior'")
                t = layer.get("thickness_nm")
                if t is not None and not (_is_number(t) and t >= 0):
                    raise UserError(f"{where}: 'film.layers[{i}].thickness_nm' must be >= 0, got {t!r}")
                out.append(Layer(as_index(layer["ior"], f"{where}: 'film.layers[{i}].ior'"),
                                 None if t is None else float(t)))
            sub = desc.get("substrate", {})
            if not isinstance(sub, dict) or "ior" not in sub:
                raise UserError(f"{where}: 'film.substrate' must be a table with 'ior'")
            ext = desc.get("ext_ior", 1.0)
            if not (_is_number(ext) and ext > 0):
                raise UserError(f"{where}: 'film.ext_ior' must be a number > 0, got {ext!r}")
            return cls(tuple(out), as_index(sub["ior"], f"{where}: 'film.substrate.ior'"), float(ext))
        if "film_ior" not in meta:
            raise UserError(f"{where}: no 'film_ior' (nor 'film')")
        if "substrate_ior" not in meta:
            raise UserError(f"{where}: no 'substrate_ior' (nor 'film')")
        k = meta.get("substrate_k", 0.0)
        if k is None:
            k = 0.0
        if not (_is_number(k) and k >= 0):
            raise UserError(f"{where}: 'substrate_k' must be a number >= 0, got {k!r}")
        sub = as_index(meta["substrate_ior"], f"{where}: 'substrate_ior'")
        if k:
            if not hasattr(sub, "k"):
                raise UserError(f"{where}: 'substrate_k' needs a numeric 'substrate_ior'")
            sub = as_index({"n": sub.n, "k": k}, f"{where}: 'substrate_k'")
        return cls((Layer(as_index(meta["film_ior"], f"{where}: 'film_ior'")),), sub, 1.0)

    def to_meta(self) -> dict:
        """``meta.json`` entries: ``film`` (the whole description) and the single-film keys
        ``film_ior`` (the top layer's index), ``substrate_ior`` and ``substrate_k`` for
        readers of single-film datasets."""
        sub = index_to_json(self.substrate)
        sub_n = sub["n"] if isinstance(sub, dict) and "n" in sub else sub
        # the database pages used (a page's name is its shelf/book/page), with the database version
        sources = {m.name: m.source for m in [layer.material for layer in self.layers] + [self.substrate]
                   if getattr(m, "source", "")}
        return {
            "film": {"layers": [{"ior": index_to_json(layer.material), "thickness_nm": layer.thickness_nm}
                                for layer in self.layers],
                     "substrate": {"ior": sub},
                     "ext_ior": self.ext_ior,
                     **({"material_sources": sources} if sources else {})},
            # a stack's top layer, for readers of single-film datasets
            "film_ior": index_to_json(self.layers[0].material),
            "substrate_ior": sub_n,
            "substrate_k": float(getattr(self.substrate, "k", 0.0) or 0.0),
        }

    def with_index(self, film_ior, layer: int = 0) -> "Film":
        """A copy with layer ``layer``'s index replaced (any form of :func:`as_index`)."""
        layers = list(self.layers)
        layers[layer] = replace(layers[layer], material=as_index(film_ior, f"film layer {layer} index"))
        return replace(self, layers=tuple(layers))

    def with_substrate(self, substrate_ior, substrate_k=0.0) -> "Film":
        """A copy on another substrate."""
        other = Film.single(1.0, None, substrate_ior, substrate_k)
        return replace(self, substrate=other.substrate)

    # -- numbers -------------------------------------------------------------------------------

    @property
    def is_single(self) -> bool:
        return len(self.layers) == 1

    def substrate_n_k(self, wavelength_nm):
        """Substrate index and extinction at ``wavelength_nm``."""
        return Layer(self.substrate).n_k(wavelength_nm)

    def effective_index(self, layer: int = 0) -> float:
        """Layer ``layer``'s real index as one number: its value at
        :data:`REFERENCE_WAVELENGTH_NM` (see the module docstring)."""
        return float(self.layers[layer].n_k(REFERENCE_WAVELENGTH_NM)[0])

    def effective_substrate_index(self) -> float:
        """The substrate's real index at :data:`REFERENCE_WAVELENGTH_NM`."""
        return float(self.substrate_n_k(REFERENCE_WAVELENGTH_NM)[0])

    @property
    def absorbing_substrate(self) -> bool:
        """Whether the substrate has k > 0 anywhere in 300-1000 nm."""
        lo, hi = 300.0, 1000.0
        if hasattr(self.substrate, "range_nm"):  # a database page: within its own range
            lo, hi = max(lo, self.substrate.range_nm[0]), min(hi, self.substrate.range_nm[1])
        return bool(np.any(self.substrate_n_k(np.linspace(lo, hi, 141))[1] > 0))

    def reflectances(self, cos_theta, wavelength_nm, thickness_nm=None):
        """Power reflectances ``(R_s, R_p)`` through the optics core.

        ``thickness_nm`` replaces the top layer's thickness (arrays broadcast as in
        :func:`thinfilm.bsdf.optics.reflectances`); the other layers of a stack scale with it
        (see :meth:`thickness_scale`). ``wavelength_nm`` gives the dispersion.
        """
        from thinfilm.bsdf import optics

        lam = np.asarray(wavelength_nm, dtype=np.float64)
        top = self.layers[0].thickness_nm if thickness_nm is None else thickness_nm
        if top is None:
            raise ValueError("the film's thickness is not known: pass thickness_nm")
        n3, k3 = self.substrate_n_k(lam)
        if self.is_single:
            n2, k2 = self.layers[0].n_k(lam)
            return optics.reflectances(cos_theta, lam, top, n2, n3, k3, self.ext_ior, k2)
        scale = self.thickness_scale(top)
        layers = [(*layer.n_k(lam), scale * layer.thickness_nm) for layer in self.layers]
        R_s, R_p, _, _ = optics.stack_powers(cos_theta, lam, layers, n3, k3, self.ext_ior)
        return R_s, R_p

    def thickness_scale(self, top_thickness_nm):
        """The factor on every layer's thickness that gives the top layer ``top_thickness_nm``
        (a stack deposited thinner or thicker as a whole; arrays allowed)."""
        nominal = self.layers[0].thickness_nm
        if not nominal:
            raise ValueError("the stack's top layer needs a thickness > 0 to scale the stack")
        return np.asarray(top_thickness_nm, dtype=np.float64) / nominal

    # -- Mitsuba --------------------------------------------------------------------------------

    def plugin_dict(self, thickness=None, thickness_scale=None, roughness: float = 0.0) -> dict:
        """The ``thinfilm`` BSDF dictionary of this film for ``mi.load_dict``.

        ``thickness``: a number of nm or a texture dictionary replacing a single film's
        thickness (default: the layer's own). A stack is written as the plugin's ``stack``
        text with its nominal thicknesses, and ``thickness_scale`` (a number or a texture
        dictionary) multiplies them. ``roughness`` > 0 makes the film rough: the plugin's
        ``alpha`` (GGX microfacets); 0 leaves the dictionary as a smooth film's.

        Examples
        --------
        >>> Film.single(1.37, 400.0).plugin_dict(roughness=0.05)["alpha"]
        0.05
        >>> "alpha" in Film.single(1.37, 400.0).plugin_dict()
        False
        """
        from thinfilm.bsdf.materials import Constant

        roughness = float(roughness)
        if not 0.0 <= roughness <= 1.0:
            raise ValueError(f"roughness must be a GGX alpha from 0 to 1, got {roughness}")
        out = {"type": "thinfilm", "ext_ior": float(self.ext_ior)}
        if self.is_single:
            if thickness_scale is not None:
                raise ValueError("a single film takes thickness, not thickness_scale")
            layer = self.layers[0]
            t = layer.thickness_nm if thickness is None else thickness
            if t is None:
                raise ValueError("the film's thickness is not known: pass thickness")
            out["thickness"] = t
            index = layer.material
            if isinstance(index, Constant):
                out["film_ior"] = float(index.n)
                if index.k:
                    out["film_k"] = float(index.k)
            else:
                out["film_ior"] = _plugin_index_text(index)
        else:
            if thickness is not None:
                raise ValueError("a stack takes thickness_scale, not thickness")
            if any(layer.thickness_nm is None for layer in self.layers):
                raise ValueError("every layer of a stack needs its thickness")
            out["stack"] = ", ".join(f"{_plugin_index_text(layer.material)}:{layer.thickness_nm!r}"
                                     for layer in self.layers)
            if thickness_scale is not None:
                out["thickness_scale"] = thickness_scale
        sub = self.substrate
        if isinstance(sub, Constant):
            out["substrate_ior"] = float(sub.n)
            out["substrate_k"] = float(sub.k)
        else:  # a material name (a Cauchy model has no plugin form)
            out["substrate_ior"] = _plugin_index_text(sub)
        if roughness > 0:
            out["alpha"] = roughness
        return out


def _plugin_index_text(index) -> str:
    """An index as the plugin's text (a number, ``n+ki`` or a material name)."""
    from thinfilm.bsdf.materials import Constant

    if isinstance(index, Constant):
        return f"{index.n!r}+{index.k!r}i" if index.k else repr(index.n)
    if hasattr(index, "name"):
        return index.name
    raise NotImplementedError(f"film index {index!r} in the plugin (a number, n+ki or a material name)")
