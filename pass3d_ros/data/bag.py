"""rosbag2 bags (sqlite3 or MCAP) through `rosbags`: the `bag:PATH[#TOPIC]` reader and a safe writer.

Reading: `bag:PATH` yields one Frame per PointCloud2 message of the bag's only PointCloud2 topic;
`bag:PATH#/topic` picks one when there are several (an error lists them otherwise). Points keep their
order and NaNs; intensity comes from `intensity` / `i` / `reflectance` as stored (no rescaling), ring when
present, stamp from the header, name = message index (6 digits).

Ground truth lives in its own field, `label_gt` (`pass3d_kitti2bag --with-labels` writes it), because the
pipeline's output clouds carry their predictions in `label`: scoring an output bag against its own `label`
would report 100 % IoU. A legacy `label` field counts as ground truth only in a cloud that is not a pass3d
output (none of `confidence`, `rgb`, `cluster_id`); in an output it is ignored with a warning, unless the
caller asks for the predictions (`read_bag(PATH, labels="predicted")`).

Writing: `BagWriter` builds the bag in a hidden sibling folder (`.NAME.partial-XXXX`) and renames it into
place only when complete, so an interrupted or failed write leaves nothing that looks like a bag. A build
folder whose writer is gone (killed with SIGKILL, power loss) is removed by the next write of the same bag. With
force it replaces only a bag it can open (or an empty folder), never the working folder, an input or a folder above
one (pass3d_ros.data.outputs); a recorder whose disk filled up can still keep what it wrote (`keep_written`).
"""

from __future__ import annotations

import contextlib
import os
import shutil
import sys
import tempfile
import time
from collections.abc import Callable, Collection, Iterable, Iterator
from pathlib import Path
from types import TracebackType
from typing import Any, Literal

import numpy as np
from rosbags.interfaces import Connection
from rosbags.rosbag2 import Reader, StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore

from pass3d_ros.classes import IGNORE, foreign_ids
from pass3d_ros.data.frame import Frame
from pass3d_ros.data.outputs import check_force, refuse_protected, writing
from pass3d_ros.data.partials import partial_prefix, process_gone, remove_stale
from pass3d_ros.msgs.errors import DatasetError, UserError
from pass3d_ros.msgs.pointcloud2 import (
    POINTCLOUD2_TYPE,
    PointCloud2Error,
    decode,
    header_stamp_ns,
    stamp_to_ns,
    to_xyzi,
)

TYPESTORE = get_typestore(Stores.ROS2_JAZZY)
STORAGES: dict[str, StoragePlugin] = {"mcap": StoragePlugin.MCAP, "sqlite3": StoragePlugin.SQLITE3}
VERSIONS: tuple[int, ...] = (9, 8)  # 9: Jazzy's format; 8: what Humble reads
OWNER_FILE = ".owner"  # in a build folder: the id of the process writing it
OWNERLESS_GRACE_S = 60.0  # a build folder without an owner file is taken as stale only after this long
LABEL_FIELD = "label"  # a pass3d output's predicted class per point (legacy bags: ground truth)
TRUTH_FIELD = "label_gt"  # ground truth per point in a bag
OUTPUT_FIELDS: tuple[str, ...] = ("confidence", "rgb", "cluster_id")  # fields only pass3d outputs carry
LabelSource = Literal["truth", "predicted"]


class BagError(UserError):
    """A bag cannot be written (exists, bad option, ...); the message names the path and the problem."""


def topic_name_problem(name: str) -> str | None:
    """What makes `name` an invalid ROS 2 topic name (the rules of rcl's topic name check), or None when it is
    valid: it starts with `/`, `~`, `_` or a letter, holds only letters, digits and `_/~{}`, has no `//`, no trailing
    `/`, no token starting with a digit, `~` only first (followed by `/`) and braces only in matched pairs."""
    if not name:
        return "it is empty"
    if not (name[0] in "/~_" or (name[0].isascii() and name[0].isalpha())):
        return "it must start with '/', '~', '_' or a letter"
    bad = sorted({c for c in name if not (c.isascii() and (c.isalnum() or c in "_/~{}"))})
    if bad:
        return f"it holds {''.join(bad)!r}; only letters, digits and _ / ~ {{ }} are allowed"
    if "//" in name:
        return "it holds '//'"
    if name.endswith("/"):
        return "it ends with '/'"
    if "~" in name[1:] or (name.startswith("~") and len(name) > 1 and name[1] != "/"):
        return "'~' may only come first, followed by '/'"
    depth = 0
    for char in name:
        depth += {"{": 1, "}": -1}.get(char, 0)
        if depth not in (0, 1):
            return "its braces do not pair up"
    if depth:
        return "its braces do not pair up"
    if any(token[:1].isdigit() for token in name.split("/")):
        return "a part of it starts with a digit"
    return None


