"""What adaptation reads from a recording about its sensor, as the nodes learn it from a stream: rings and their
resolution, the elevation span, the mounting (height and tilt), the intensity scale and map, the vehicle's own returns
(core/self_returns.py), and which simulated sensor of the synthetic world is closest (its labelled scans anchor the
fine-tune, and its unseen scenes guard it).
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Iterable
from dataclasses import asdict, dataclass

import numpy as np

from pass3d_ros.core.pipeline import ScanPipeline
from pass3d_ros.core.self_returns import SelfReturnReader, SelfReturns
from pass3d_ros.core.stage1 import Stage1Config
from pass3d_ros.core.stage1.lasers import LASER_TABLES
from pass3d_ros.core.stage1.ring import FIRING_ORDER_SOURCES, RING_SOURCES
from pass3d_ros.data.frame import Frame
from pass3d_ros.evaluation.offline import INTENSITY_MATCH, proposed_frame
from pass3d_ros.msgs.errors import UserError
from pass3d_ros.synthetic.sensor import SENSOR_NAMES, sensor_model

ELEVATION_PERCENTILES = (0.5, 99.5)  # the span of a scan's returns, robust to a few stray points
SPAN_SCALE_DEG = 5.0  # one unit of distance between sensors: 5 degrees of the lowest laser's elevation
TABLE_SPAN_TOLERANCE_DEG = 2.0  # a named laser table fits when its lowest laser lies this close to the measured one
FAR_DISTANCE = 1.0  # a signature distance beyond which the nearest simulated sensor is only the least unlike one
AUTO = "auto"  # no simulated sensor named: the nearest one is taken
SKY_ALLOWANCE_DEG = 8.0  # the top lasers may see only sky (no returns): the measured top may lie this far below
# Ring sources that count the sensor's lasers: all but elevation bins, which only guess the count.
COUNTED_SOURCES = tuple(source for source in RING_SOURCES if source != "elevation_bins")
# Ring sources a named laser table may help: not the firing order, which gives exact rings (a named table used to
# replace it in stage 1, which on KITTI's HDL-64E cost a third of the cars: docs/adapt.md).
TABLE_SOURCES = tuple(source for source in COUNTED_SOURCES if source not in FIRING_ORDER_SOURCES)


@dataclass(frozen=True)
class SensorReading:
    """The medians over a recording's scans of what stage 1 measured, and what they say about the sensor."""

    scans: int
    n_rings: int
    ring_source: str
    vertical_deg: float
    horizontal_deg: float
    top_deg: float
    bottom_deg: float
    nearest_simulated: str  # pass3d_ros.synthetic.sensor.SENSOR_NAMES: the nearest, or the one the user named
    distance: float  # between the two signatures (0: the same; over FAR_DISTANCE: no simulated sensor is close)
    laser_table: str  # a LASER_TABLES name whose rings and span fit (rings not from the firing order), else "auto"
    intensity_divisor: float  # the full scale the stream divides intensities by (1.0: already 0..1)
    mounting: dict | None
    intensity: dict
    simulated_named: bool = False  # the simulated sensor was named by the user (pass3d_adapt --sensor), not guessed
    constant_intensity: float | None = None  # the one intensity (0..1) every point of most scans reads (a driver or
    # conversion dropped it), None when the scans carry intensity
    self_returns: SelfReturns | None = None  # the vehicle's own returns the scans show (None: not looked for)

    @property
    def simulated_how(self) -> str:
        """How the simulated sensor was chosen, for logs and reports: "named" (--sensor) or "nearest"."""
        return "named" if self.simulated_named else "nearest"

    def to_dict(self) -> dict:
        """Plain values for reports."""
        return {**asdict(self), "simulated_how": self.simulated_how}


def _signature(n_rings: float, vertical: float, horizontal: float, bottom: float) -> np.ndarray:
    """Sensor features compared on log scales (rings, resolutions) and in SPAN_SCALE_DEG units (the lowest laser;
    not the top one, which often sees only sky); NaN where a feature is unknown."""
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.array([np.log2(n_rings), np.log2(vertical), np.log2(horizontal), bottom / SPAN_SCALE_DEG],
                        dtype=np.float64)


def simulated_signature(name: str) -> np.ndarray:
    """The signature of a simulated sensor, from its model (laser elevations, columns)."""
    model = sensor_model(name)
    elevations = np.sort(np.asarray(model.elevation_deg, dtype=np.float64))
    return _signature(len(elevations), float(np.median(np.diff(elevations))), 360.0 / model.columns,
                      float(elevations[0]))


