"""Bird's-eye-view PNGs of a labeled scan, written with zlib alone (no imaging dependency)."""

from __future__ import annotations

import struct
import zlib
from pathlib import Path

import numpy as np

from pass3d_ros.classes import BACKGROUND, CLASS_COLORS_RGB


def write_png(path: Path, image: np.ndarray) -> None:
    """Write an H x W x 3 uint8 image as an 8-bit RGB PNG."""
    image = np.ascontiguousarray(image, dtype=np.uint8)
    height, width, _ = image.shape
    raw = np.concatenate([np.zeros((height, 1), dtype=np.uint8), image.reshape(height, width * 3)], axis=1)

    def chunk(kind: bytes, payload: bytes) -> bytes:
        return struct.pack(">I", len(payload)) + kind + payload + struct.pack(">I", zlib.crc32(kind + payload))

    header = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    data = b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + chunk(b"IDAT", zlib.compress(raw.tobytes(), 6))
    Path(path).write_bytes(data + chunk(b"IEND", b""))


def render_bev(points: np.ndarray, labels: np.ndarray, extent_m: float = 40.0, pixels: int = 800) -> np.ndarray:
    """Top view, sensor at the centre, x up: background grey and dim, classes in the paper's colours."""
    finite = np.isfinite(points[:, :3]).all(axis=1)
    points, labels = points[finite], np.asarray(labels)[finite]
    scale = pixels / (2.0 * extent_m)
    col = ((points[:, 1] * -1.0 + extent_m) * scale).astype(np.int64)
    row = ((extent_m - points[:, 0]) * scale).astype(np.int64)
    inside = (col >= 0) & (col < pixels) & (row >= 0) & (row < pixels)
    image = np.full((pixels, pixels, 3), 16, dtype=np.uint8)
    labels = np.asarray(labels, dtype=np.intp)
    labels = np.where(labels < len(CLASS_COLORS_RGB), labels, BACKGROUND)
    order = np.argsort(labels[inside] != BACKGROUND, kind="stable")  # foreground drawn last, on top
    r, c, lab = row[inside][order], col[inside][order], labels[inside][order]
    colors = CLASS_COLORS_RGB[lab].copy()
    colors[lab == BACKGROUND] //= 2
    image[r, c] = colors
    fg = lab != BACKGROUND
    for dr, dc in ((0, 1), (1, 0), (1, 1)):  # fatten foreground points to 2x2 so small objects stay visible
        rr, cc = np.clip(r[fg] + dr, 0, pixels - 1), np.clip(c[fg] + dc, 0, pixels - 1)
        image[rr, cc] = colors[fg]
    return image