def parse_bag_spec(text: str | Path) -> tuple[Path, str | None]:
    """`PATH` or `PATH#/topic` -> (path, topic or None)."""
    path, sep, topic = str(text).partition("#")
    if sep and not topic:
        raise DatasetError(f"bag spec {text!r}: empty topic after '#'")
    if topic and not topic.startswith("/"):
        topic = "/" + topic
    return Path(path), topic or None


def _open_reader(path: Path) -> Reader:
    try:
        reader = Reader(path)
        reader.open()
    except Exception as exc:  # rosbags raises FileNotFoundError, ReaderError, yaml and sqlite errors
        why = " ".join(str(exc).split())  # a YAML error spans lines (with a caret line): the tools print one
        raise DatasetError(f"{path}: cannot open as a rosbag2 bag ({why})") from exc
    return reader


def _type_counts(reader: Reader, msgtype: str) -> dict[str, int]:
    counts: dict[str, int] = {}
    for conn in reader.connections:
        if conn.msgtype == msgtype:
            counts[conn.topic] = counts.get(conn.topic, 0) + conn.msgcount
    return counts


def _contents(reader: Reader) -> str:
    """What the bag holds, for an error message: `topic (type), ...` or `no topics`."""
    types = {conn.topic: conn.msgtype for conn in reader.connections}
    return ", ".join(f"{topic} ({types[topic]})" for topic in sorted(types)) or "no topics"


def _select(reader: Reader, path: Path, topic: str | None, msgtype: str) -> str:
    counts = _type_counts(reader, msgtype)
    if topic is not None:
        if topic not in counts:
            raise DatasetError(f"{path}: no {msgtype} topic {topic!r}; the bag has {_contents(reader)}")
        return topic
    if not counts:
        raise DatasetError(f"{path}: no {msgtype} topic; the bag has {_contents(reader)}")
    if len(counts) != 1:
        listing = ", ".join(sorted(counts))
        raise DatasetError(f"{path}: {len(counts)} {msgtype} topics ({listing}); choose one with bag:PATH#/topic")
    return next(iter(counts))


def topic_types(path: Path) -> dict[str, str]:
    """Topic -> message type of every topic in the bag."""
    reader = _open_reader(path)
    try:
        return {conn.topic: conn.msgtype for conn in reader.connections}
    finally:
        reader.close()


def topics_of_type(path: Path, msgtype: str = POINTCLOUD2_TYPE) -> dict[str, int]:
    """Topic -> message count of the bag's topics of `msgtype`."""
    reader = _open_reader(path)
    try:
        return _type_counts(reader, msgtype)
    finally:
        reader.close()


def select_topic(path: Path, topic: str | None, msgtype: str = POINTCLOUD2_TYPE) -> str:
    """`topic` if the bag has it with `msgtype`, else the bag's only topic of that type; DatasetError otherwise
    (listing what the bag has: every topic and its type when none fits)."""
    reader = _open_reader(path)
    try:
        return _select(reader, path, topic, msgtype)
    finally:
        reader.close()


def _all_read(messages: Iterable[tuple[Connection, int, bytes]], expected: int, where: str
              ) -> Iterator[tuple[Connection, int, bytes]]:
    """`messages`, then a DatasetError naming `where` when fewer came than the `expected` its metadata lists: rosbags
    skips a corrupt record of an MCAP file without a word, which would otherwise read as a shorter bag."""
    got = 0
    for message in messages:
        got += 1
        yield message
    if got < expected:
        raise DatasetError(f"{where}: only {got} of the {expected} messages its metadata lists could be read "
                           "(the storage file is corrupt or truncated)")


def iter_raw(path: Path, topic: str) -> Iterator[tuple[Connection, int, bytes]]:
    """(connection, bag time ns, CDR bytes) of every message on `topic`, in bag order; DatasetError after the last
    when fewer read back than the metadata lists."""
    reader = _open_reader(path)
    try:
        connections = [conn for conn in reader.connections if conn.topic == topic]
        expected = sum(conn.msgcount for conn in connections)
        yield from _all_read(reader.messages(connections=connections), expected, f"{path}#{topic}")
    finally:
        reader.close()


