"""Stage-2 training samples: stage-1 proposals of labelled frames, their points and per-point labels.

Stage 1 runs once per frame; the samples are cached as one npz file (in the training output folder) so
later epochs and runs skip it. A validation set also keeps every frame's full label array, so validation
scores the whole pipeline point by point (points outside every proposal count as background).
"""

from __future__ import annotations

import ast
import functools
import hashlib
import json
import zipfile
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from tqdm import tqdm

from pass3d_ros.classes import BACKGROUND, IGNORE, NUM_CLASSES
from pass3d_ros.core.pipeline import ScanPipeline
from pass3d_ros.core.stage1.config import Stage1Config
from pass3d_ros.core.stage2 import canonical
from pass3d_ros.core.stage2.pointnet2 import ModelConfig
from pass3d_ros.core.stage2.segmentation import prepare_proposals, uses_intensity
from pass3d_ros.data.frame import Frame
from pass3d_ros.data.spec import Dataset, DatasetError

CACHE_VERSION = 1
Proposer = Callable[[Frame], list[np.ndarray]]


def stage1_proposer(frame: Frame, pipeline: ScanPipeline) -> list[np.ndarray]:
    """Member indices (into `frame.points`) of the stage-1 proposals of a frame, through `pipeline`: the input checks
    and stage 1 with what its stream holds across the frames (laser lines, ring order, mounting), as a node runs
    them."""
    return pipeline.propose(frame.points, frame.ring).input_members()


@dataclass
class SampleSet:
    """P proposals: points (M, 4) float32 and labels (M,) uint8 of all members, proposal p at
    offsets[p]:offsets[p+1]; frame (P,) and point_index (M,) locate them in their frames."""

    points: np.ndarray
    labels: np.ndarray
    offsets: np.ndarray
    frame: np.ndarray
    point_index: np.ndarray
    frame_names: list[str]
    frame_sizes: np.ndarray
    frame_labels: np.ndarray | None = None  # (sum of frame sizes,) uint8, validation sets only
    _boxes: canonical.Boxes | None = None

    def __len__(self) -> int:
        return len(self.offsets) - 1

    @property
    def counts(self) -> np.ndarray:
        """Points per proposal (P,)."""
        return np.diff(self.offsets)

    @property
    def boxes(self) -> canonical.Boxes:
        """The fitted box of every proposal (computed once)."""
        if self._boxes is None:
            self._boxes = canonical.fit_boxes(self.points[:, :3], self.offsets)
        return self._boxes

    def members(self, ids: np.ndarray) -> list[np.ndarray]:
        """Index arrays into `points` of proposals `ids`."""
        return [np.arange(self.offsets[i], self.offsets[i + 1]) for i in ids]

    def proposal_class(self) -> np.ndarray:
        """Majority foreground label of each proposal (background if it has no foreground point) (P,)."""
        seg = np.repeat(np.arange(len(self)), self.counts)
        votes = np.bincount(seg * NUM_CLASSES + self.labels, minlength=len(self) * NUM_CLASSES)
        votes = votes.reshape(len(self), NUM_CLASSES)
        fg = votes[:, 1:]
        return np.where(fg.sum(1) > 0, 1 + fg.argmax(1), BACKGROUND)

    def frame_offsets(self) -> np.ndarray:
        """Start of each frame in frame_labels (F + 1,)."""
        return np.concatenate([[0], np.cumsum(self.frame_sizes)])

    def describe(self) -> dict:
        """Counts for checkpoints and logs."""
        return {
            "frames": len(self.frame_names),
            "proposals": len(self),
            "points": len(self.points),
            "proposals_per_class": np.bincount(self.proposal_class(), minlength=NUM_CLASSES).tolist(),
            "points_per_class": np.bincount(self.labels, minlength=NUM_CLASSES).tolist(),
        }

    @classmethod
    def concatenate(cls, parts: list[SampleSet]) -> SampleSet:
        """One set of all proposals and frames of `parts`, in order (frame ids renumbered)."""
        frame_base = np.cumsum([0] + [len(p.frame_sizes) for p in parts])
        point_base = np.cumsum([0] + [len(p.points) for p in parts])
        frame_labels = [p.frame_labels for p in parts if p.frame_labels is not None]  # None: no frames in a part
        return cls(
            points=np.concatenate([p.points for p in parts]),
            labels=np.concatenate([p.labels for p in parts]),
            offsets=np.concatenate(
                [[0]] + [p.offsets[1:] + b for p, b in zip(parts, point_base[:-1], strict=True)]
            ).astype(np.int64),
            frame=np.concatenate([p.frame + b for p, b in zip(parts, frame_base[:-1], strict=True)]).astype(np.int32),
            point_index=np.concatenate([p.point_index for p in parts]),
            frame_names=[n for p in parts for n in p.frame_names],
            frame_sizes=np.concatenate([p.frame_sizes for p in parts]).astype(np.int64),
            frame_labels=np.concatenate(frame_labels) if frame_labels else None,
        )

    def save(self, path: Path) -> None:
        """Write as one npz file."""
        arrays = {
            "points": self.points,
            "labels": self.labels,
            "offsets": self.offsets,
            "frame": self.frame,
            "point_index": self.point_index,
            "frame_names": np.array(self.frame_names, dtype=str),
            "frame_sizes": self.frame_sizes,
            "version": np.array(CACHE_VERSION),
        }
        if self.frame_labels is not None:
            arrays["frame_labels"] = self.frame_labels
        tmp = path.with_name(path.name + ".tmp.npz")
        np.savez_compressed(tmp, **arrays)
        tmp.replace(path)

    @classmethod
    def load(cls, path: Path) -> SampleSet:
        """Read a file written by save()."""
        with np.load(path) as data:
            if int(data["version"]) != CACHE_VERSION:
                raise ValueError(f"{path}: sample cache version {int(data['version'])}, expected {CACHE_VERSION}")
            return cls(
                points=data["points"],
                labels=data["labels"],
                offsets=data["offsets"],
                frame=data["frame"],
                point_index=data["point_index"],
                frame_names=[str(n) for n in data["frame_names"]],
                frame_sizes=data["frame_sizes"],
                frame_labels=data.get("frame_labels"),
            )


