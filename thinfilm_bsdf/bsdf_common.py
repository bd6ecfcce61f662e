"""What the project's Mitsuba plugins share: reading and checking their parameters, the film
(one layer or a stack) they are coated with, the Mueller matrix in Mitsuba's Stokes bases, and
the per-variant plugin class.

Used by the ``thinfilm`` BSDF (:mod:`thinfilm.bsdf.plugin`, with its rough lobe
:mod:`thinfilm.bsdf.microfacet`), the ``thinfilm_sheet`` BSDF (:mod:`thinfilm.bsdf.sheet`)
and the generator's ``imagespace`` texture (:mod:`thinfilm.generators.textures`). Importing it
imports Mitsuba; the functions that read properties or build Mitsuba values need a variant set.
"""

from __future__ import annotations

import math
import numbers

import drjit as dr
import mitsuba as mi

from . import limits
from .materials import Constant, as_dispersion, parse_stack

__all__ = [
    "ParameterError",
    "fail",
    "range_text",
    "checked_float",
    "texture_parameter",
    "check_texture",
    "clamped",
    "stack_layer_limit",
    "Film",
    "StackLayer",
    "check_parameters",
    "broadcast_like",
    "mueller_spectrum",
    "to_stokes_bases",
    "variant_class",
]


class ParameterError(ValueError, RuntimeError):
    """A bad parameter of a plugin: a ``ValueError``, and a ``RuntimeError`` as Mitsuba's own
    plugins raise for theirs (Mitsuba's loader reports either as a ``RuntimeError``,
    "failed to instantiate ... plugin of type ...", that ends with this message)."""


def fail(message: str, plugin: str = "thinfilm"):
    """Raise the :class:`ParameterError` of a bad parameter, prefixed with the plugin's name."""
    raise ParameterError(f"{plugin}: {message}")


def _number_text(x: float) -> str:
    return str(int(x)) if float(x).is_integer() and abs(x) < 1e15 else f"{x:g}"


def range_text(bounds, unit: str = "") -> str:
    """``"a finite number from LOW to HIGH UNIT"`` for a ``(low, high)`` range of :mod:`.limits`."""
    low, high = bounds
    return f"a finite number from {_number_text(low)} to {_number_text(high)}{' ' + unit if unit else ''}"


def checked_float(props, name, default, bounds, plugin="thinfilm", unit=""):
    """The number given for ``name`` (``default`` when absent) as a float, checked to be finite
    and within ``bounds`` (``(low, high)``, inclusive; :mod:`.limits`)."""
    value = props.get(name, default) if name in props else default
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        fail(f"parameter '{name}' must be a number, got {type(value).__name__}", plugin)
    value = float(value)
    low, high = bounds
    if not (math.isfinite(value) and low <= value <= high):
        fail(f"parameter '{name}' must be {range_text(bounds, unit)}, got {value}", plugin)
    return value


def texture_parameter(props, name):
    """The texture given for ``name`` (a texture or spectrum object), else None."""
    if name not in props:
        return None
    value = props.get(name)
    if isinstance(value, mi.Texture):
        return value
    if props.type(name) == mi.Properties.Type.Spectrum:
        return props.get_unbounded_texture(name)
    return None


#: the parameters of a texture (as ``mi.traverse`` names them) that hold the values it returns:
#: a ``bitmap``'s ``data``, a ``uniform`` or ``srgb`` texture's ``value``, a spectrum's ``values``
_VALUE_KEYS = ("data", "value", "values")


def check_texture(texture, name, bounds, plugin="thinfilm", unit=""):
    """Refuse a texture whose stored values (``mi.traverse``: a ``bitmap``'s pixels, a
    constant's value, nested textures' too) are not finite or lie outside ``bounds``.

    What a texture computes rather than stores (a procedural or a user's Python texture) is
    not known here: the plugins clamp what they read from a texture into ``bounds`` (NaN read
    as the low end; :func:`clamped`)."""
    import numpy as np

    try:
        params = mi.traverse(texture)
        items = [(key, params[key]) for key in params.keys()]
    except Exception:  # a texture that cannot be traversed: its values are clamped when read
        return
    low, high = bounds
    for key, value in items:
        if key.rsplit(".", 1)[-1] not in _VALUE_KEYS:
            continue
        try:
            values = np.asarray(value, dtype=np.float64).ravel()
        except (TypeError, ValueError):
            continue
        bad = ~(np.isfinite(values) & (values >= low) & (values <= high))
        if bad.any():
            fail(f"parameter '{name}': the texture holds {values[bad][0]:g} ({int(bad.sum())} of "
                 f"the {values.size} values of its '{key}' out of range); expected "
                 f"{range_text(bounds, unit)}", plugin)