class BagFile:
    """A bag opened once (`PATH` or `PATH#/topic`): its topic of `msgtype` chosen as `select_topic` does, the
    message count from its metadata, and its messages, as many passes as asked. Close it (or use `with`)."""

    def __init__(self, spec: str | Path, msgtype: str = POINTCLOUD2_TYPE) -> None:
        self.path, topic = parse_bag_spec(spec)
        self._reader = _open_reader(self.path)
        try:
            self.topic = _select(self._reader, self.path, topic, msgtype)
        except BaseException:
            self._reader.close()
            raise
        self._connections = [conn for conn in self._reader.connections if conn.topic == self.topic]
        self.count = sum(conn.msgcount for conn in self._connections)

    def __str__(self) -> str:
        return f"{self.path}#{self.topic}"

    def messages(self) -> Iterator[tuple[Connection, int, bytes]]:
        """(connection, bag time ns, CDR bytes) of every message on the topic, in bag order; DatasetError after the
        last when fewer read back than the metadata lists."""
        return _all_read(self._reader.messages(connections=self._connections), self.count, str(self))

    def close(self) -> None:
        """Release the file; closing twice is harmless."""
        if self._reader.is_open:
            self._reader.close()

    def __enter__(self) -> BagFile:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()


def is_output_cloud(names: Collection[str]) -> bool:
    """Whether a cloud with these field names is a pass3d output (its `label` is a prediction)."""
    return any(name in names for name in OUTPUT_FIELDS)


def truth_field(names: Collection[str]) -> str | None:
    """The field holding ground truth: `label_gt`, else a legacy `label` of a cloud that is not a pass3d
    output; None when there is none."""
    if TRUTH_FIELD in names:
        return TRUTH_FIELD
    if LABEL_FIELD in names and not is_output_cloud(names):
        return LABEL_FIELD
    return None


def message_stamp_ns(msgtype: str, raw: bytes | memoryview) -> int:
    """The header stamp of a serialized message (a MarkerArray: its first marker's), 0 when there is none."""
    msg = TYPESTORE.deserialize_cdr(bytes(raw), msgtype)
    header = getattr(msg, "header", None)
    if header is None and getattr(msg, "markers", None):
        header = msg.markers[0].header
    return stamp_to_ns(header.stamp) if header is not None else 0


def cloud_to_frame(name: str, msg: Any, labels: LabelSource = "truth") -> Frame:
    """A Frame from a PointCloud2 (rclpy or rosbags): points in order, NaNs kept, ring when present; labels
    from the ground-truth field (`truth`, see `truth_field`) or from an output's `label` (`predicted`)."""
    cloud = decode(msg)
    xyzi = to_xyzi(cloud)
    names = cloud.dtype.names or ()
    field = truth_field(names) if labels == "truth" else LABEL_FIELD if LABEL_FIELD in names else None
    values = label_values(cloud, field) if field is not None else None
    return Frame(name=name, points=xyzi.points, stamp_ns=header_stamp_ns(msg), ring=xyzi.ring, labels=values)


def label_values(cloud: np.ndarray, field: str) -> np.ndarray:
    """A label field as uint8 class ids; a value uint8 cannot hold (negative, past 255, fractional, NaN) makes the
    message malformed (PointCloud2Error), never another class (a cast read 257 as car)."""
    column = cloud[field]
    with np.errstate(invalid="ignore"):
        labels = column.astype(np.uint8)
    if not np.can_cast(column.dtype, np.uint8, "safe"):
        bad = labels != column
        if bad.any():
            raise PointCloud2Error(f"field {field!r} holds {column[bad][0]}, expected class ids (uint8)")
    return labels


def read_bag(path: str | Path, labels: LabelSource = "truth") -> Iterator[Frame]:
    """Frames of a bag's PointCloud2 topic (`PATH` or `PATH#/topic`), in bag order; `labels` as in
    `cloud_to_frame` (an output bag read for truth has none, and says so once on stderr)."""
    if labels not in ("truth", "predicted"):
        raise ValueError(f"labels must be 'truth' or 'predicted', got {labels!r}")
    return _frames(BagFile(path), labels)


def _frames(bag: BagFile, labels: LabelSource = "truth") -> Iterator[Frame]:
    try:
        for index, (conn, _, raw) in enumerate(bag.messages()):
            yield _message_frame(bag, index, conn.msgtype, raw, labels)
    finally:
        bag.close()


