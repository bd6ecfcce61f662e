"""The ``thinfilm`` command line.

Each subcommand's arguments are declared here (the contract of ``docs/design.md``,
*CLI contract*); the work is done by a ``cli_main(args)`` function in the module that owns
it, imported only when that subcommand runs so that ``thinfilm --help`` stays instant.

Bad input raises :class:`thinfilm.core.errors.UserError`; it is printed as one line on stderr
and the exit code is 2. Warnings (:class:`thinfilm.core.errors.ThinfilmWarning`) are printed
as one ``thinfilm: warning: ...`` line each.
"""

from __future__ import annotations

import argparse
import contextlib
import errno
import importlib
import sys

from . import __version__
from .core.errors import NoResultError, UserError

__all__ = ["main", "build_parser", "commands", "arguments", "subcommands", "flag_for", "cli_message"]

#: the flags of library arguments whose name is not the flag's (``--NAME`` with ``-`` for ``_``)
FLAGS = {"thickness_range_nm": "--thickness-range", "options": "--option"}


def flag_for(argument: str) -> str:
    """The command-line flag of a library argument (``substrate_ior`` → ``--substrate-ior``)."""
    return FLAGS.get(argument, "--" + argument.replace("_", "-"))


def cli_message(error: UserError) -> str:
    """A :class:`UserError` as the command line shows it: the argument it is about named by
    its flag."""
    argument = getattr(error, "argument", None)
    return error.render(flag_for(argument)) if argument else str(error)


class _Parser(argparse.ArgumentParser):
    """Usage errors as one line on stderr (``thinfilm: error: ...``), exit code 2."""

    def error(self, message):
        self.exit(2, f"{self.prog}: error: {message} (see '{self.prog} --help')\n")


def _positive_int(text):
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number, got {text!r}") from None
    if value <= 0:
        raise argparse.ArgumentTypeError(f"must be > 0, got {value}")
    return value


def _bounded_int(lo, hi):
    def parse(text):
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a whole number from {lo} to {hi}, got {text!r}") from None
        if not lo <= value <= hi:
            raise argparse.ArgumentTypeError(f"expected a whole number from {lo} to {hi}, got {value}")
        return value

    parse.__name__ = "whole number"
    return parse


def _positive_float(text):
    import math

    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"expected a finite number > 0, got {text!r}")
    return value


def _index(text):
    """A refractive index on the command line, as in scene specs: a number from 0.01 to 100
    (returned as a float), or ``n+ki`` text or a material name (a shipped table or a
    refractiveindex.info page), checked here and returned as the text."""
    import math

    from .generators.spec_schema import LIMITS

    lo, hi = LIMITS["index"]
    try:
        value = float(text)
    except ValueError:
        value = None
    if value is not None:
        if not (math.isfinite(value) and lo <= value <= hi):
            raise argparse.ArgumentTypeError(f"expected a refractive index from {lo:g} to {hi:g}, got {text!r}")
        return value
    from .bsdf.materials import parse_index

    try:
        parsed = parse_index(text)
    except ValueError as e:
        raise argparse.ArgumentTypeError(" ".join(str(e).split())) from None
    if hasattr(parsed, "n"):  # n+ki
        k_lo, k_hi = LIMITS["extinction"]
        if not (lo <= parsed.n <= hi and k_lo <= parsed.k <= k_hi):
            raise argparse.ArgumentTypeError(f"expected an index n from {lo:g} to {hi:g} and k from {k_lo:g} "
                                             f"to {k_hi:g}, got {text!r}")
    return text


def _nonnegative_float(text):
    import math

    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not (math.isfinite(value) and value >= 0):
        raise argparse.ArgumentTypeError(f"expected a finite number >= 0, got {text!r}")
    return value


#: command-line limits (the scene spec's are :data:`thinfilm.generators.spec_schema.LIMITS`)
MAX_SPP = 2**20
MAX_SEED = 2**32 - 1