def clamped(value, bounds):
    """``value`` (read from a texture) clamped into ``bounds``, NaN read as the low end."""
    low, high = bounds
    return dr.clip(dr.select(dr.isnan(value), low, value), low, high)


#: ``thickness_scale``: a relative thickness, at most the thickest film over the thinnest
SCALE = (0.0, limits.THICKNESS_NM[1])


def _in_range(value, name, bounds, plugin, unit="", what=None):
    """``value`` (already a float) checked finite and within ``bounds``."""
    low, high = bounds
    if not (math.isfinite(value) and low <= value <= high):
        fail(f"parameter '{name}'{' ' + what if what else ''} must be {range_text(bounds, unit)}, "
             f"got {value}", plugin)
    return value


def stack_layer_limit():
    """The most layers a ``stack`` may have in the current variant (:mod:`.limits`)."""
    return limits.max_stack_layers(mi.variant())


class Film:
    """The film of a plugin: one film (``thickness``, ``film_ior``, ``film_k``) or a ``stack``,
    with ``thickness_scale``. Reads the properties, exposes and checks the parameters, and
    gives the layers ``(n, k, thickness_nm)`` at a surface point for the optics core.

    Shared by the ``thinfilm`` and ``thinfilm_sheet`` plugins (``plugin`` names the one
    in error messages).
    """

    def __init__(self, props, plugin="thinfilm", default_ior=1.37, default_thickness=400.0):
        self.plugin = plugin
        self.scale_tex = texture_parameter(props, "thickness_scale")
        if self.scale_tex is not None:
            check_texture(self.scale_tex, "thickness_scale", SCALE, plugin)
        self.scale = mi.Float(1.0 if self.scale_tex is not None else
                              checked_float(props, "thickness_scale", 1.0, SCALE, plugin))
        self.stack = None
        if "stack" in props:
            given = [name for name in ("thickness", "film_ior", "film_k") if name in props]
            if given:
                fail(f"parameter 'stack' cannot be combined with '{given[0]}' "
                     f"(write the film as a stack layer instead)", plugin)
            text = props.get("stack")
            if not isinstance(text, str):
                fail(f"parameter 'stack' must be a string 'INDEX:THICKNESS_NM, ...', "
                     f"got {type(text).__name__}", plugin)
            count, most = text.count(",") + 1, stack_layer_limit()
            if count > most:  # counted before any layer is read
                fail(f"parameter 'stack' holds {count} layers, at most {most} in {mi.variant()} "
                     f"(thinfilm.bsdf.limits: every layer adds to the kernel Mitsuba compiles)", plugin)
            try:
                layers = parse_stack(text)
            except ValueError as e:
                fail(f"parameter 'stack': {e}", plugin)
            self.stack = [StackLayer(layer, i, plugin) for i, layer in enumerate(layers)]
            return

        # Thickness: number or texture.
        self.thickness_tex = texture_parameter(props, "thickness")
        if self.thickness_tex is not None:
            check_texture(self.thickness_tex, "thickness", limits.THICKNESS_NM, plugin, "nm")
            self.thickness = mi.Float(0.0)
        else:
            self.thickness = mi.Float(checked_float(props, "thickness", default_thickness,
                                                    limits.THICKNESS_NM, plugin, "nm"))

        # Film index: number, spectrum texture, n+ki text or material name; extinction.
        self.ior_tex = texture_parameter(props, "film_ior")
        self.dispersion = None
        k = None
        raw = props.get("film_ior", default_ior) if "film_ior" in props else default_ior
        if self.ior_tex is not None:
            if mi.is_rgb and props.type("film_ior") == mi.Properties.Type.Spectrum \
                    and "uniform=" not in str(raw):
                fail("parameter 'film_ior': a spectrum needs a spectral variant (Mitsuba's RGB "
                     "variants reduce it to a colour); give a number or a material name", plugin)
            check_texture(self.ior_tex, "film_ior", limits.INDEX, plugin)
            self.ior = mi.Float(0.0)
        elif isinstance(raw, str):
            try:
                disp = as_dispersion(raw)
            except ValueError as e:
                fail(f"parameter 'film_ior': {e}", plugin)
            if isinstance(disp, Constant):
                self.ior = mi.Float(_in_range(disp.n, "film_ior", limits.INDEX, plugin))
                k = _in_range(disp.k, "film_ior", limits.EXTINCTION, plugin, what="extinction k")
            else:
                self.dispersion = disp
                self.ior = mi.Float(0.0)
            if "film_k" in props and (self.dispersion is not None or k):
                fail(f"parameter 'film_k' cannot be combined with film_ior {raw!r}, which "
                     f"brings its own extinction", plugin)
        else:
            self.ior = mi.Float(checked_float(props, "film_ior", default_ior, limits.INDEX, plugin))
        if k is None:
            k = checked_float(props, "film_k", 0.0, limits.EXTINCTION, plugin)
        self.k = mi.Float(k)

    # -- parameters ---------------------------------------------------------

    def opaque(self):
        """The scalar parameters, to be made opaque (kernel inputs, not literals)."""
        values = [self.scale]
        if self.stack is None:
            values += [self.thickness, self.ior, self.k]
        else:
            for layer in self.stack:
                values += [layer.thickness, layer.ior, layer.k]
        return values

    def traverse(self, callback):
        diff = mi.ParamFlags.Differentiable
        callback.put("thickness_scale", self.scale_tex if self.scale_tex is not None else self.scale,
                     diff)
        if self.stack is not None:
            for i, layer in enumerate(self.stack):
                callback.put(f"layer_{i}.thickness", layer.thickness, diff)
                if layer.dispersion is None:
                    callback.put(f"layer_{i}.ior", layer.ior, diff)
                    callback.put(f"layer_{i}.k", layer.k, diff)
            return
        callback.put("thickness", self.thickness_tex if self.thickness_tex is not None
                     else self.thickness, diff)
        if self.ior_tex is not None:
            callback.put("film_ior", self.ior_tex, diff)
        elif self.dispersion is None:
            callback.put("film_ior", self.ior, diff)
        if self.dispersion is None:
            callback.put("film_k", self.k, diff)

    def check_wavelengths(self, wavelength, plugin=None):
        """Refuse a database material whose range does not cover the wavelengths this variant
        evaluates (:func:`check_material_wavelengths`)."""
        models = ([layer.dispersion for layer in self.stack] if self.stack is not None
                  else [self.dispersion])
        check_material_wavelengths(models, wavelength, "stack" if self.stack is not None else "film_ior",
                                   plugin or self.plugin)

    def checks(self):
        """``(name, value, bounds)`` for every scalar parameter (see ``check_parameters``)."""
        out = [] if self.scale_tex is not None else [("thickness_scale", self.scale, SCALE)]
        if self.stack is not None:
            for i, layer in enumerate(self.stack):
                out.append((f"layer_{i}.thickness", layer.thickness, limits.THICKNESS_NM))
                if layer.dispersion is None:
                    out += [(f"layer_{i}.ior", layer.ior, limits.INDEX),
                            (f"layer_{i}.k", layer.k, limits.EXTINCTION)]
            return out
        if self.thickness_tex is None:
            out.append(("thickness", self.thickness, limits.THICKNESS_NM))
        if self.ior_tex is None and self.dispersion is None:
            out.append(("film_ior", self.ior, limits.INDEX))
        out.append(("film_k", self.k, limits.EXTINCTION))
        return out

    def describe(self) -> str:
        if self.stack is not None:
            return "stack=[" + ", ".join(layer.describe() for layer in self.stack) + "]"
        film = (self.dispersion.name if self.dispersion is not None
                else "texture" if self.ior_tex is not None else self.ior)
        thickness = "texture" if self.thickness_tex is not None else self.thickness
        return f"thickness={thickness} nm, film_ior={film}, film_k={self.k}"

    # -- layers at a surface point --------------------------------------------

    def layers(self, si, wavelengths, active):
        """``[(n, k, thickness_nm), ...]`` from the exterior down, at ``si`` and ``wavelengths``."""
        scale = (clamped(self.scale_tex.eval_1(si, active), SCALE) if self.scale_tex is not None
                 else self.scale)
        if self.stack is not None:
            return [layer.at(wavelengths, scale) for layer in self.stack]
        if self.ior_tex is not None and mi.is_rgb:  # RGB: one (grey) index per point
            n = broadcast_like(clamped(self.ior_tex.eval_1(si, active), limits.INDEX), wavelengths)
        elif self.ior_tex is not None:
            n = clamped(self.ior_tex.eval(si, active), limits.INDEX)
        elif self.dispersion is not None:
            n = self.dispersion(wavelengths)
        else:
            n = mi.UnpolarizedSpectrum(self.ior)
        k = self.dispersion.extinction(wavelengths) if self.dispersion is not None else self.k
        if self.thickness_tex is not None:
            thickness = clamped(self.thickness_tex.eval_1(si, active), limits.THICKNESS_NM)
        else:
            thickness = self.thickness
        return [(n, k, thickness * scale)]