def _message_frame(bag: BagFile, index: int, msgtype: str, raw: bytes, labels: LabelSource) -> Frame:
    try:
        msg = TYPESTORE.deserialize_cdr(raw, msgtype)
    except Exception as exc:  # truncated or foreign CDR surfaces as struct, index or value errors
        raise DatasetError(f"{bag}: message {index} does not deserialize: {exc}") from exc
    try:
        frame = cloud_to_frame(f"{index:06d}", msg, labels)
    except PointCloud2Error as exc:
        raise DatasetError(f"{bag}: message {index}: {exc}") from exc
    if frame.labels is not None:
        _check_class_ids(bag, index, frame.labels)
    if index == 0 and labels == "truth" and frame.labels is None:
        names = {field.name for field in msg.fields}
        if LABEL_FIELD in names and is_output_cloud(names):
            _to_stderr(f"warning: {bag} holds pass3d outputs: their `{LABEL_FIELD}` field is the "
                       f"prediction, not ground truth, so these frames have no labels (ground truth goes in "
                       f"`{TRUTH_FIELD}`)")
    return frame


def _check_class_ids(bag: BagFile, index: int, labels: np.ndarray) -> None:
    """DatasetError naming the bag and message when its labels hold ids that are no class of this package (e.g. a
    label_gt field of another scheme's ids, or corrupt data), which scoring would otherwise meet as a bug."""
    wrong = foreign_ids(labels)
    if wrong.size:
        shown = ", ".join(str(int(v)) for v in wrong[:5]) + (" ..." if wrong.size > 5 else "")
        raise DatasetError(f"{bag}: message {index}: labels {shown} are no class id (0 background, 1 car, "
                           f"2 pedestrian, 3 cyclist, {IGNORE} ignore)")


def first_frame(bag: BagFile, labels: LabelSource = "truth") -> Frame | None:
    """The first frame of an open bag (None when its topic is empty); the bag stays open."""
    for conn, _, raw in bag.messages():
        return _message_frame(bag, 0, conn.msgtype, raw, labels)
    return None


def count_frames(path: str | Path) -> int | None:
    """Message count of the chosen PointCloud2 topic, from the bag's metadata."""
    try:
        with BagFile(path) as bag:
            return bag.count
    except DatasetError:
        return None


def check_bag_target(out: Path, *, force: bool, inputs: Iterable[str | Path] = (), what: str = "--out") -> None:
    """Refuse a bag output no writer may touch; an existing one needs `force`, and then must be a bag (or empty).
    BagWriter checks it when made; a tool that makes its writer only later (after discovery) calls it first."""
    refuse_protected(out, inputs, what)
    if not (out.exists() or out.is_symlink()):
        return
    if not force:
        raise BagError(f"{out} exists; pass --force to overwrite it")
    check_force(out, ours=is_bag, kind="a bag", inputs=inputs, what=what)


