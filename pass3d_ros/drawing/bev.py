"""Bird's-eye-view pictures of labeled scans, written as PNG with zlib alone (no imaging dependency).

One picture per frame: ground truth | prediction side by side (the prediction alone when there is no truth),
each panel titled, range rings every 10 m with labels, a 10 m scale bar, points in the class colours of
`pass3d_ros.classes` (foreground 3x3 pixels, background 1 pixel and dimmed), every object outlined by its
minimum-area rectangle with its class name, and a class legend along the bottom. Sensor at each panel's
centre, x (forward) up, y (left) to the left.
"""

from __future__ import annotations

import struct
import zlib
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pass3d_ros.classes import BACKGROUND, CLASS_COLORS_RGB, CLASS_NAMES, FOREGROUND, NUM_CLASSES
from pass3d_ros.core.stage2.canonical import fit_box_members, vertices
from pass3d_ros.data.bag import TYPESTORE, iter_raw, parse_bag_spec, select_topic
from pass3d_ros.drawing.font import draw_text, text_size
from pass3d_ros.msgs.pointcloud2 import decode

EXTENT_M = 40.0  # half the side of a panel in metres
PANEL_PX = 600  # panel side in pixels: 7.5 px per metre at 40 m
RING_STEP_M = 10.0
TITLE_PX = 24  # band above each panel
LEGEND_PX = 28  # band along the bottom
GAP_PX = 6  # between panels
GRID_CELL_M = 0.3  # cell of the connected-component grouping: points up to about 0.6 m apart join one object
MIN_BOX_POINTS = 5  # fewer same-class points get no box (stray points would clutter the picture)
BOX_MARGIN_PX = 2.5  # boxes sit this far outside the point centres so the 3x3 dots stay inside the outline