def build_samples(
    frames: Iterable[Frame],
    background_keep: float = 1.0,
    seed: int = 0,
    keep_frame_labels: bool = False,
    proposer: Proposer | None = None,
    progress: bool = True,
    total: int | None = None,
    shard: tuple[int, int] = (0, 1),
    stage1: Stage1Config | None = None,
) -> SampleSet:
    """Run the proposer (default: stage 1 with the `stage1` parameters) on every frame and collect its proposals; a
    proposal without any foreground point is kept with probability `background_keep` (seeded). shard=(i, n): only
    frames i, i + n, i + 2n, ... (still read in turn), with the background draws seeded by (seed, i)."""
    proposer = proposer or functools.partial(stage1_proposer, pipeline=ScanPipeline(stage1, intensity_match=False))
    index_in_shard, shards = shard
    rng = np.random.default_rng(seed if shards == 1 else [seed, index_in_shard])
    if shards > 1:
        frames = (frame for f, frame in enumerate(frames) if f % shards == index_in_shard)
        total = None if total is None else len(range(index_in_shard, total, shards))
    points, labels, index, counts, frame_ids = [], [], [], [], []
    names, sizes, frame_labels = [], [], []
    bar = tqdm(frames, desc="stage 1 proposals", unit="frame", disable=None if progress else True, total=total)
    for f, frame in enumerate(bar):
        if frame.labels is None:
            raise DatasetError(f"frame {frame.name}: no per-point labels, cannot train or validate on it")
        frame_label = np.asarray(frame.labels, dtype=np.uint8)
        names.append(frame.name)
        sizes.append(len(frame.points))
        if keep_frame_labels:
            frame_labels.append(frame_label)
        for member in proposer(frame):
            member = np.asarray(member, dtype=np.int64)
            if len(member) == 0:
                continue
            member_labels = frame_label[member]
            if np.any(member_labels == IGNORE):  # partly outside the annotated view: its labels are not known
                continue
            if not np.any(member_labels != BACKGROUND) and rng.random() >= background_keep:
                continue
            points.append(frame.points[member])
            labels.append(member_labels)
            index.append(member.astype(np.int32))
            counts.append(len(member))
            frame_ids.append(f)
    return SampleSet(
        points=np.concatenate(points).astype(np.float32) if points else np.zeros((0, 4), np.float32),
        labels=np.concatenate(labels).astype(np.uint8) if labels else np.zeros(0, np.uint8),
        offsets=np.concatenate([[0], np.cumsum(counts, dtype=np.int64)]).astype(np.int64),
        frame=np.asarray(frame_ids, dtype=np.int32),
        point_index=np.concatenate(index) if index else np.zeros(0, np.int32),
        frame_names=names,
        frame_sizes=np.asarray(sizes, dtype=np.int64),
        frame_labels=np.concatenate(frame_labels) if keep_frame_labels and frame_labels else None,
    )