def simulated_distances(n_rings: float, vertical: float, horizontal: float, bottom: float) -> dict[str, float]:
    """Each simulated sensor's signature distance (Euclidean, over the features known: NaN or a count of 0 leaves
    one out) to this one."""
    measured = _signature(n_rings if n_rings > 0 else np.nan, vertical, horizontal, bottom)
    finite = np.isfinite(measured)
    return {name: float(np.linalg.norm((simulated_signature(name) - measured)[finite])) for name in SENSOR_NAMES}


def nearest_simulated(n_rings: float, vertical: float, horizontal: float, bottom: float) -> tuple[str, float]:
    """The simulated sensor whose signature lies nearest to this one, and the distance."""
    distances = simulated_distances(n_rings, vertical, horizontal, bottom)
    name = min(distances, key=distances.get)
    return name, distances[name]


def fitting_table(n_rings: int, top: float, bottom: float) -> str:
    """The one named laser table with `n_rings` lasers whose lowest laser lies within TABLE_SPAN_TOLERANCE_DEG of
    the measured bottom and whose top laser lies above the measured top by at most SKY_ALLOWANCE_DEG (and not below
    it by more than the tolerance); "auto" when none or several fit: a table is a claim, so only on clear evidence."""
    fits = [name for name, table in LASER_TABLES.items()
            if len(table) == n_rings and abs(min(table) - bottom) <= TABLE_SPAN_TOLERANCE_DEG
            and -TABLE_SPAN_TOLERANCE_DEG <= max(table) - top <= SKY_ALLOWANCE_DEG]
    return fits[0] if len(fits) == 1 else "auto"


def read_sensor(frames: Iterable[tuple[str, Frame]], config: Stage1Config,
                intensity_match: bool = INTENSITY_MATCH, printed: set[str] | None = None,
                simulated: str = AUTO) -> SensorReading:
    """Stage 1 over the (spec, frame) pairs of one sensor, one stream state held across them as a node holds it;
    UserError when no scan has points. `printed`: input-check lines already printed (evaluation.offline.proposed_frame).
    `simulated`: a SENSOR_NAMES entry to take as the simulated sensor instead of the nearest (AUTO)."""
    pipeline = ScanPipeline(config, intensity_match=intensity_match)
    stream = pipeline.stream
    rings, sources, vertical, horizontal, tops, bottoms = [], Counter(), [], [], [], []
    constant: list[float] = []
    body = SelfReturnReader()
    specs: Counter[str] = Counter()  # scans read of each spec, for the error when none holds a point
    for spec, frame in frames:
        specs[spec] += 1
        proposed = proposed_frame(pipeline, spec, frame, printed=printed)
        scan, result = proposed.scan, proposed.result
        if proposed.empty:
            continue
        if any(note.topic == "intensity-constant" for note in scan.notes):
            constant.append(float(scan.points[0, 3]))
        body.add(scan.points, result.ground)
        xyz = scan.points[:, :3].astype(np.float64)
        elevation = np.degrees(np.arctan2(xyz[:, 2], np.hypot(xyz[:, 0], xyz[:, 1])))
        low, high = np.percentile(elevation, ELEVATION_PERCENTILES)
        tops.append(high)
        bottoms.append(low)
        sources[result.ring_source] += 1
        if result.sensor is not None:
            rings.append(result.sensor.n_rings)
            vertical.append(result.sensor.vertical_deg)
            horizontal.append(result.sensor.horizontal_deg)
    if not tops:
        read = ", ".join(f"{spec} ({count} scan(s) read)" for spec, count in specs.items())
        raise UserError(f"no scan of the recording holds a point: {read}; each was empty or had every point "
                        "dropped (the notes above say why)")
    n_rings = int(np.median(rings)) if rings else 0
    values = [float(np.nanmedian(v)) if np.isfinite(v).any() else float("nan") for v in (vertical, horizontal)] \
        if rings else [float("nan"), float("nan")]
    top, bottom = float(np.median(tops)), float(np.median(bottoms))
    source = sources.most_common(1)[0][0]
    counted = source in COUNTED_SOURCES  # elevation bins guess the ring count (their spacing may be read: unused)
    distances = simulated_distances(n_rings if counted else 0, values[0] if counted else np.nan, values[1], bottom)
    nearest = min(distances, key=distances.get) if simulated == AUTO else simulated
    return SensorReading(
        scans=len(tops), n_rings=n_rings, ring_source=source, vertical_deg=values[0],
        horizontal_deg=values[1], top_deg=top, bottom_deg=bottom, nearest_simulated=nearest,
        distance=distances[nearest], simulated_named=simulated != AUTO,
        constant_intensity=float(np.median(constant)) if 2 * len(constant) > len(tops) else None,
        laser_table=fitting_table(n_rings, top, bottom) if source in TABLE_SOURCES else "auto",
        intensity_divisor=float(stream.scale.divisor or 1.0),
        mounting=next(iter(stream.mountings.values()), None), intensity=dict(stream.maps), self_returns=body.read(),
    )