def _workers(text):
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number, got {text!r}") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be >= 0, got {value}")
    return value


def _add_cluster_arguments(p) -> None:
    p.add_argument("--workers", type=_workers, default=None, metavar="N",
                   help="local Dask worker processes (default: one per core; 0: every task in this process)")
    p.add_argument("--scheduler", default=None, metavar="ADDRESS",
                   help="use an existing Dask cluster: tcp://HOST:PORT or a scheduler file")


def _examples(*lines: str) -> dict:
    """The keyword arguments of a (sub)parser whose ``--help`` ends with these example command
    lines (kept as written)."""
    return {"epilog": "examples:\n" + "\n".join("  " + line for line in lines),
            "formatter_class": argparse.RawDescriptionHelpFormatter}


def _add_refine_arguments(p):
    p.add_argument("--refine", action="store_true",
                   help="refine the estimate on all the captures before writing it ('thinfilm refine')")
    p.add_argument("--prior", choices=("default", "none"), default="default",
                   help="with --refine: default (a height field and smooth thickness) or none (each pixel alone)")


def build_parser() -> argparse.ArgumentParser:
    from .generators.spec_schema import LIMITS

    p = _Parser(
        prog="thinfilm",
        description="Spectral, polarized thin-film rendering, benchmark generation and reconstruction.",
        **_examples("thinfilm generate cylinder --out data/cyl --resolution 64",
                    "thinfilm reconstruct rgb data/cyl --out est/cyl-rgb",
                    "thinfilm evaluate data/cyl est/cyl-rgb --out eval/cyl-rgb",
                    "thinfilm COMMAND --help      (the options and an example of each command)"),
    )
    p.add_argument("--version", action="version", version=f"thinfilm {__version__}")
    sub = p.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True

    r = sub.add_parser("render", help="render a Mitsuba scene (XML, TOML or JSON dict) with the thinfilm plugin",
                       **_examples("thinfilm render examples/soap_bubble.xml --out out/bubble --spp 16"))
    r.add_argument("scene", help="Mitsuba scene: .xml, or a .toml/.json file holding a load_dict dictionary")
    r.add_argument("--out", required=True, help="output image path stem; writes STEM.exr and STEM.png")
    r.add_argument("--variant", default="llvm_ad_spectral_polarized", help="Mitsuba variant (default: %(default)s)")
    r.add_argument("--spp", type=_bounded_int(1, MAX_SPP), default=None,
                   help=f"samples per pixel, 1 to {MAX_SPP} (overrides the scene)")
    r.add_argument("--seed", type=_bounded_int(0, MAX_SEED), default=0,
                   help="sampler seed, 0 to 2^32 - 1 (default: %(default)s)")
    r.add_argument("--overwrite", action="store_true",
                   help="replace existing STEM.exr and STEM.png (never the scene's own files)")
    r.add_argument("--exposure", default="auto",
                   help="PNG brightness: 'auto' (99.5th percentile to 90%%) or a gain (the EXR stays linear)")
    r.set_defaults(target="thinfilm.render:cli_main")

    g = sub.add_parser("generate", help="generate a benchmark dataset from a scene spec or preset, or a sweep of them",
                       **_examples("thinfilm generate cylinder --out data/cyl --resolution 64",
                                   "thinfilm generate examples/scene.toml --out data/mine --set film.thickness.value=450",
                                   "thinfilm generate --sweep examples/sweep.toml --count 4 --seed 1 --out data/sweep"))
    g.add_argument("spec", metavar="SPEC.toml|PRESET", nargs="?", default=None,
                   help="a scene spec file, or a preset name (hemisphere, cylinder, pyramid); not with --sweep")
    g.add_argument("--out", required=True, help="the dataset folder to write (with --sweep: the folder of the datasets)")
    g.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="override a spec key, e.g. --set film.thickness.value=450 (repeatable)")
    g.add_argument("--resolution", type=_bounded_int(*LIMITS["resolution"]), default=None,
                   help="image width and height in pixels (%d to %d)" % LIMITS["resolution"])
    g.add_argument("--seed", type=int, default=None,
                   help="overrides the spec's seed (0 to 2^32 - 1); with --sweep, the sweep's seed")
    g.add_argument("--sweep", default=None, metavar="SWEEP.toml",
                   help="a scene spec whose values may be distributions: write --count datasets DIR/NNNN and DIR/index.csv")
    g.add_argument("--count", type=_positive_int, default=None, metavar="N", help="with --sweep: number of datasets")
    g.add_argument("--resume", action="store_true", help="with --sweep: keep the datasets already in --out")
    _add_cluster_arguments(g)
    g.set_defaults(target="thinfilm.sweep:generate_main")

    rec = sub.add_parser("reconstruct", help="estimate normals, film index and thickness from a dataset",
                         **_examples("thinfilm reconstruct rgb data/cyl --out est/cyl-rgb",
                                     "thinfilm reconstruct spectral data/cyl --out est/cyl-spec"))
    rsub = rec.add_subparsers(dest="kind", metavar="KIND")
    rsub.required = True
    rgb = rsub.add_parser("rgb", help="from polarized RGB images (known film index)",
                          **_examples("thinfilm reconstruct rgb data/cyl --out est/cyl-rgb",
                                      "thinfilm reconstruct rgb data/cyl --out est/cyl-paper --method paper "
                                      "--film-ior 1.38"))
    rgb.add_argument("dataset", help="a dataset folder (generated or imported)")
    rgb.add_argument("--out", required=True, help="the estimate folder to write")
    rgb.add_argument("--film-ior", type=_index, default=None, metavar="N2",
                     help="film index: a number, n+ki or a material name (default: the dataset's meta.json)")
    rgb.add_argument("--substrate-ior", type=_index, default=None, metavar="N3",
                     help="substrate index: a number, n+ki or a material name (default: the dataset's meta.json)")
    rgb.add_argument("--thickness-range", type=_nonnegative_float, nargs=2, metavar=("MIN", "MAX"), default=None,
                     help="film thicknesses to consider, nm (default: 100 to 1000; colour alone cannot order "
                          "thicker films)")
    rgb.add_argument("--method", default=None,
                     help="a method of 'thinfilm methods', or package.module:function (default: the kind's default)")
    rgb.add_argument("--mask", default=None, help="optional mask image (non-zero on the object)")
    rgb.add_argument("--option", action="append", default=None, metavar="NAME=VALUE",
                    help="set one of the method's options (repeatable; 'thinfilm methods' lists them)")
    _add_refine_arguments(rgb)
    rgb.set_defaults(target="thinfilm.reconstruct:cli_main")
    sp = rsub.add_parser("spectral", help="from s-polarized hyperspectral images (film index estimated)",
                         **_examples("thinfilm reconstruct spectral data/cyl --out est/cyl-spec",
                                     "thinfilm reconstruct spectral data/cyl --out est/cyl-paper --method paper"))
    sp.add_argument("dataset", help="a dataset folder (generated or imported)")
    sp.add_argument("--out", required=True, help="the estimate folder to write")
    sp.add_argument("--substrate-ior", type=_index, default=None, metavar="N3",
                    help="substrate index: a number, n+ki or a material name (default: the dataset's meta.json)")
    sp.add_argument("--thickness-range", type=_nonnegative_float, nargs=2, metavar=("MIN", "MAX"), default=None,
                    help="film thicknesses to consider, nm (default: 20 to 5000, less where the bands cannot "
                         "resolve the fringes)")
    sp.add_argument("--method", default=None,
                    help="a method of 'thinfilm methods', or package.module:function (default: the kind's default)")
    sp.add_argument("--mask", default=None, help="optional mask image (non-zero on the object)")
    sp.add_argument("--option", action="append", default=None, metavar="NAME=VALUE",
                    help="set one of the method's options (repeatable; 'thinfilm methods' lists them)")
    _add_refine_arguments(sp)
    sp.set_defaults(target="thinfilm.reconstruct:cli_main")

    rf = sub.add_parser("refine", help="fit an estimate again to all of a dataset's captures (shape, thickness, "
                                       "film index), with its uncertainty",
                        **_examples("thinfilm refine data/cyl est/cyl-rgb --out est/cyl-refined",
                                    "thinfilm refine data/cyl est/cyl-rgb --out est/cyl-pixels --prior none"))
    rf.add_argument("dataset", help="the dataset folder the estimate was made from")
    rf.add_argument("estimate", help="an estimate folder (any method's, or a third party's)")
    rf.add_argument("--out", required=True, help="the refined estimate folder to write")
    rf.add_argument("--prior", choices=("default", "none"), default="default",
                    help="default: a height field and smooth thickness; none: every pixel on its own")
    rf.add_argument("--iterations", type=_positive_int, default=8, metavar="N", help="Gauss-Newton iterations")
    rf.set_defaults(target="thinfilm.refine:cli_main")

    me = sub.add_parser("methods", help="list the reconstruction methods (built-in and installed)",
                        **_examples("thinfilm methods", "thinfilm methods --json"))
    me.add_argument("--json", action="store_true", help="one JSON object per method, for machines")
    me.set_defaults(target="thinfilm.methods_command:cli_main")

    ev = sub.add_parser("evaluate", help="re-render an estimate and score it against the captures",
                        **_examples("thinfilm evaluate data/cyl est/cyl-rgb --out eval/cyl-rgb"))
    ev.add_argument("dataset", help="the dataset folder the estimate was made from")
    ev.add_argument("estimate", help="an estimate folder written by 'thinfilm reconstruct'")
    ev.add_argument("--out", required=True, help="the evaluation folder to write (metrics.json, figures)")
    ev.set_defaults(target="thinfilm.evaluation:cli_main")

    _add_import_parsers(sub)

    b = sub.add_parser("benchmark", help="every scene of a suite x every method, scored, with a report",
                       **_examples("thinfilm benchmark --quick --out out/benchmark",
                                   "thinfilm benchmark --quick --methods coherent,eikonal --resolution 32 --out out/small",
                                   "thinfilm benchmark --quick --resume --baseline out/benchmark/results.json "
                                   "--out out/again"))
    b.add_argument("--suite", default=None, metavar="NAME|FILE",
                   help="a shipped suite (presets, the default; standard) or a suite .toml file")
    b.add_argument("--quick", action="store_true", help="small images (at most 128 px; presets: about a minute)")
    b.add_argument("--methods", default=None, metavar="A,B,...",
                   help="methods to run: names, aliases or package.module:function (default: the suite's, "
                        "else every registered method)")
    b.add_argument("--resolution", type=_positive_int, default=None, metavar="N", help="every scene at N x N pixels")
    b.add_argument("--resume", action="store_true", help="keep the finished tasks of an earlier run into --out")
    b.add_argument("--baseline", default=None, metavar="OLD/results.json",
                   help="compare with an earlier run: print what got worse, exit 1 on any regression")
    b.add_argument("--no-figures", action="store_true",
                   help="no PNG figures per task (faster for large suites; the report has the tables only)")
    _add_cluster_arguments(b)
    b.add_argument("--out", required=True, help="the run's folder (datasets, tasks, results.json, report.md)")
    b.add_argument("--refine", action="store_true",
                   help="also each kind's default method refined on the captures (rows NAME+refine)")
    b.set_defaults(target="thinfilm.benchmark:cli_main")

    fs = sub.add_parser("fit-spectrum", help="film thickness (and index) from measured reflection spectra",
                         **_examples("thinfilm fit-spectrum examples/spectrum_mgf2.csv --film-ior MgF2 --substrate-ior 1.52",
                                     "thinfilm fit-spectrum run/*.csv --film-ior cauchy:1.324,0.003046 --substrate-ior 1 "
                                     "--fit-film-ior --json"))
    fs.add_argument("spectra", nargs="+", metavar="SPECTRUM",
                    help="two-column text file: wavelength in nm, value (comma or whitespace separated)")
    fs.add_argument("--film-ior", required=True, metavar="N|MATERIAL|cauchy:A,B[,C]",
                    help="film index: a number, a material, or Cauchy n = A + B/λ² + C/λ⁴ with λ in µm "
                         "(B in µm², C in µm⁴; cauchy-nm:A,B[,C] takes them with λ in nm)")
    fs.add_argument("--substrate-ior", required=True, metavar="N3",
                    help="substrate index, a number or a material (1 for a free-standing film in air)")
    fs.add_argument("--substrate-k", type=float, default=None, metavar="K", help="substrate extinction k3")
    fs.add_argument("--angle", type=float, default=0.0, metavar="DEG",
                    help="angle of incidence in degrees (default: %(default)s; unpolarized light)")
    fs.add_argument("--background", default=None, metavar="FILE",
                    help="spectrum without film reflection (a black film, a dark reading)")
    fs.add_argument("--reference", default=None, metavar="FILE", help="spectrum of a white reference")
    fs.add_argument("--wavelength-range", type=float, nargs=2, metavar=("MIN", "MAX"), default=None,
                    help="fit only these wavelengths (nm)")
    fs.add_argument("--thickness-range", type=float, nargs=2, metavar=("MIN", "MAX"), default=None,
                    help="thicknesses searched (nm; default 1 to 10000, less where the sampling is coarse)")
    fs.add_argument("--resolution", type=float, default=None, metavar="FWHM",
                    help="the spectrometer's line width, full width at half maximum in nm (default: fitted)")
    fs.add_argument("--thickness-spread", type=float, default=None, metavar="SIGMA",
                    help="thickness spread over the light spot, standard deviation in nm (default: fitted)")
    fs.add_argument("--fit-film-ior", action="store_true", help="fit the film index too")
    fs.add_argument("--json", action="store_true", help="one JSON object per line, one per spectrum")
    fs.set_defaults(target="thinfilm.fit_spectrum:cli_main")
    return p