class BagWriter:
    """A rosbag2 writer that builds the bag in a hidden sibling and renames it into place on `close`.

    In a `with`, any exception (Ctrl-C included) removes everything written.
    """

    def __init__(self, out: str | Path, *, storage: str = "mcap", version: int = 9, force: bool = False,
                 log: Callable[[str], None] | None = None, inputs: Iterable[str | Path] = (),
                 what: str = "--out") -> None:
        self.out = Path(out)
        if self.out.name in ("", ".", ".."):  # `.`, `x/..`: name the folder itself, so the build sibling has a name
            self.out = self.out.resolve()
        self.inputs, self.what = tuple(inputs), what
        self.log = log if log is not None else _to_stderr
        if storage not in STORAGES:
            raise BagError(f"unknown storage {storage!r}, expected one of {', '.join(STORAGES)}")
        if version not in VERSIONS:
            raise BagError(f"unsupported rosbag2 version {version}, expected 9 (Jazzy) or 8 (Humble)")
        self.storage, self.version, self.force = storage, version, force
        self._check_target()
        self.counts: dict[str, int] = {}
        self._tmp: Path | None = None
        self._writer: Writer | None = None
        self._connections: dict[str, Connection] = {}

    def _check_target(self) -> None:
        check_bag_target(self.out, force=self.force, inputs=self.inputs, what=self.what)

    @property
    def temporary_path(self) -> Path | None:
        """Where the bag is being built, while open."""
        return self._tmp

    def open(self) -> BagWriter:
        """Create the hidden build folder and open the rosbags writer in it."""
        self.out.parent.mkdir(parents=True, exist_ok=True)
        remove_stale(self.out, lambda p: p.is_dir() and _is_stale(p), self.log, "unfinished build folder(s)")
        self._tmp = Path(tempfile.mkdtemp(prefix=partial_prefix(self.out), dir=self.out.parent))
        try:
            (self._tmp / OWNER_FILE).write_text(f"{os.getpid()}\n")
            plugin = STORAGES[self.storage]
            self._writer = Writer(self._tmp / self.out.name, version=self.version, storage_plugin=plugin)
            self._writer.open()
        except BaseException:
            self.abort()
            raise
        return self

    def write_raw(self, topic: str, msgtype: str, stamp_ns: int, data: bytes | memoryview) -> None:
        """Append one CDR-serialized message at bag time `stamp_ns`."""
        if self._writer is None:
            raise BagError(f"{self.out}: writer is not open")
        conn = self._connections.get(topic)
        if conn is None:
            if msgtype not in TYPESTORE.types:
                raise BagError(f"{self.out}: message type {msgtype!r} unknown to the ROS 2 Jazzy typestore")
            conn = self._writer.add_connection(topic, msgtype, typestore=TYPESTORE)
            self._connections[topic] = conn
        elif conn.msgtype != msgtype:
            raise BagError(f"{self.out}: topic {topic} already holds {conn.msgtype}, not {msgtype}")
        with writing(self.out):
            self._writer.write(conn, int(stamp_ns), data)
        self.counts[topic] = self.counts.get(topic, 0) + 1

    def write(self, topic: str, msg: Any, stamp_ns: int) -> None:
        """Serialize a rosbags message and append it."""
        self.write_raw(topic, msg.__msgtype__, stamp_ns, TYPESTORE.serialize_cdr(msg, msg.__msgtype__))

    def close(self) -> Path:
        """Finish the bag and move it to `out` (replacing an old one only with force); returns `out`."""
        if self._writer is None or self._tmp is None:
            raise BagError(f"{self.out}: writer is not open")
        try:
            with writing(self.out):
                self._writer.close()
            self._writer = None
            self._move_into_place()
        except BaseException:
            self.abort()
            raise
        return self.out

    def keep_written(self) -> tuple[Path, int] | None:
        """After a failed write (a full disk): finish the bag with the messages written before and move it into
        place when it reads back whole; (its path, its message count), or None with everything removed."""
        if self._writer is None or self._tmp is None or not any(self.counts.values()):
            self.abort()
            return None
        try:
            with contextlib.suppress(Exception):  # the storage may have been left mid-record: closing tries
                self._writer.close()
            self._writer = None
            count = _readable_messages(self._tmp / self.out.name)
            if count < sum(self.counts.values()):
                raise BagError(f"{self.out}: only {count} of the messages written read back")
            self._move_into_place()
        except Exception:
            self.abort()
            return None
        return self.out, count

    def _move_into_place(self) -> None:
        """Rename the finished bag to `out`, setting an old one (force) aside and removing it once replaced."""
        assert self._tmp is not None
        self._check_target()
        replaced = None
        if self.out.exists() or self.out.is_symlink():
            replaced = self._tmp / ".replaced"
            self.out.rename(replaced)
        try:
            (self._tmp / self.out.name).rename(self.out)
        except BaseException:
            if replaced is not None:
                replaced.rename(self.out)
            raise
        shutil.rmtree(self._tmp, ignore_errors=True)
        self._tmp = None

    def abort(self) -> None:
        """Drop everything written so far; nothing is left at `out` or beside it."""
        writer, self._writer = self._writer, None
        if writer is not None:
            # the storage may already be broken; removing the folder is what matters
            with contextlib.suppress(Exception):
                writer.abort()
        if self._tmp is not None:
            shutil.rmtree(self._tmp, ignore_errors=True)
            self._tmp = None

    def __enter__(self) -> BagWriter:
        return self.open()

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()


def is_bag(path: Path) -> bool:
    """Whether `path` is a rosbag2 bag this package can open (what --force may replace)."""
    if not path.is_dir() or path.is_symlink():
        return False
    try:
        reader = Reader(path)
        reader.open()
    except Exception:  # rosbags raises FileNotFoundError, ReaderError, yaml and sqlite errors
        return False
    reader.close()
    return True


def _readable_messages(path: Path) -> int:
    """How many messages of the bag at `path` read back; any error reading it propagates."""
    reader = Reader(path)
    reader.open()
    try:
        return sum(1 for _ in reader.messages())
    finally:
        reader.close()


def _to_stderr(text: str) -> None:
    print(text, file=sys.stderr)


def _is_stale(partial: Path) -> bool:
    """Whether the writer of a build folder is gone: its recorded process is dead, or it has no owner file
    and is older than the grace period (a writer between creating the folder and recording itself)."""
    try:
        pid = int((partial / OWNER_FILE).read_text().strip())
    except (OSError, ValueError):
        try:
            return time.time() - partial.stat().st_mtime > OWNERLESS_GRACE_S
        except OSError:
            return False
    return process_gone(pid)
