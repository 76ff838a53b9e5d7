"""Bird's-eye pictures: layout, class colours where the objects are, legend, boxes, text, and a PNG that decodes."""

from __future__ import annotations

import struct
import zlib
from pathlib import Path

import numpy as np
import pytest

from pass3d_ros.classes import BACKGROUND, CAR, CLASS_NAMES, CYCLIST, PEDESTRIAN
from pass3d_ros.drawing import bev
from pass3d_ros.drawing.font import GLYPH_H, draw_text, glyph, text_mask, text_size

HEIGHT = bev.TITLE_PX + bev.PANEL_PX + bev.LEGEND_PX
SCALE = bev.PANEL_PX / (2 * bev.EXTENT_M)
CAR_XY, PED_XY, CYC_XY = (12.0, 8.0), (-10.0, -6.0), (6.0, -15.0)


def outline(center: tuple[float, float], length: float, width: float, step: float = 0.05) -> np.ndarray:
    """Points along an axis-aligned rectangle's outline at z = 0.5 (what a LiDAR sees of an object's sides)."""
    cx, cy = center
    u = np.arange(-length / 2, length / 2 + 1e-9, step)
    v = np.arange(-width / 2, width / 2 + 1e-9, step)
    xy = np.concatenate([np.stack([u, np.full_like(u, -width / 2)], 1), np.stack([u, np.full_like(u, width / 2)], 1),
                         np.stack([np.full_like(v, -length / 2), v], 1), np.stack([np.full_like(v, length / 2), v], 1)])
    xy += (cx, cy)
    return np.column_stack([xy, np.full(len(xy), 0.5), np.full(len(xy), 0.3)]).astype(np.float32)


@pytest.fixture(scope="module")
def scene() -> tuple[np.ndarray, np.ndarray]:
    """A ground grid (background) with one car, one pedestrian and one cyclist."""
    g = np.arange(-30.0, 30.0, 1.0)
    gx, gy = np.meshgrid(g, g)
    ground = np.column_stack([gx.ravel(), gy.ravel(), np.full(gx.size, -1.7), np.full(gx.size, 0.1)])
    parts = [ground.astype(np.float32), outline(CAR_XY, 4.0, 1.8), outline(PED_XY, 0.6, 0.6),
             outline(CYC_XY, 1.8, 0.6)]
    labels = np.concatenate([np.full(len(p), cls, np.uint8)
                             for p, cls in zip(parts, (BACKGROUND, CAR, PEDESTRIAN, CYCLIST), strict=True)])
    return np.concatenate(parts), labels


def pixel(xy: tuple[float, float], panel: int = 0) -> tuple[int, int]:
    """Row and column of a sensor-frame x-y point in the figure's panel `panel`."""
    row = bev.TITLE_PX + (bev.EXTENT_M - xy[0]) * SCALE
    col = panel * (bev.PANEL_PX + bev.GAP_PX) + (bev.EXTENT_M - xy[1]) * SCALE
    return int(row), int(col)


def window(image: np.ndarray, center: tuple[int, int], half: int) -> np.ndarray:
    return image[center[0] - half : center[0] + half + 1, center[1] - half : center[1] + half + 1].reshape(-1, 3)


def has_color(pixels: np.ndarray, color: np.ndarray) -> int:
    return int(np.all(pixels.reshape(-1, 3) == color, axis=1).sum())


def test_two_panels_with_truth_one_without(scene: tuple[np.ndarray, np.ndarray]) -> None:
    points, labels = scene
    both = bev.frame_picture("000007", points, labels, truth=labels)
    assert both.shape == (HEIGHT, 2 * bev.PANEL_PX + bev.GAP_PX, 3) and both.dtype == np.uint8
    alone = bev.frame_picture("000007", points, labels)
    assert alone.shape == (HEIGHT, bev.PANEL_PX, 3)
    # The prediction panel of the pair is the lone panel, title band aside (both say "prediction  000007").
    right = both[:, bev.PANEL_PX + bev.GAP_PX :]
    np.testing.assert_array_equal(right[bev.TITLE_PX : bev.TITLE_PX + bev.PANEL_PX],
                                  alone[bev.TITLE_PX : bev.TITLE_PX + bev.PANEL_PX])