def commands(parser: argparse.ArgumentParser | None = None) -> list[tuple[str, argparse.ArgumentParser]]:
    """Every (sub)command of the command line, depth first: ``("thinfilm", parser)``,
    ``("thinfilm render", parser)``, ``("thinfilm reconstruct rgb", parser)``, ... (the
    command-line reference and the help tests walk it)."""
    parser = build_parser() if parser is None else parser
    out = [(parser.prog, parser)]
    for action in arguments(parser):
        if isinstance(action, argparse._SubParsersAction):
            for name, child in action.choices.items():
                out.extend(commands(child))
    return out


def arguments(parser: argparse.ArgumentParser) -> list[argparse.Action]:
    """The arguments of one (sub)parser, in their order (the subcommands' action included)."""
    return list(parser._actions)


def subcommands(parser: argparse.ArgumentParser) -> dict[str, str | None]:
    """The subcommands of one (sub)parser and the one-line help of each (None where it has
    none)."""
    out = {}
    for action in arguments(parser):
        if isinstance(action, argparse._SubParsersAction):
            helps = {choice.dest: choice.help for choice in action._choices_actions}
            out.update({name: helps.get(name) for name in action.choices})
    return out


def _add_import_parsers(sub) -> None:
    """``thinfilm import polarization|spectral`` (:mod:`thinfilm.importers`)."""
    imp = sub.add_parser("import", help="make a dataset folder from real captures (polarization camera, "
                                        "hyperspectral cubes)",
                         **_examples("thinfilm import polarization data/raw/raw.tiff --layout dofp-rgb --out data/part",
                                     "thinfilm import spectral cube.hdr --white white.hdr --dark dark.hdr --out data/cube"))
    isub = imp.add_subparsers(dest="kind", metavar="KIND")
    isub.required = True

    def common(q):
        q.add_argument("--out", required=True, help="the dataset folder to write")
        q.add_argument("--film-ior", default=None, metavar="N|MATERIAL", help="known film index, recorded in meta.json")
        q.add_argument("--substrate-ior", default=None, metavar="N", help="known substrate index, recorded in meta.json")
        q.add_argument("--pixel-size", type=float, default=None, metavar="S",
                       help="scene units per pixel (scales surface.ply), recorded in meta.json")
        q.add_argument("--saturation", default=None, metavar="LEVEL",
                       help="raw value at or above which a sample is saturated (default: the largest code, "
                            "less 0.2%% for images; the data type's largest value for integer cubes)")
        q.add_argument("--white-reflectance", default="1", metavar="R|CSV",
                       help="reflectance of the white reference target: a number or a CSV spectrum (default 1)")
        q.add_argument("--polarizer-extinction", default=None, metavar="E|E1,E2,...|FILE",
                       help="measured extinction ratio of the polarizers (minimum over maximum transmittance, in "
                            "[0, 1)): one for all, one per angle, or a text file of them")
        q.add_argument("--polarizer-offset", default=None, metavar="DEG|D1,D2,...|FILE",
                       help="measured axis of the polarizers minus their nominal angles, degrees: one for all, one "
                            "per angle, or a text file of them")

    pol = isub.add_parser("polarization", help="polarizer images or a colour polarization-sensor mosaic",
                          **_examples("thinfilm import polarization frame.tiff --layout dofp-rgb --bit-depth 12 "
                                      "--dark dark.tiff --white-reference white.tiff --out data/part",
                                      "thinfilm import polarization p0.tif p45.tif p90.tif p135.tif --layout separate "
                                      "--angles 0,45,90,135 --out data/dslr"))
    pol.add_argument("images", nargs="+", metavar="IMAGE", help="PNG or TIFF files (8, 12 or 16 bits)")
    pol.add_argument("--layout", required=True, choices=("separate", "dofp-rgb"),
                     help="separate: one RGB image per polarizer angle; dofp-rgb: raw mosaic(s) of a colour "
                          "division-of-focal-plane sensor")
    pol.add_argument("--angles", default=None, metavar="A,B,C,...",
                     help="separate: the polarizer angle of each image, in degrees (3 or more)")
    pol.add_argument("--pattern", default=None, metavar="PATTERN",
                     help="dofp-rgb: the sensor's filter pattern (default RGGB:90,45,135,0, Sony IMX250MYR)")
    pol.add_argument("--bit-depth", type=_positive_int, default=None, metavar="N",
                     help="bits of the camera's values (default: the file's; e.g. 12 for 12-bit values in 16-bit files)")
    pol.add_argument("--dark", default=None, metavar="FILE|LEVEL", help="dark frame (same shape) or dark level")
    pol.add_argument("--flat", default=None, metavar="FILE", help="flat field of a uniform unpolarized field (same shape)")
    pol.add_argument("--white-balance", default=None, metavar="R,G,B",
                     help="gains from normalized raw values to reflectance units")
    pol.add_argument("--white-reference", default=None, metavar="IMAGE",
                     help="image of a diffuse white target through the polarizers (same layout and shape)")
    pol.add_argument("--camera", default=None, metavar="NAME|CSV", help="camera sensitivities for the forward models")
    pol.add_argument("--illuminant", default=None, metavar="NAME|CSV", help="illuminant for the forward models")
    pol.add_argument("--wavelengths", default=None, metavar="START:STOP:STEP|LIST|FILE",
                     help="bands of the camera model (default 400:720:4)")
    pol.add_argument("--demosaic", default="bilinear", choices=("residual", "bilinear"),
                     help="dofp-rgb: bilinear per plane (default) or residual (polarization- and colour-aware "
                          "residual interpolation, object and background each from its own samples)")
    pol.add_argument("--mask", default=None, metavar="IMAGE",
                     help="dofp-rgb: the object's pixels (nonzero), same shape as the mosaic (default: found on "
                          "the mosaic when a lit object is seen before a dark background)")
    pol.add_argument("--edge-margin", type=int, default=None, metavar="N",
                     help="dofp-rgb with --demosaic residual: mark the object's outermost N pixels invalid "
                          "(default 3; 0 keeps them)")
    pol.add_argument("--keep-edges", action="store_true",
                     help="dofp-rgb: keep every pixel at the object's silhouette valid (bilinear: those whose "
                          "interpolation crosses it; residual: --edge-margin 0)")
    common(pol)
    pol.set_defaults(target="thinfilm.importers.polarization:cli_main")

    spe = isub.add_parser("spectral", help="hyperspectral cubes (ENVI or multi-page TIFF)",
                          **_examples("thinfilm import spectral cube.hdr --white white.hdr --dark dark.hdr --out data/cube",
                                      "thinfilm import spectral p0.tif p45.tif p90.tif p135.tif --polarizer stokes "
                                      "--wavelengths 400:720:4 --out data/cube"))
    spe.add_argument("cubes", nargs="+", metavar="CUBE", help="ENVI (.hdr and data) or TIFF cube(s)")
    spe.add_argument("--wavelengths", default=None, metavar="START:STOP:STEP|LIST|FILE",
                     help="band centres in nm (required for TIFF cubes; overrides an ENVI header)")
    spe.add_argument("--white", default=None, metavar="CUBE|CSV", help="white reference cube or spectrum")
    spe.add_argument("--dark", default=None, metavar="CUBE|CSV|LEVEL", help="dark reference cube, spectrum or level")
    spe.add_argument("--flat", default=None, metavar="CUBE|IMAGE",
                     help="flat field: a cube of a uniform field (same shape) or one image for every band; each "
                          "band is divided by its response relative to its mean (with a --white spectrum)")
    spe.add_argument("--polarizer", default="s", choices=("s", "stokes"),
                     help="s: one s-polarized cube (default); stokes: cubes behind polarizers at --angles")
    spe.add_argument("--angles", default=None, metavar="A,B,C,...",
                     help="stokes: the polarizer angle of each cube (default 0,45,90,135 for 4 cubes)")
    spe.add_argument("--band-fwhm", type=float, default=None, metavar="NM",
                     help="band width (FWHM, nm), recorded for re-rendering (default: the ENVI header's)")
    common(spe)
    spe.set_defaults(target="thinfilm.importers.spectral:cli_main")