def cache_key(specs: list[str], background_keep: float, seed: int, keep_frame_labels: bool, proposer: str) -> str:
    """Short hash naming a sample cache: the data specs, sampling settings, and the proposer's identity."""
    text = json.dumps([CACHE_VERSION, specs, background_keep, seed, keep_frame_labels, proposer])
    return hashlib.sha1(text.encode()).hexdigest()[:12]


# Every module of these, and all they import, can change the proposals: stage 1's steps, and what a stream holds across
# scans (laser lines, mounting), through which training samples are proposed (pass3d_ros.core.pipeline).
STAGE1_PACKAGES: tuple[str, ...] = ("pass3d_ros.core.stage1", "pass3d_ros.core.stream")
PACKAGE_ROOT = Path(__file__).resolve().parents[1]  # the pass3d_ros folder


def _imported_modules(path: Path) -> set[str]:
    """The pass3d_ros modules a source file imports (`import a.b`, `from a import b`: b may be a module)."""
    found: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            found.add(node.module)
            found.update(f"{node.module}.{alias.name}" for alias in node.names)
    return {name for name in found if name.split(".")[0] == "pass3d_ros"}


def package_modules(package: str, root: Path = PACKAGE_ROOT) -> list[str]:
    """The dotted names of every module in a pass3d_ros package folder (its __init__ included)."""
    folder = root.joinpath(*package.split(".")[1:])
    return [package + "".join(f".{part}" for part in path.relative_to(folder).with_suffix("").parts
                              if part != "__init__") for path in sorted(folder.rglob("*.py"))]


def source_closure(entries: list[str], root: Path = PACKAGE_ROOT) -> list[Path]:
    """The source files of modules `entries` and of every pass3d_ros module they import, directly or not (sorted):
    derived from the code, so a new or renamed stage-1 module is never left out of a cache's identity."""
    seen: dict[str, Path] = {}
    todo = list(entries)
    while todo:
        name = todo.pop()
        parts = name.split(".")[1:]
        candidates = [root.joinpath(*parts).with_suffix(".py"), root.joinpath(*parts, "__init__.py")]
        path = next((c for c in candidates if c.is_file()), None)
        if path is None or name in seen:
            continue
        seen[name] = path
        todo.extend(_imported_modules(path) - seen.keys())
    return sorted(seen.values())


def _digest(paths: list[Path]) -> str:
    """A short hash of the files' contents, in the order given, each prefixed by its length (so an edit to an empty
    file is not the same edit to the file after it)."""
    digest = hashlib.sha1()
    for path in paths:
        if path.is_file():
            data = path.read_bytes()
            digest.update(len(data).to_bytes(8, "little"))
            digest.update(data)
    return digest.hexdigest()[:12]


def stage1_identity(root: Path = PACKAGE_ROOT) -> str:
    """A hash of every source file stage 1 runs (`source_closure`), so a changed stage 1 rebuilds the caches."""
    files = source_closure([name for package in STAGE1_PACKAGES for name in package_modules(package, root)], root)
    return _digest(files)


def stage1_overrides(config: Stage1Config | None) -> dict:
    """The parameters of `config` that differ from the defaults (empty for None)."""
    if config is None:
        return {}
    defaults = Stage1Config().to_dict()
    return {k: v for k, v in config.to_dict().items() if v != defaults.get(k)}


def synthetic_identity() -> str:
    """A hash of the synthetic generator's source files, so a changed world rebuilds the caches of synthetic data."""
    root = Path(__file__).resolve().parents[1] / "synthetic"
    return _digest(sorted(root.rglob("*.py")))


def cache_path(
    specs: Sequence[str | Dataset], cache_dir: Path, background_keep: float, seed: int, keep_frame_labels: bool,
    proposer: Proposer | None = None, proposer_name: str | None = None, shards: int = 1,
    stage1: Stage1Config | None = None,
) -> Path:
    """The sample cache file of these settings; a set built in `shards` shards (data-parallel) has its own, and so
    does one built with other stage-1 parameters (`stage1`; the defaults keep the plain name)."""
    texts = [str(spec) for spec in specs]
    name = proposer_name or ("stage1-" + stage1_identity() if proposer is None else "custom")
    overrides = stage1_overrides(stage1)
    if overrides:
        name += "-params-" + json.dumps(overrides, sort_keys=True)
    if any(text.startswith("synthetic") for text in texts):
        name += "-world-" + synthetic_identity()
    if shards > 1:
        name += f"-shards{shards}"
    return Path(cache_dir) / f"samples_{cache_key(texts, background_keep, seed, keep_frame_labels, name)}.npz"