def test_objects_show_in_their_class_colour_in_both_panels(scene: tuple[np.ndarray, np.ndarray]) -> None:
    points, labels = scene
    missed = np.where(labels == CAR, BACKGROUND, labels).astype(np.uint8)  # the prediction misses the car
    image = bev.frame_picture("f", points, missed, truth=labels)
    for panel in (0, 1):
        for xy, cls in ((PED_XY, PEDESTRIAN), (CYC_XY, CYCLIST)):
            assert has_color(window(image, pixel(xy, panel), 8), bev.POINT_RGB[cls]) > 10, (panel, CLASS_NAMES[cls])
    assert has_color(window(image, pixel(CAR_XY, 0), 18), bev.POINT_RGB[CAR]) > 50, "truth panel (left) shows the car"
    assert has_color(window(image, pixel(CAR_XY, 1), 18), bev.POINT_RGB[CAR]) == 0, "prediction panel has no car"
    assert has_color(window(image, pixel(CAR_XY, 1), 18), bev.POINT_RGB[BACKGROUND]) > 50, "its points are background"


def test_legend_titles_rings_and_scale(scene: tuple[np.ndarray, np.ndarray]) -> None:
    points, labels = scene
    image = bev.frame_picture("000007", points, labels, truth=labels)
    legend = image[bev.TITLE_PX + bev.PANEL_PX :]
    for cls in range(len(CLASS_NAMES)):
        assert has_color(legend, bev.POINT_RGB[cls]) >= 100, f"swatch of {CLASS_NAMES[cls]}"
    assert has_color(legend, bev.TEXT_RGB) > 200, "class names"
    titles = image[: bev.TITLE_PX]
    left, right = titles[:, : bev.PANEL_PX], titles[:, bev.PANEL_PX + bev.GAP_PX :]
    title_left = text_mask("ground truth  000007", 2)
    assert has_color(left, bev.TEXT_RGB) == title_left.sum()
    assert has_color(right, bev.TEXT_RGB) == text_mask("prediction  000007", 2).sum()
    plot = image[bev.TITLE_PX : bev.TITLE_PX + bev.PANEL_PX, : bev.PANEL_PX]
    assert has_color(plot, bev.RING_RGB) > 4 * 2 * np.pi * 10 * SCALE, "at least 4 range rings of >= 10 m"
    assert has_color(plot, bev.RING_TEXT_RGB) > 0, "ring labels"
    bar_row = bev.PANEL_PX - 12
    assert has_color(plot[bar_row], bev.TEXT_RGB) == round(bev.RING_STEP_M * SCALE) + 1, "10 m scale bar"


def test_boxes_outline_objects(scene: tuple[np.ndarray, np.ndarray]) -> None:
    points, labels = scene
    image = bev.render_bev(points, labels)
    row, col = (int(v - bev.TITLE_PX * (k == 0)) for k, v in enumerate(pixel(CAR_XY)))
    # The car is 4 m x 1.8 m: 30 x 13.5 px; its outline runs a few pixels outside the point ring.
    around = image[row - 22 : row + 23, col - 12 : col + 13]
    inside = image[row - 12 : row + 13, col - 4 : col + 5]
    assert has_color(around, bev.BOX_RGB[CAR]) > 2 * (30 + 13), "the car's rectangle"
    assert has_color(inside, bev.BOX_RGB[CAR]) == 0, "an outline, not a fill"
    for xy, cls in ((PED_XY, PEDESTRIAN), (CYC_XY, CYCLIST)):
        r, c = int((bev.EXTENT_M - xy[0]) * SCALE), int((bev.EXTENT_M - xy[1]) * SCALE)
        assert has_color(image[r - 30 : r + 30, c - 40 : c + 40], bev.BOX_RGB[cls]) > 20, CLASS_NAMES[cls]
    background_only = bev.render_bev(points, np.zeros_like(labels))
    assert not any(has_color(background_only, bev.BOX_RGB[cls]) for cls in (CAR, PEDESTRIAN, CYCLIST))