def _one_line_warning(message, category, filename, lineno, line=None):
    """Warnings as one ``thinfilm: warning: ...`` line (no source line, no file name)."""
    text = " ".join(str(message).split())
    return f"thinfilm: warning: {text}\n"


def _one_line(text: str, limit: int = 400) -> str:
    line = " ".join(str(text).split())
    return line if len(line) <= limit else line[:limit - 1] + "…"


def _debug() -> bool:
    import os

    return os.environ.get("THINFILM_DEBUG", "") not in ("", "0")


def main(argv=None) -> int:
    """Run one command; returns the exit code.

    Exit codes: 0 success; 2 bad input or an output that cannot be written (one
    ``thinfilm: error: ...`` line on stderr, nothing written); 130 on Ctrl-C and 143 on
    SIGTERM (one line, temporary files removed). Warnings meant for users
    (:class:`~thinfilm.core.errors.ThinfilmWarning`) are printed as one line each when the
    command succeeds; when it fails, its error is the only line. Warnings of libraries are
    not shown (``THINFILM_DEBUG=1`` shows them, and the traceback of an unexpected error).
    """
    import signal
    import warnings

    from .core import signals

    previous = {}
    if _is_main_thread():
        for name in signals.NAMES:
            signum = getattr(signal, name, None)
            if signum is not None:
                previous[signum] = signal.getsignal(signum)
        signals.install()
    signals.reset()
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            code = _run(argv)
        if code == 0 or code is None:
            shown = set()
            for w in caught:
                if not (_is_ours(w.category) or _debug()):
                    continue
                text = _one_line_warning(w.message, w.category, w.filename, w.lineno)
                if text not in shown:
                    shown.add(text)
                    sys.stderr.write(text)
        if argv is None and code is not None and code >= 128:
            # Run as the program and interrupted: the clean-up is done; exit with the code
            # itself. (An interrupt that landed inside a library's embedded Python call leaves
            # the interpreter believing it went unhandled, and it would then kill itself with
            # the signal at exit instead of returning 130 or 143.)
            import os

            sys.stdout.flush()
            sys.stderr.flush()
            os._exit(code)
        return code
    finally:
        for signum, handler in previous.items():
            if handler is not None:
                signal.signal(signum, handler)