# what SampleSet.load raises on a file it cannot read (a cut-short .npz: BadZipFile, which is no ValueError)
READ_ERRORS = (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile)


def load_cached(path: Path) -> SampleSet | None:
    """The sample cache at `path`, or None when there is none or it cannot be read (then it is rebuilt)."""
    if not path.is_file():
        return None
    try:
        return SampleSet.load(path)
    except READ_ERRORS:
        return None


def cached_samples(
    specs: Sequence[str | Dataset],
    cache_dir: Path,
    frames: Callable[[Sequence[str | Dataset]], Iterable[Frame]],
    background_keep: float,
    seed: int,
    keep_frame_labels: bool,
    proposer: Proposer | None = None,
    proposer_name: str | None = None,
    rebuild: bool = False,
    progress: bool = True,
    total: int | None = None,
    stage1: Stage1Config | None = None,
) -> tuple[SampleSet, Path]:
    """The samples of `specs`, from the cache in `cache_dir` when present, else built (and cached); `stage1`: the
    stage-1 parameters of the default proposer."""
    path = cache_path(specs, cache_dir, background_keep, seed, keep_frame_labels, proposer, proposer_name,
                      stage1=stage1)
    loaded = None if rebuild else load_cached(path)
    if loaded is not None:
        return loaded, path
    samples = build_samples(frames(specs), background_keep, seed, keep_frame_labels, proposer, progress, total,
                            stage1=stage1)
    path.parent.mkdir(parents=True, exist_ok=True)
    samples.save(path)
    return samples, path


# Per-proposal intensity augmentation: sensors and surfaces differ in gain, offset and response, dark points read
# 0 anywhere, and some drivers give no intensity at all (the VLP-32C frames read a constant 1.0).
GAIN_RANGE = (0.6, 1.6)  # log-uniform
OFFSET_SIGMA = 0.04
GAMMA_RANGE = (0.7, 1.4)  # log-uniform
ZERO_PROB, ZERO_SHARE_MAX = 0.5, 0.5  # half the proposals lose up to half their points' intensity to 0
CONSTANT_PROB = 0.08  # the whole proposal reads one constant (1.0 half the time)


def augment_intensity(intensity: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Intensity (B, N) in [0, 1] after a random gain, offset and gamma per proposal, random zeroing of a share of
    its points, and now and then one constant for the whole proposal."""
    b = intensity.shape[0]
    gain = np.exp(rng.uniform(*np.log(GAIN_RANGE), b))[:, None]
    gamma = np.exp(rng.uniform(*np.log(GAMMA_RANGE), b))[:, None]
    offset = rng.normal(0.0, OFFSET_SIGMA, b)[:, None]
    out = np.clip(np.clip(intensity, 0.0, 1.0) ** gamma * gain + offset, 0.0, 1.0)
    share = np.where(rng.random(b) < ZERO_PROB, rng.uniform(0.0, ZERO_SHARE_MAX, b), 0.0)
    out[rng.random(intensity.shape) < share[:, None]] = 0.0
    constant = rng.random(b) < CONSTANT_PROB
    level = np.where(rng.random(b) < 0.5, 1.0, rng.uniform(0.0, 1.0, b))
    out[constant] = level[constant, None]
    return out.astype(intensity.dtype)


def training_batch(
    samples: SampleSet, ids: np.ndarray, config: ModelConfig, rng: np.random.Generator, augment: bool,
    intensity_augment: bool = False,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Network input of proposals `ids`: xyz (B, N, 3), features (B, N, 2), labels (B, N).

    augment: a random one of the 8 views per proposal; else the inference view (vertex nearest the sensor).
    intensity_augment: augment_intensity per proposal (not when the config feeds no intensity).
    The N points are a fresh random sample every time.
    """
    ids = np.asarray(ids, dtype=np.int64)
    all_boxes = samples.boxes
    boxes = canonical.Boxes(all_boxes.center[ids], all_boxes.size[ids], all_boxes.yaw[ids], all_boxes.zmin[ids])
    views = rng.integers(0, canonical.NUM_VIEWS, len(ids)) if augment else None
    batch = prepare_proposals(
        samples.points, samples.members(ids), config, views=views, rng=rng, boxes=boxes, queries=False
    )
    feat = batch.sample_feat
    if intensity_augment and uses_intensity(config):
        feat[:, :, 0] = augment_intensity(feat[:, :, 0], rng)
    return batch.sample_xyz, feat, samples.labels[batch.sample_index]