PLOT_RGB = np.array([16, 16, 16], dtype=np.uint8)
BAND_RGB = np.array([32, 32, 32], dtype=np.uint8)
TEXT_RGB = np.array([235, 235, 235], dtype=np.uint8)
RING_RGB = np.array([58, 58, 58], dtype=np.uint8)
RING_TEXT_RGB = np.array([140, 140, 140], dtype=np.uint8)
HALO_RGB = (0, 0, 0)
# What a point of each class looks like in the picture (background dimmed), and each class's box colour (lighter).
POINT_RGB: np.ndarray = CLASS_COLORS_RGB.copy()
POINT_RGB[BACKGROUND] = CLASS_COLORS_RGB[BACKGROUND] // 2
BOX_RGB: np.ndarray = ((CLASS_COLORS_RGB.astype(np.int64) + 255) // 2).astype(np.uint8)


@dataclass
class Panel:
    """One panel: its title, the scan's points (N x >=3), a class per point and, optionally, an object id per
    point (-1 none) that decides which points share a box."""

    title: str
    points: np.ndarray
    labels: np.ndarray
    groups: np.ndarray | None = None


def write_png(path: Path, image: np.ndarray) -> None:
    """Write an H x W x 3 uint8 image as an 8-bit RGB PNG."""
    image = np.ascontiguousarray(image, dtype=np.uint8)
    height, width, _ = image.shape
    raw = np.concatenate([np.zeros((height, 1), dtype=np.uint8), image.reshape(height, width * 3)], axis=1)

    def chunk(kind: bytes, payload: bytes) -> bytes:
        return struct.pack(">I", len(payload)) + kind + payload + struct.pack(">I", zlib.crc32(kind + payload))

    header = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    data = b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + chunk(b"IDAT", zlib.compress(raw.tobytes(), 9))
    Path(path).write_bytes(data + chunk(b"IEND", b""))


def grid_components(xy: np.ndarray, cell_m: float = GRID_CELL_M) -> np.ndarray:
    """Component id per point (0..K-1): points whose grid cells touch (8-neighbourhood) share one.

    Used for boxes where no object ids exist: it needs nothing but the points, is deterministic, and a gap
    wider than two cells (as between parked cars) splits objects, while scan-line gaps on one object do not.
    """
    xy = np.asarray(xy, dtype=np.float64)[:, :2]
    if len(xy) == 0:
        return np.zeros(0, dtype=np.int64)
    cells = np.floor(xy / cell_m).astype(np.int64)
    cells -= cells.min(axis=0) - 1
    unique, inverse = np.unique(cells, axis=0, return_inverse=True)
    stride = int(unique[:, 1].max()) + 2
    keys = unique[:, 0] * stride + unique[:, 1]  # sorted, as np.unique sorts rows lexicographically
    ends_a, ends_b = [], []
    for dx, dy in ((0, 1), (1, -1), (1, 0), (1, 1)):
        wanted = keys + dx * stride + dy
        at = np.minimum(np.searchsorted(keys, wanted), len(keys) - 1)
        hit = keys[at] == wanted
        ends_a.append(np.flatnonzero(hit))
        ends_b.append(at[hit])
    a, b = np.concatenate(ends_a), np.concatenate(ends_b)
    parent = np.arange(len(keys))
    while True:  # hook each edge onto the smaller root, then halve paths; ends when every edge is inside one root
        low = np.minimum(parent[a], parent[b])
        hooked = parent.copy()
        np.minimum.at(hooked, a, low)
        np.minimum.at(hooked, b, low)
        hooked = hooked[hooked]
        if np.array_equal(hooked, parent):
            break
        parent = hooked
    return np.unique(parent, return_inverse=True)[1].reshape(-1)[inverse.reshape(-1)]


def objects(points: np.ndarray, labels: np.ndarray, groups: np.ndarray | None = None,
            min_points: int = MIN_BOX_POINTS) -> list[tuple[int, np.ndarray]]:
    """(class, point indices) of every object: foreground points grouped by (group id, class); points without
    a group id (no `groups`, or -1) are grouped by `grid_components` within their class."""
    labels = np.asarray(labels)
    found: list[tuple[int, np.ndarray]] = []
    for cls in FOREGROUND:
        idx = np.flatnonzero(labels == cls)
        ids = np.full(len(idx), -1, dtype=np.int64) if groups is None else np.asarray(groups, np.int64)[idx]
        loose = ids < 0
        if loose.any():
            ids[loose] = grid_components(points[idx[loose], :2]) + (ids.max(initial=-1) + 1)
        order = np.argsort(ids, kind="stable")
        starts = np.flatnonzero(np.diff(ids[order], prepend=-2))
        for members in np.split(idx[order], starts[1:]):
            if len(members) >= min_points:
                found.append((cls, members))
    return found


class _Canvas:
    """A panel's plot area: metres to pixels, and the primitives drawn on it."""

    def __init__(self, extent_m: float, pixels: int) -> None:
        self.extent, self.pixels = extent_m, pixels
        self.scale = pixels / (2.0 * extent_m)
        self.image = np.empty((pixels, pixels, 3), dtype=np.uint8)
        self.image[:] = PLOT_RGB

    def to_pixel(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Float (row, col) of sensor-frame x-y points: x up, y left."""
        xy = np.asarray(xy, dtype=np.float64)
        return (self.extent - xy[..., 0]) * self.scale, (self.extent - xy[..., 1]) * self.scale

    def dots(self, rows: np.ndarray, cols: np.ndarray, color: np.ndarray, radius: int) -> None:
        for dr in range(-radius, radius + 1):
            for dc in range(-radius, radius + 1):
                r, c = rows + dr, cols + dc
                inside = (r >= 0) & (r < self.pixels) & (c >= 0) & (c < self.pixels)
                self.image[r[inside], c[inside]] = color if color.ndim == 1 else color[inside]

    def polyline(self, rows: np.ndarray, cols: np.ndarray, color: np.ndarray) -> None:
        """Straight segments between consecutive (row, col) vertices, sampled at half-pixel steps."""
        for r0, c0, r1, c1 in zip(rows[:-1], cols[:-1], rows[1:], cols[1:], strict=True):
            steps = int(np.ceil(2 * max(abs(r1 - r0), abs(c1 - c0)))) + 1
            t = np.linspace(0.0, 1.0, steps)
            self.dots(np.round(r0 + t * (r1 - r0)).astype(np.int64), np.round(c0 + t * (c1 - c0)).astype(np.int64),
                      color, 0)


def render_bev(points: np.ndarray, labels: np.ndarray, groups: np.ndarray | None = None,
               extent_m: float = EXTENT_M, pixels: int = PANEL_PX) -> np.ndarray:
    """One panel's plot (pixels x pixels x 3): range rings, points by class, object boxes with class names."""
    points = np.asarray(points)
    labels = np.asarray(labels).astype(np.intp)
    finite = np.isfinite(points[:, :3]).all(axis=1)
    labels = np.where(labels < NUM_CLASSES, labels, BACKGROUND)
    canvas = _Canvas(extent_m, pixels)
    _rings(canvas)

    rows, cols = canvas.to_pixel(np.where(finite[:, None], points[:, :2], 1e9))
    rows, cols = np.floor(rows).astype(np.int64), np.floor(cols).astype(np.int64)
    background = finite & (labels == BACKGROUND)
    canvas.dots(rows[background], cols[background], POINT_RGB[BACKGROUND], 0)
    for cls in FOREGROUND:
        mine = finite & (labels == cls)
        canvas.dots(rows[mine], cols[mine], POINT_RGB[cls], 1)
    _sensor(canvas)

    found = objects(points[finite], labels[finite], None if groups is None else np.asarray(groups)[finite])
    if found:
        corners = _box_corners(points[finite], [members for _, members in found], BOX_MARGIN_PX / canvas.scale)
        texts = []
        for (cls, _), box in zip(found, corners, strict=True):
            r, c = canvas.to_pixel(box)
            canvas.polyline(np.append(r, r[0]), np.append(c, c[0]), BOX_RGB[cls])
            texts.append((cls, r, c))
        taken: list[tuple[int, int, int, int]] = []
        for cls, r, c in texts:  # names after all outlines, so no outline crosses a name
            row, col = _place_name(CLASS_NAMES[cls], r, c, taken, canvas.pixels)
            draw_text(canvas.image, row, col, CLASS_NAMES[cls], BOX_RGB[cls], halo=HALO_RGB)
    _scale_bar(canvas)
    return canvas.image


def _place_name(name: str, rows: np.ndarray, cols: np.ndarray, taken: list[tuple[int, int, int, int]],
                pixels: int) -> tuple[int, int]:
    """Top-left of a box's name: above the box, else below it, else left or right of it, whichever first lies
    inside the panel and overlaps no name placed before (above when none does); the choice is added to `taken`."""
    height, width = text_size(name)
    top, bottom, left, right = (int(v) for v in (np.floor(rows.min()), np.ceil(rows.max()),
                                                  np.floor(cols.min()), np.ceil(cols.max())))
    middle_row, middle_col = (top + bottom) // 2 - height // 2, (left + right) // 2 - width // 2
    candidates = [(top - height - 2, middle_col), (bottom + 3, middle_col),
                  (middle_row, left - width - 3), (middle_row, right + 3)]
    for row, col in candidates:
        box = (row - 1, col - 4, row + height + 1, col + width + 4)  # names at least 8 pixels apart side by side
        inside = box[0] >= 0 and box[1] >= 0 and box[2] <= pixels and box[3] <= pixels
        if inside and not any(box[0] < t[2] and t[0] < box[2] and box[1] < t[3] and t[1] < box[3] for t in taken):
            break
    else:
        row, col = candidates[0]
    taken.append((row - 1, col - 4, row + height + 1, col + width + 4))
    return row, col


def _box_corners(points: np.ndarray, members: list[np.ndarray], margin_m: float) -> np.ndarray:
    """(P, 4, 2) x-y corners of each group's minimal-area rectangle, grown by `margin_m` on every side."""
    boxes = fit_box_members(points[:, :3].astype(np.float64), members)
    boxes.size[:, :2] += 2 * margin_m
    return vertices(boxes)


def _rings(canvas: _Canvas) -> None:
    radii = np.arange(RING_STEP_M, canvas.extent + 1e-6, RING_STEP_M)
    for radius in radii:
        angles = np.linspace(0.0, 2 * np.pi, int(np.ceil(4 * np.pi * radius * canvas.scale)), endpoint=False)
        r, c = canvas.to_pixel(np.stack([radius * np.cos(angles), radius * np.sin(angles)], axis=1))
        canvas.dots(np.round(r).astype(np.int64), np.round(c).astype(np.int64), RING_RGB, 0)
    for radius in radii:  # labels on the forward-right diagonal, just outside each ring
        r, c = canvas.to_pixel(np.array([radius, -radius]) * np.sqrt(0.5))
        draw_text(canvas.image, int(r) - 9, int(c) + 3, f"{radius:.0f} m", RING_TEXT_RGB)


def _sensor(canvas: _Canvas) -> None:
    """A small white triangle at the sensor, pointing forward (up)."""
    r, c = (int(v) for v in canvas.to_pixel(np.zeros(2)))
    for k in range(5):
        canvas.dots(np.full(2 * k + 1, r - 2 + k), np.arange(c - k, c + k + 1), TEXT_RGB, 0)


def _scale_bar(canvas: _Canvas) -> None:
    """A ring step long bar with end ticks in the bottom-right corner."""
    length = round(RING_STEP_M * canvas.scale)
    row, right = canvas.pixels - 12, canvas.pixels - 12
    canvas.image[row, right - length : right + 1] = TEXT_RGB
    canvas.image[row - 4 : row + 1, right - length] = TEXT_RGB
    canvas.image[row - 4 : row + 1, right] = TEXT_RGB
    label = f"{RING_STEP_M:.0f} m"
    height, width = text_size(label)
    draw_text(canvas.image, row - height - 4, right - length // 2 - width // 2, label, TEXT_RGB)


def render_figure(panels: Sequence[Panel], extent_m: float = EXTENT_M, panel_px: int = PANEL_PX) -> np.ndarray:
    """Panels side by side, each under its title band, above one class legend; returns H x W x 3 uint8."""
    if not panels:
        raise ValueError("render_figure needs at least one panel")
    width = len(panels) * panel_px + (len(panels) - 1) * GAP_PX
    image = np.empty((TITLE_PX + panel_px + LEGEND_PX, width, 3), dtype=np.uint8)
    image[:] = BAND_RGB
    for k, panel in enumerate(panels):
        left = k * (panel_px + GAP_PX)
        image[TITLE_PX : TITLE_PX + panel_px, left : left + panel_px] = render_bev(
            panel.points, panel.labels, panel.groups, extent_m, panel_px)
        title = panel.title[: max((panel_px - 12) // 12, 1)]
        draw_text(image, (TITLE_PX - text_size(title, 2)[0]) // 2, left + 6, title, TEXT_RGB, scale=2)
    _legend(image, TITLE_PX + panel_px)
    return image


def _legend(image: np.ndarray, top: int) -> None:
    """Colour swatch and name of every class, left to right, in the band that starts at row `top`."""
    col, swatch = 8, 12
    middle = top + LEGEND_PX // 2
    for cls, name in enumerate(CLASS_NAMES):
        image[middle - swatch // 2 : middle + swatch // 2, col : col + swatch] = POINT_RGB[cls]
        col += swatch + 6
        height, width = text_size(name, 2)
        draw_text(image, middle - height // 2, col, name, TEXT_RGB, scale=2)
        col += width + 20


def frame_picture(name: str, points: np.ndarray, predicted: np.ndarray, cluster_id: np.ndarray | None = None,
                  truth: np.ndarray | None = None, instance: np.ndarray | None = None,
                  truth_points: np.ndarray | None = None) -> np.ndarray:
    """The picture of one frame: "ground truth" | "prediction" panels (the prediction alone without `truth`);
    `truth_points` are the truth's points when they are not `points` (e.g. read from another bag).

    Predicted boxes group points by (cluster_id, class), so each shows what one proposal became; truth boxes
    group by (instance, class) when the frame has instances, else by touching grid cells (`grid_components`).
    """
    panels = [Panel(f"prediction  {name}", points, predicted, cluster_id)]
    if truth is not None:
        panels.insert(0, Panel(f"ground truth  {name}", points if truth_points is None else truth_points, truth,
                               instance))
    return render_figure(panels)


def output_cluster_ids(bag: str | Path) -> Iterator[np.ndarray | None]:
    """Per-point `cluster_id` of every cloud of a pass3d output bag, in bag order (None for a cloud without the
    field): the proposals behind the predicted boxes, which a Frame does not carry."""
    path, topic = parse_bag_spec(bag)
    topic = select_topic(path, topic)
    for conn, _, raw in iter_raw(path, topic):
        cloud = decode(TYPESTORE.deserialize_cdr(raw, conn.msgtype))
        yield np.asarray(cloud["cluster_id"], dtype=np.int64) if "cluster_id" in (cloud.dtype.names or ()) else None