def _is_main_thread() -> bool:
    import threading

    return threading.current_thread() is threading.main_thread()


def _is_ours(category) -> bool:
    from .core.errors import ThinfilmWarning

    return issubclass(category, ThinfilmWarning)


def _interrupted(signum) -> int:
    import signal

    from .core import signals

    word = "interrupted" if signum in (None, signal.SIGINT) else "terminated"
    print(f"thinfilm: {word}", file=sys.stderr)
    return signals.exit_code(signum or signal.SIGINT)


def _run(argv) -> int:
    from .core import signals

    try:
        args = build_parser().parse_args(argv)
        module_name, func_name = args.target.split(":")
        try:
            module = importlib.import_module(module_name)
        except ModuleNotFoundError as e:
            if e.name and e.name.startswith("thinfilm") and signals.received() is None:
                print(f"thinfilm: error: '{args.command}' is not available in this version", file=sys.stderr)
                return 2
            raise
        return int(getattr(module, func_name)(args) or 0)
    except SystemExit:
        raise
    except KeyboardInterrupt:
        return _interrupted(signals.received())
    except signals.Terminated as e:
        return _interrupted(e.signum)
    except UserError as e:
        if signals.received() is not None:
            return _interrupted(signals.received())
        print(f"thinfilm: error: {_one_line(cli_message(e))}", file=sys.stderr)
        return 2
    except NoResultError as e:
        if signals.received() is not None:
            return _interrupted(signals.received())
        print(f"thinfilm: error: {_one_line(e)}", file=sys.stderr)
        return 1
    except BrokenPipeError:
        # the reader of our output went away (``thinfilm methods | head -1``): not an error
        import os

        with contextlib.suppress(OSError, ValueError):
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
    except MemoryError:
        print("thinfilm: error: out of memory: the inputs ask for more than this machine has (a smaller "
              "resolution, fewer bands or a narrower range)", file=sys.stderr)
        return 2
    except Exception as e:
        if signals.received() is not None:
            # A library turned the interrupt into an error of its own (an import cut short).
            return _interrupted(signals.received())
        if isinstance(e, OSError) and e.errno == errno.ENAMETOOLONG and e.filename is not None:
            # a path given by the user, met by a check that did not expect it to be refused
            from .core.files import path_error

            print(f"thinfilm: error: {_one_line(path_error(e.filename, 'file', e))}", file=sys.stderr)
            return 2
        from .bsdf.materials import WavelengthRangeError

        if isinstance(e, WavelengthRangeError):
            # a material met wavelengths outside its table (the inputs ask for them): no bug
            print(f"thinfilm: error: {_one_line(e)}", file=sys.stderr)
            return 2
        if _debug():
            raise
        what = f"{type(e).__name__}: {e}" if str(e) else type(e).__name__
        print(f"thinfilm: error: unexpected failure ({_one_line(what, 300)}); nothing was written. "
              f"This is a bug in thinfilm: please report it (THINFILM_DEBUG=1 shows the traceback)",
              file=sys.stderr)
        return 2


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
