"""A tiny 5x7 bitmap font, so the bird's-eye pictures can carry titles and labels without an imaging library."""

from __future__ import annotations

import numpy as np

GLYPH_W, GLYPH_H = 5, 9  # a character cell: 7 rows above the baseline, 2 for descenders
ADVANCE = GLYPH_W + 1  # one blank column between characters
DESCENDERS = "gpqy"  # their 7 rows start 2 rows lower, reaching below the baseline
# Each glyph: 7 rows top to bottom, two hex digits per row, bit 4 = leftmost column. Unknown characters draw "?".
_GLYPHS: dict[str, str] = {
    " ": "00000000000000", "?": "0e110102040004", "!": "04040404040004", ".": "00000000000c0c",
    ",": "000000000c0408", ":": "000c0c000c0c00", "-": "0000001f000000", "_": "0000000000001f",
    "/": "00010204081000", "(": "02040808080402", ")": "08040202020408", "%": "18190204081303",
    "=": "00001f001f0000", "+": "0004041f040400", "|": "04040404040404", "<": "02040810080402",
    ">": "08040201020408", "'": "04040800000000", "#": "0a0a1f0a1f0a0a", "*": "0004150e150400",
    "[": "0e08080808080e", "]": "0e02020202020e",
    "0": "0e11131519110e", "1": "040c040404040e", "2": "0e11010204081f", "3": "1f02040201110e",
    "4": "02060a121f0202", "5": "1f101e0101110e", "6": "0608101e11110e", "7": "1f010204080808",
    "8": "0e11110e11110e", "9": "0e11110f01020c",
    "A": "0e11111f111111", "B": "1e11111e11111e", "C": "0e11101010110e", "D": "1c12111111121c",
    "E": "1f10101e10101f", "F": "1f10101e101010", "G": "0e11101711110f", "H": "1111111f111111",
    "I": "0e04040404040e", "J": "0702020202120c", "K": "11121418141211", "L": "1010101010101f",
    "M": "111b1515111111", "N": "11111915131111", "O": "0e11111111110e", "P": "1e11111e101010",
    "Q": "0e11111115120d", "R": "1e11111e141211", "S": "0f10100e01011e", "T": "1f040404040404",
    "U": "1111111111110e", "V": "11111111110a04", "W": "1111111515150a", "X": "11110a040a1111",
    "Y": "11110a04040404", "Z": "1f01020408101f",
    "a": "00000e010f110f", "b": "1010161911111e", "c": "00000e1010110e", "d": "01010d1311110f",
    "e": "00000e111f100e", "f": "0609081c080808", "g": "0f1111110f010e", "h": "10101619111111",
    "i": "04000c0404040e", "j": "0200060202120c", "k": "10101214181412", "l": "0c04040404040e",
    "m": "00001a15151111", "n": "00001619111111", "o": "00000e1111110e", "p": "1e1111111e1010",
    "q": "0f1111110f0101", "r": "00001619101010", "s": "00000f100e011e", "t": "08081c08080906",
    "u": "0000111111130d", "v": "00001111110a04", "w": "0000111115150a", "x": "0000110a040a11",
    "y": "111111130d010e", "z": "00001f0204081f",
}
_BITS = 1 << np.arange(GLYPH_W - 1, -1, -1)


def _unpack(char: str, rows: str) -> np.ndarray:
    mask = np.zeros((GLYPH_H, GLYPH_W), dtype=bool)
    top = 2 if char in DESCENDERS else 0
    mask[top : top + 7] = (np.frombuffer(bytes.fromhex(rows), dtype=np.uint8)[:, None] & _BITS) > 0
    return mask


_MASKS: dict[str, np.ndarray] = {char: _unpack(char, rows) for char, rows in _GLYPHS.items()}


def glyph(char: str) -> np.ndarray:
    """The 9 x 5 boolean mask of one character ("?" for a character the font lacks)."""
    return _MASKS.get(char, _MASKS["?"])


def text_size(text: str, scale: int = 1) -> tuple[int, int]:
    """(height, width) in pixels of `text` drawn at `scale`."""
    return GLYPH_H * scale, max(len(text) * ADVANCE - 1, 0) * scale


def text_mask(text: str, scale: int = 1) -> np.ndarray:
    """Boolean mask of a line of text, each font pixel drawn as a `scale` x `scale` block."""
    mask = np.zeros((GLYPH_H, max(len(text) * ADVANCE - 1, 0)), dtype=bool)
    for k, char in enumerate(text):
        mask[:, k * ADVANCE : k * ADVANCE + GLYPH_W] = glyph(char)
    return np.kron(mask, np.ones((scale, scale), dtype=bool)) if scale > 1 else mask


def draw_text(image: np.ndarray, row: int, col: int, text: str, color: tuple[int, int, int] | np.ndarray,
              scale: int = 1, halo: tuple[int, int, int] | None = None) -> None:
    """Draw `text` into an H x W x 3 image with its top-left corner at (row, col), clipped at the edges; a `halo`
    colour outlines it by one pixel so it stays legible over points."""
    mask = text_mask(text, scale)
    if halo is not None:
        grown = np.zeros((mask.shape[0] + 2, mask.shape[1] + 2), dtype=bool)
        for dr in range(3):
            for dc in range(3):
                grown[dr : dr + mask.shape[0], dc : dc + mask.shape[1]] |= mask
        _paint(image, row - 1, col - 1, grown, halo)
    _paint(image, row, col, mask, color)


def _paint(image: np.ndarray, row: int, col: int, mask: np.ndarray, color: tuple[int, int, int] | np.ndarray) -> None:
    height, width = image.shape[:2]
    r0, c0 = max(row, 0), max(col, 0)
    r1, c1 = min(row + mask.shape[0], height), min(col + mask.shape[1], width)
    if r0 >= r1 or c0 >= c1:
        return
    image[r0:r1, c0:c1][mask[r0 - row : r1 - row, c0 - col : c1 - col]] = np.asarray(color, dtype=np.uint8)