class StackLayer:
    """One layer (number ``index`` from the exterior) of a ``stack`` parameter: its thickness and
    constant index as opaque Floats, or a tabulated material; checked within :mod:`.limits`."""

    def __init__(self, layer, index=0, plugin="thinfilm"):
        name = f"layer_{index}"
        self.thickness = mi.Float(_in_range(layer.thickness_nm, f"{name}.thickness",
                                            limits.THICKNESS_NM, plugin, "nm"))
        if isinstance(layer.material, Constant):
            self.dispersion = None
            self.ior = mi.Float(_in_range(layer.material.n, f"{name}.ior", limits.INDEX, plugin))
            self.k = mi.Float(_in_range(layer.material.k, f"{name}.k", limits.EXTINCTION, plugin))
        else:
            self.dispersion = layer.material
            self.ior = mi.Float(0.0)
            self.k = mi.Float(0.0)

    def at(self, wavelengths, scale):
        if self.dispersion is not None:
            return (self.dispersion(wavelengths), self.dispersion.extinction(wavelengths),
                    self.thickness * scale)
        return self.ior, self.k, self.thickness * scale

    def describe(self) -> str:
        index = self.dispersion.name if self.dispersion is not None else f"{self.ior}+{self.k}i"
        return f"{index}:{self.thickness}"