def test_grouping_by_ids_or_touching_cells() -> None:
    a, b = outline((10.0, 0.0), 4.0, 1.8), outline((10.0, 2.5), 4.0, 1.8)  # two cars 0.7 m apart
    points = np.concatenate([a, b])
    labels = np.full(len(points), CAR, np.uint8)
    assert len(bev.objects(points, labels)) == 2, "a 0.7 m gap splits the grid components"
    joined = np.concatenate([a, outline((10.0, 1.95), 4.0, 1.8)])  # 0.15 m apart: one blob without ids
    assert len(bev.objects(joined, labels)) == 1
    ids = np.repeat([4, 9], [len(a), len(a)])
    found = bev.objects(joined, labels, ids)
    assert sorted(len(m) for _, m in found) == [len(a), len(a)] and {c for c, _ in found} == {CAR}
    mixed = labels.copy()
    mixed[: len(a) // 2] = PEDESTRIAN  # one proposal, two classes: a box per (id, class)
    assert sorted(c for c, _ in bev.objects(joined, mixed, ids)) == [CAR, CAR, PEDESTRIAN]
    few = bev.objects(points[:3], labels[:3])
    assert few == [], "fewer than MIN_BOX_POINTS points get no box"
    chain = np.column_stack([np.arange(0.0, 5.0, 0.25), np.zeros(20)])
    assert len(np.unique(bev.grid_components(chain))) == 1
    assert len(np.unique(bev.grid_components(np.concatenate([chain, chain + np.array([7.0, 0.0])])))) == 2


def test_text_renders_pixels() -> None:
    image = np.zeros((30, 120, 3), np.uint8)
    draw_text(image, 5, 4, "car 10 m", (255, 0, 0), halo=(0, 0, 255))
    assert has_color(image, np.array([255, 0, 0])) == text_mask("car 10 m").sum() > 20
    assert has_color(image, np.array([0, 0, 255])) > 0, "the halo"
    assert text_size("pedestrian", 2) == (2 * GLYPH_H, 2 * (10 * 6 - 1))
    assert text_mask("abc", 2).shape == text_size("abc", 2) and text_mask("abc", 2).sum() == 4 * text_mask("abc").sum()
    shapes = {ch: glyph(ch).tobytes() for ch in "ABCabc0123456789 m"}
    assert len(set(shapes.values())) == len(shapes), "every glyph differs"
    assert np.array_equal(glyph("~"), glyph("?")), "unknown characters draw '?'"
    assert glyph("g")[GLYPH_H - 1].any() and not glyph("a")[GLYPH_H - 1].any(), "descenders go below the baseline"
    edge = np.zeros((5, 5, 3), np.uint8)
    draw_text(edge, -3, -3, "W", (9, 9, 9))  # clipped, no error
    assert has_color(edge, np.array([9, 9, 9])) > 0


def test_png_round_trip(tmp_path: Path, scene: tuple[np.ndarray, np.ndarray]) -> None:
    points, labels = scene
    image = bev.frame_picture("000007", points, labels, truth=labels)
    path = tmp_path / "bev.png"
    bev.write_png(path, image)
    data = path.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    chunks, at = {}, 8
    while at < len(data):
        (length,) = struct.unpack(">I", data[at : at + 4])
        kind, payload = data[at + 4 : at + 8], data[at + 8 : at + 8 + length]
        assert struct.unpack(">I", data[at + 8 + length : at + 12 + length])[0] == zlib.crc32(kind + payload)
        chunks[kind] = chunks.get(kind, b"") + payload
        at += 12 + length
    width, height, depth, color_type = struct.unpack(">IIBB", chunks[b"IHDR"][:10])
    assert (width, height, depth, color_type) == (image.shape[1], image.shape[0], 8, 2) and b"IEND" in chunks
    rows = np.frombuffer(zlib.decompress(chunks[b"IDAT"]), np.uint8).reshape(height, 1 + 3 * width)
    assert not rows[:, 0].any(), "filter type 0 on every row"
    np.testing.assert_array_equal(rows[:, 1:].reshape(height, width, 3), image)
    assert len(data) < 150_000
