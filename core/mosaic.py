"""Colour-polarization filter arrays: the layout of a division-of-focal-plane (DoFP) sensor.

A colour polarization sensor puts one colour filter and one linear polarizer in front of each
pixel, in a pattern that repeats every few rows and columns. The default pattern is that of
Sony's IMX250MYR (and the cameras built on it): 2 × 2 blocks of polarizers
``[[90°, 45°], [135°, 0°]]``, each block under one colour filter, the colour blocks in an RGGB
Bayer order. One period is 4 × 4 pixels; **row 0, column 0 is the top-left pixel of the image as
stored in the file** (the first pixel of the first row)::

              col 0   col 1   col 2   col 3
    row 0     R 90    R 45    G 90    G 45
    row 1     R 135   R 0     G 135   G 0
    row 2     G 90    G 45    B 90    B 45
    row 3     G 135   G 0     B 135   B 0

Polarizer angles follow the project's convention (:mod:`thinfilm.core.conventions`): the
transmission axis measured from image +x (right) towards image +y (up), in degrees. A camera
whose datasheet measures angles the other way round (clockwise as displayed) has 45° and 135°
swapped with respect to ours: describe it with a pattern that swaps them.

Patterns are written two ways (:func:`parse_pattern`):

``BAYER:A1,A2,A3,A4``
    Colour blocks of 2 × 2 polarizers: ``BAYER`` is the order of the 2 × 2 colour blocks read
    row by row (``RGGB``, ``BGGR``, ``GRBG``, ``GBRG``), ``A1..A4`` the polarizer angles inside
    every block, row by row. The default is ``RGGB:90,45,135,0``.
``R90 R45 G90 G45 / R135 R0 G135 G0 / ...``
    Every cell of one period, row by row (rows separated by ``/`` or ``;``, cells by spaces or
    commas), each cell a colour letter and an angle in whole degrees.

Every colour must appear behind every polarizer angle, with at least three angles distinct
modulo 180° (so that S0, S1, S2 are determined). The sites of each (colour, angle) pair must
form one lattice per period or a checkerboard of two (as the green sites of a Bayer order do),
which :func:`thinfilm.importers.demosaic.demosaic` interpolates bilinearly.

Examples
--------
>>> p = parse_pattern(DEFAULT_PATTERN)
>>> p.shape, p.angles
((4, 4), (0, 45, 90, 135))
>>> p.cell(0, 0), p.cell(1, 1), p.cell(3, 2)
(('R', 90), ('R', 0), ('B', 135))
>>> parse_pattern("R90 R45 G90 G45 / R135 R0 G135 G0 / G90 G45 B90 B45 / G135 G0 B135 B0") == p
True
>>> import numpy as np
>>> images = {a: np.full((4, 4, 3), [1.0, 2.0, 3.0]) * (1 + a) for a in p.angles}
>>> mosaic_from_images(images, p)[0].tolist()    # R90, R45, G90, G45 of the top row
[91.0, 46.0, 182.0, 92.0]
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

from .errors import UserError

__all__ = ["COLOURS", "DEFAULT_PATTERN", "MosaicPattern", "parse_pattern", "mosaic_from_images"]

COLOURS = "RGB"
#: Sony IMX250MYR: polarizer blocks [[90, 45], [135, 0]] under an RGGB Bayer of 2 x 2 blocks.
DEFAULT_PATTERN = "RGGB:90,45,135,0"


@dataclass(frozen=True)
class MosaicPattern:
    """One period of a colour-polarization filter array.

    Attributes
    ----------
    colour : tuple of tuples of int
        (P, Q) colour index per cell: 0 red, 1 green, 2 blue.
    angle : tuple of tuples of int
        (P, Q) polarizer angle per cell, whole degrees in [0, 180).
    text : str
        The pattern as given (canonical for the default).
    """

    colour: tuple
    angle: tuple
    text: str = ""

    def __eq__(self, other):
        return isinstance(other, MosaicPattern) and (self.colour, self.angle) == (other.colour, other.angle)

    def __hash__(self):
        return hash((self.colour, self.angle))

    @property
    def shape(self) -> tuple:
        """(P, Q): rows and columns of one period."""
        return len(self.colour), len(self.colour[0])

    @property
    def angles(self) -> tuple:
        """The distinct polarizer angles, sorted."""
        return tuple(sorted({a for row in self.angle for a in row}))

    def cell(self, row: int, col: int) -> tuple:
        """(colour letter, angle) of the sensor pixel at ``row``, ``col`` (any image position)."""
        p, q = self.shape
        return COLOURS[self.colour[row % p][col % q]], self.angle[row % p][col % q]

    def lattices(self, colour: int, angle: int) -> list:
        """Offsets (row, col) inside the period of the cells with this colour and angle."""
        return [(r, c) for r, row in enumerate(self.colour) for c, k in enumerate(row)
                if k == colour and self.angle[r][c] == angle]

    def maps(self, shape) -> tuple:
        """(colour, angle) index images of a sensor of ``shape`` (H, W): which colour and which
        polarizer angle each pixel sees."""
        h, w = shape
        p, q = self.shape
        reps = (-(-h // p), -(-w // q))
        colour = np.tile(np.asarray(self.colour, dtype=np.int64), reps)[:h, :w]
        angle = np.tile(np.asarray(self.angle, dtype=np.int64), reps)[:h, :w]
        return colour, angle

    def diagram(self) -> str:
        """The period as text, one row per line (``R090 R045 ...``)."""
        return "\n".join(" ".join(f"{COLOURS[k]}{a:03d}" for k, a in zip(cr, ar))
                         for cr, ar in zip(self.colour, self.angle))


def _bad(where, text, why):
    raise UserError(f"{where}: {why}, got {text!r} (expected e.g. '{DEFAULT_PATTERN}', or every cell "
                    f"of one period as 'R90 R45 G90 G45 / R135 R0 G135 G0 / ...')")


def _angle(where, text, token):
    try:
        value = int(token)
    except ValueError:
        _bad(where, text, f"polarizer angle {token!r} is not a whole number of degrees")
    if not 0 <= value < 180:
        _bad(where, text, f"polarizer angle {value} is outside 0-179 degrees")
    return value


def parse_pattern(text: str, where: str = "--pattern") -> MosaicPattern:
    """Parse and check a pattern (see the module docstring). ``where`` names the source in
    errors (:class:`~thinfilm.core.errors.UserError`, one line)."""
    if not isinstance(text, str) or not text.strip():
        _bad(where, text, "empty pattern")
    s = text.strip().upper()
    m = re.fullmatch(r"([RGB]{4})\s*:\s*([0-9,\s]+)", s)
    if m:
        bayer = m.group(1)
        if sorted(bayer) != sorted("RGGB"):
            _bad(where, text, f"the Bayer order {bayer} must hold one R, two G and one B")
        tokens = [t for t in re.split(r"[,\s]+", m.group(2)) if t]
        if len(tokens) != 4:
            _bad(where, text, f"expected 4 polarizer angles for a 2 x 2 block, found {len(tokens)}")
        pol = [_angle(where, text, t) for t in tokens]
        colour = [[COLOURS.index(bayer[2 * (r // 2) + c // 2]) for c in range(4)] for r in range(4)]
        angle = [[pol[2 * (r % 2) + c % 2] for c in range(4)] for r in range(4)]
    else:
        rows = [r for r in re.split(r"[/;\n]", s) if r.strip()]
        colour, angle = [], []
        for row in rows:
            cells = [c for c in re.split(r"[,\s]+", row.strip()) if c]
            colour.append([])
            angle.append([])
            for cell in cells:
                cm = re.fullmatch(r"([RGB])\s*(\S+)", cell)
                if not cm:
                    _bad(where, text, f"cell {cell!r} is not a colour letter R, G or B followed by an angle")
                colour[-1].append(COLOURS.index(cm.group(1)))
                angle[-1].append(_angle(where, text, cm.group(2)))
        widths = {len(r) for r in colour}
        if len(widths) != 1:
            _bad(where, text, f"rows have different numbers of cells ({sorted(widths)})")
    pattern = MosaicPattern(tuple(map(tuple, colour)), tuple(map(tuple, angle)), text.strip())
    _check(pattern, where, text)
    return pattern


def _check(p: MosaicPattern, where, text):
    from .conventions import check_polarizer_angles

    angles = p.angles
    try:
        check_polarizer_angles(angles, where)
    except UserError:
        _bad(where, text, f"need at least 3 polarizer angles distinct modulo 180 degrees, the pattern has {list(angles)}")
    rows, cols = p.shape
    for k in range(3):
        for a in angles:
            cells = p.lattices(k, a)
            if not cells:
                _bad(where, text, f"colour {COLOURS[k]} never appears behind the {a} degree polarizer")
            if len(cells) == 1:
                continue
            (r0, c0), *rest = cells
            if (len(cells) == 2 and rows % 2 == 0 and cols % 2 == 0
                    and rest[0] == ((r0 + rows // 2) % rows, (c0 + cols // 2) % cols)):
                continue
            _bad(where, text, f"the {COLOURS[k]} {a} degree cells {cells} form neither one lattice nor a "
                              f"checkerboard of two")


def mosaic_from_images(images: dict, pattern: MosaicPattern) -> np.ndarray:
    """What a colour polarization sensor records of a scene: each pixel takes the value of the
    image of its polarizer angle in its colour channel.

    Parameters
    ----------
    images : dict
        angle (degrees) → (H, W, 3) camera RGB behind a polarizer at that angle; must hold
        every angle of the pattern.
    pattern : MosaicPattern

    Returns
    -------
    (H, W) float64
    """
    first = next(iter(images.values()))
    shape = np.shape(first)[:2]
    colour, angle = pattern.maps(shape)
    out = np.zeros(shape)
    for a in pattern.angles:
        if a not in images:
            raise ValueError(f"no image for polarizer angle {a}")
        sel = angle == a
        img = np.asarray(images[a], dtype=np.float64)
        out[sel] = np.take_along_axis(img, colour[..., None], axis=-1)[..., 0][sel]
    return out