def check_material_wavelengths(models, wavelength, name, plugin="thinfilm"):
    """Refuse a database material (:class:`.materials.DatabaseMaterial`, among ``models``) whose
    range does not cover the wavelengths this variant evaluates: 360–830 nm in spectral
    variants (what Mitsuba samples), the colour basis's nodes in RGB variants, the
    ``wavelength`` parameter in mono variants. The plugins call it when they load and when
    ``wavelength`` changes; ``name`` is the parameter the message names."""
    models = [m for m in models if hasattr(m, "check_range")]
    if not models:
        return
    if mi.is_spectral:
        low, high, what = 360.0, 830.0, f"the wavelengths {mi.variant()} samples"
    elif mi.is_rgb:
        from .rgb import NODE_RANGE_NM

        (low, high), what = NODE_RANGE_NM, f"the wavelengths {mi.variant()} integrates over"
    else:
        low = high = float(dr.ravel(wavelength)[0]) if dr.width(wavelength) else 550.0
        what = "the 'wavelength' parameter"
    for model in models:
        try:
            model.check_range(low, high, what)
        except ValueError as e:
            fail(f"parameter '{name}': {e}", plugin)


def substrate_parameter(props, plugin="thinfilm"):
    """``(n3, k3, dispersion)`` of the ``substrate_ior`` and ``substrate_k`` properties: a
    number (with ``substrate_k``), ``n+ki`` text or a material name, whose dispersion and
    extinction then come from its table (``n3 = k3 = 0`` and ``dispersion`` the model)."""
    raw = props.get("substrate_ior") if "substrate_ior" in props else None
    if not isinstance(raw, str):
        return (checked_float(props, "substrate_ior", 1.6, limits.INDEX, plugin),
                checked_float(props, "substrate_k", 0.0, limits.SUBSTRATE_EXTINCTION, plugin), None)
    try:
        disp = as_dispersion(raw)
    except ValueError as e:
        fail(f"parameter 'substrate_ior': {e}", plugin)
    if isinstance(disp, Constant) and not disp.k:
        return (_in_range(disp.n, "substrate_ior", limits.INDEX, plugin),
                checked_float(props, "substrate_k", 0.0, limits.SUBSTRATE_EXTINCTION, plugin), None)
    if "substrate_k" in props:
        fail(f"parameter 'substrate_k' cannot be combined with substrate_ior {raw!r}, which "
             f"brings its own extinction", plugin)
    if isinstance(disp, Constant):
        return (_in_range(disp.n, "substrate_ior", limits.INDEX, plugin),
                _in_range(disp.k, "substrate_ior", limits.SUBSTRATE_EXTINCTION, plugin, what="extinction k"),
                None)
    return 0.0, 0.0, disp


def check_parameters(plugin, checks):
    """Refuse a parameter update that makes a value non-finite or puts it outside its range:
    ``checks`` holds ``(name, value, (low, high))``."""
    for name, value, (low, high) in checks:
        v = dr.ravel(value)
        if bool(dr.any(~((v >= low) & (v <= high)))):  # NaN fails both comparisons
            fail(f"parameter '{name}' must be {range_text((low, high))}, got {value}", plugin)


def broadcast_like(value, wavelengths):
    """``value`` (a Float per lane) broadcast to the type of ``wavelengths``."""
    cls = type(wavelengths)
    return value if type(value) is cls else cls(value)


def mueller_spectrum(a, b, c, s):
    """Mitsuba's Mueller matrix ``[[a, b, 0, 0], [b, a, 0, 0], [0, 0, c, s], [0, 0, -s, c]]``."""
    value = dr.zeros(mi.Spectrum)
    value[0, 0] = a
    value[0, 1] = b
    value[1, 0] = b
    value[1, 1] = a
    value[2, 2] = c
    value[2, 3] = s
    value[3, 2] = -s
    value[3, 3] = c
    return value


def to_stokes_bases(value, wo_hat, wi_hat, normal=None):
    """Rotate a Mueller matrix given in the s/p frame (Stokes reference axis perpendicular to
    the plane of incidence) into Mitsuba's implicit Stokes bases of ``-wo_hat`` (incoming
    light) and ``wi_hat`` (outgoing light), as Mitsuba's ``conductor`` and ``dielectric`` do.
    ``normal`` is the reflecting surface's normal: the shading normal by default, a
    microfacet normal in ``roughconductor``'s way."""
    n = mi.Vector3f(0, 0, 1) if normal is None else normal
    s_in = dr.cross(n, -wo_hat)
    s_out = dr.cross(n, wi_hat)
    collinear = dr.all(s_in == mi.Vector3f(0))
    s_in = dr.select(collinear, mi.Vector3f(1, 0, 0), dr.normalize(s_in))
    s_out = dr.select(collinear, mi.Vector3f(1, 0, 0), dr.normalize(s_out))
    return mi.mueller.rotate_mueller_basis(
        value,
        -wo_hat, s_in, mi.mueller.stokes_basis(-wo_hat),
        wi_hat, s_out, mi.mueller.stokes_basis(wi_hat),
    )


#: the per-variant plugin classes made so far, by (class name, variant)
_CLASSES: dict = {}


def variant_class(mixin, base: str, name: str):
    """A subclass of ``mi.<base>`` for the current Mitsuba variant, with ``mixin``'s methods.

    ``mi.BSDF``, ``mi.Texture`` … are different classes in every variant, and nanobind
    classes take one base, so Python plugins copy their methods into a per-variant subclass.
    """
    variant = mi.variant()
    if variant is None:
        raise RuntimeError(f"{name}: call mitsuba.set_variant(...) before using the plugin")
    key = (name, variant)
    if key not in _CLASSES:
        namespace = {k: v for k, v in vars(mixin).items() if k not in ("__dict__", "__weakref__")}
        _CLASSES[key] = type(name, (getattr(mi, base),), namespace)
    return _CLASSES[key]
