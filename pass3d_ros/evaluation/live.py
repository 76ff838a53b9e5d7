"""Live-path evaluation: a bag's clouds through both real nodes in one process, outputs matched by header stamp.

`run_live` (its steps in `LiveHarness`) starts ClusterProposalNode and SegmentationNode on a
SingleThreadedExecutor in a private rclpy context (its own DDS domain, so a real robot on the default domain
never sees the test traffic), publishes the bag's PointCloud2 CDR bytes unchanged on the cluster node's input
topic and listens to the labeled output (and, for per-stage times, to the proposals in between). Ground truth
comes from the bag's `label` field. `pass3d_ros.evaluation.report.score` turns a LiveResult into the dict
`pass3d_evaluate` writes as JSON.

Timing: latency = publish wall time -> receipt of /pass3d/labeled; stage1_ms = publish -> receipt of
/pass3d/proposals; stage2_ms = that receipt -> receipt of /pass3d/labeled. Each includes the DDS hop of
its output message, which is what a live consumer sees.
"""

from __future__ import annotations

import random
import struct
import threading
import time
from collections.abc import Callable, Iterator, Mapping
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from pass3d_ros.classes import IGNORE, NUM_CLASSES
from pass3d_ros.core.metrics import ConfusionAccumulator
from pass3d_ros.data.bag import TYPESTORE, BagWriter, count_frames, iter_raw, parse_bag_spec, select_topic
from pass3d_ros.msgs.pointcloud2 import POINTCLOUD2_TYPE, PointCloud2Error, decode, finite_mask, header_stamp_ns

NODE_NAMES: tuple[str, ...] = ("cluster_proposal_node", "segmentation_node")
DISCOVERY_TIMEOUT_S = 15.0
SETTLE_S = 0.3  # after matching: the subscriber side of discovery may finish a moment later
QUIET_S = 1.0  # at the end, both nodes idle and no output for this long: nothing more will come
FRAME_GAP_NS = 100_000_000  # replay spacing between passes of a one-message bag (10 Hz)


class LiveEvalError(RuntimeError):
    """The live run could not start (discovery) or its bag is unusable; the message says which."""


@dataclass
class LiveFrame:
    """One output frame matched to its input."""

    index: int  # position of the input in the replay: pass x bag messages + position in the bag's topic
    stamp_ns: int
    points: int  # finite input points
    latency_ms: float
    stage1_ms: float | None
    stage2_ms: float | None
    mismatch: bool  # output point count differs from the input's, or no label field
    truth: np.ndarray | None = None  # kept only with keep_labels
    predicted: np.ndarray | None = None  # kept only with keep_labels


@dataclass
class LiveResult:
    """What a live run published, what came back, and the accumulated point-wise confusion."""

    lockstep: bool
    rate: float
    frames_in: int = 0
    frames_out: int = 0
    mismatched: int = 0
    timeouts: int = 0  # lockstep: outputs not back within timeout_s (they may still arrive later)
    skipped: int = 0  # input frames not published: empty, undecodable, or not stamped after their predecessor
    unmatched_outputs: int = 0  # outputs whose stamp matches no pending input
    labeled_frames: int = 0  # output frames that entered the confusion matrix
    latency_ms: list[float] = field(default_factory=list)
    frames: list[LiveFrame] = field(default_factory=list)
    confusion: ConfusionAccumulator = field(default_factory=ConfusionAccumulator)
    node_counters: dict[str, dict[str, int]] = field(default_factory=dict)
    wall_s: float = 0.0
    record_out: Path | None = None

    @property
    def dropped(self) -> int:
        """Inputs without an output: dropped by a node's one-slot mailbox, lost in transport, or skipped by a node."""
        return self.frames_in - self.frames_out


@dataclass
class _Pending:
    index: int
    points: int
    truth: np.ndarray | None
    published: float = 0.0
    proposals_at: float | None = None


def cdr_stamp_ns(raw: bytes | memoryview) -> int:
    """Header stamp of a serialized message whose first field is a std_msgs/Header (PointCloud2 is)."""
    order = "<" if raw[1] == 1 else ">"  # CDR encapsulation: 0x0001 little endian, 0x0000 big endian
    sec, nanosec = struct.unpack_from(order + "iI", raw, 4)
    return sec * 1_000_000_000 + nanosec


def with_stamp(raw: bytes | memoryview, stamp_ns: int) -> bytes:
    """A copy of a serialized message whose first field is a std_msgs/Header, with a new header stamp."""
    order = "<" if raw[1] == 1 else ">"
    out = bytearray(raw)
    struct.pack_into(order + "iI", out, 4, *divmod(stamp_ns, 1_000_000_000))
    return bytes(out)


def _replay(path: Path, topic: str, repeat: int) -> Iterator[tuple[int, str, int, bytes]]:
    """(replay index, message type, bag time ns, CDR bytes) of the topic's messages, `repeat` times over.

    Pass k shifts the header stamps and bag times by k x (span of the topic + its mean message spacing,
    100 ms for a single message), so stamps keep increasing from pass to pass and the pace stays the bag's.
    """
    first: tuple[int, int] | None = None  # (header stamp, bag time) of the first message
    last: tuple[int, int] = (0, 0)
    count = index = 0
    shift = (0, 0)
    for lap in range(repeat):
        for conn, bag_ns, raw in iter_raw(path, topic):
            if lap == 0:
                try:
                    stamp = cdr_stamp_ns(raw)
                except (IndexError, struct.error):
                    stamp = last[0]
                if first is None:
                    first = (stamp, bag_ns)
                last, count = (stamp, bag_ns), count + 1
                yield index, conn.msgtype, bag_ns, raw
            else:
                try:
                    shifted = with_stamp(raw, cdr_stamp_ns(raw) + lap * shift[0])
                except (IndexError, struct.error):
                    shifted = bytes(raw)  # too short for a header: the consumer skips it as undecodable
                yield index, conn.msgtype, bag_ns + lap * shift[1], shifted
            index += 1
        if lap == 0:
            if first is None:
                return
            stamp_span, time_span = last[0] - first[0], last[1] - first[1]
            if count > 1:
                shift = (stamp_span + stamp_span // (count - 1), time_span + time_span // (count - 1))
            else:
                shift = (FRAME_GAP_NS, FRAME_GAP_NS)


def _input_frame(raw: bytes, msgtype: str) -> tuple[int, int, np.ndarray | None]:
    """(stamp, finite point count, ground-truth labels of the finite points or None) of one bag message."""
    msg = TYPESTORE.deserialize_cdr(raw, msgtype)
    cloud = decode(msg)
    keep = finite_mask(cloud)
    truth = None
    if "label" in (cloud.dtype.names or ()):
        truth = np.ascontiguousarray(cloud["label"][keep], dtype=np.uint8)
        bad = (truth >= NUM_CLASSES) & (truth != IGNORE)
        if bad.any():
            raise LiveEvalError(f"label field holds ids other than 0..{NUM_CLASSES - 1} or {IGNORE} (unknown)")
    return header_stamp_ns(msg), int(np.count_nonzero(keep)), truth


def _overrides(node_parameters: Mapping[str, Mapping[str, Any]] | None) -> dict[str, list]:
    """{node name: [rclpy Parameter]} from {node name: {parameter: value}}, node names checked."""
    from rclpy.parameter import Parameter

    unknown = sorted(set(node_parameters or {}) - set(NODE_NAMES))
    if unknown:
        raise ValueError(f"node_parameters: unknown node(s) {', '.join(unknown)}; nodes: {', '.join(NODE_NAMES)}")
    out: dict[str, list] = {}
    for name in NODE_NAMES:
        values = dict((node_parameters or {}).get(name, {}))
        out[name] = [Parameter(k, value=_plain(v)) for k, v in values.items()]
    return out


def _plain(value: Any) -> Any:
    """A value rclpy accepts: paths as str, tuples and arrays as lists, numpy scalars as Python numbers."""
    if isinstance(value, Path):
        return str(value)
    if isinstance(value, (tuple, np.ndarray)):
        return [_plain(v) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    return value


def _check_declared(node: Any, overrides: list) -> None:
    unknown = [p.name for p in overrides if not node.has_parameter(p.name)]
    if unknown:
        raise ValueError(f"{node.get_name()}: unknown parameter(s) {', '.join(unknown)}")


def _make_node(node_class: type, context: Any, overrides: list, nodes: list[Any]) -> Any:
    """Construct one node with its parameter overrides; a refused or unknown parameter is a ValueError."""
    from rclpy.exceptions import ParameterException

    try:
        node = node_class(context=context, parameter_overrides=overrides)
    except ParameterException as exc:
        raise ValueError(f"{node_class.__name__}: {exc}") from exc
    nodes.append(node)
    _check_declared(node, overrides)
    return node


def _wait(predicate: Callable[[], bool], timeout: float) -> bool:
    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() >= deadline:
            return False
        time.sleep(0.01)
    return True


class _Session:
    """Shared state of one run: pending inputs by stamp, matched outputs, the optional recording."""

    def __init__(self, result: LiveResult, keep_labels: bool, writer: BagWriter | None, labeled_topic: str) -> None:
        self.result = result
        self.keep_labels = keep_labels
        self.writer = writer
        self.labeled_topic = labeled_topic
        self.pending: dict[int, _Pending] = {}
        self.cond = threading.Condition()
        self.last_output = time.perf_counter()
        self.error: BaseException | None = None

    def on_proposals(self, raw: bytes) -> None:
        now = time.perf_counter()
        stamp = cdr_stamp_ns(raw)
        with self.cond:
            entry = self.pending.get(stamp)
            if entry is not None and entry.proposals_at is None:
                entry.proposals_at = now

    def on_labeled(self, raw: bytes) -> None:
        now = time.perf_counter()
        try:
            self._labeled(raw, now)
        except Exception as exc:  # an executor callback must not die; run_live re-raises it
            with self.cond:
                self.error = self.error or exc
                self.cond.notify_all()

    def _labeled(self, raw: bytes, now: float) -> None:
        stamp = cdr_stamp_ns(raw)
        if self.writer is not None:
            self.writer.write_raw(self.labeled_topic, POINTCLOUD2_TYPE, stamp, raw)
        with self.cond:
            entry = self.pending.get(stamp)
        if entry is None:
            with self.cond:
                self.result.unmatched_outputs += 1
                self.last_output = now
                self.cond.notify_all()
            return
        cloud = decode(TYPESTORE.deserialize_cdr(raw, POINTCLOUD2_TYPE))
        predicted = cloud["label"].astype(np.uint8) if "label" in (cloud.dtype.names or ()) else None
        mismatch = predicted is None or len(predicted) != entry.points
        frame = LiveFrame(
            index=entry.index,
            stamp_ns=stamp,
            points=entry.points,
            latency_ms=1e3 * (now - entry.published),
            stage1_ms=None if entry.proposals_at is None else 1e3 * (entry.proposals_at - entry.published),
            stage2_ms=None if entry.proposals_at is None else 1e3 * (now - entry.proposals_at),
            mismatch=mismatch,
        )
        if self.keep_labels:
            frame.truth, frame.predicted = entry.truth, predicted
        with self.cond:
            for older in [s for s in self.pending if s <= stamp]:  # outputs come in input order
                del self.pending[older]
            result = self.result
            result.frames_out += 1
            result.latency_ms.append(frame.latency_ms)
            result.frames.append(frame)
            if mismatch:
                result.mismatched += 1
            elif entry.truth is not None:
                result.confusion.update(entry.truth, predicted)
                result.labeled_frames += 1
            self.last_output = now
            self.cond.notify_all()


@dataclass
class LiveOptions:
    """How a live run plays its bag (see `run_live`)."""

    lockstep: bool = True
    rate: float = 1.0
    node_parameters: Mapping[str, Mapping[str, Any]] | None = None
    record_out: Path | None = None
    timeout_s: float = 30.0
    keep_labels: bool = True
    stage_timing: bool = True
    domain_id: int | None = None
    force: bool = False
    log_level: str | None = None
    progress: bool = False
    repeat: int = 1

    def check(self) -> None:
        """Refuse values that cannot run (ValueError naming the option)."""
        if self.rate < 0:
            raise ValueError(f"rate must be >= 0, got {self.rate}")
        if self.timeout_s <= 0:
            raise ValueError(f"timeout_s must be > 0, got {self.timeout_s}")
        if self.repeat < 1:
            raise ValueError(f"repeat must be >= 1, got {self.repeat}")
        if self.log_level is not None and self.log_level.lower() not in LOG_LEVELS:
            raise ValueError(f"log_level must be one of {', '.join(LOG_LEVELS)}, got {self.log_level!r}")


LOG_LEVELS: dict[str, str] = {"debug": "DEBUG", "info": "INFO", "warn": "WARN", "warning": "WARN", "error": "ERROR"}


def run_live(bag: str | Path, options: LiveOptions | None = None, **fields: Any) -> LiveResult:
    """Play `bag` (`PATH` or `PATH#/topic`) through both live nodes and collect what comes out.

    Options (a LiveOptions, or its fields as keywords): lockstep publishes the next frame only once the
    previous one's labeled output arrived or `timeout_s` passed (counted in `timeouts`); otherwise publish
    at `rate` x the recorded pace (0: as fast as possible) and wait at most `timeout_s` after the last
    publish for the outputs. `node_parameters` = {"cluster_proposal_node": {...}, "segmentation_node": {...}};
    unknown nodes or parameters are a ValueError, bad weights the node's own error. `record_out`: the
    received labeled messages as an MCAP bag (`force` replaces an existing one). keep_labels=False keeps
    per-frame records without label arrays (long soaks: the confusion matrix still accumulates).
    `domain_id` defaults to a random one in 100..200. `log_level` (debug, info, warn, error) sets both
    nodes' loggers for the rest of the process. `repeat` plays the bag that many times back to back (long
    runs from a short bag), every pass shifted in stamp and time by the bag's span plus one frame spacing
    so stamps keep increasing.
    """
    options = LiveOptions(**fields) if options is None else replace(options, **fields)
    harness = LiveHarness(bag, options)
    try:
        harness.start()
        harness.play()
        harness.drain()
    except BaseException:
        harness.stop(complete=False)
        raise
    harness.stop(complete=True)
    return harness.result


class LiveHarness:
    """One live run in steps: `start` (private context, both nodes, discovery), `play` (publish the bag),
    `drain` (wait for the last outputs, read the node counters), `stop` (tear down, close the recording)."""

    def __init__(self, bag: str | Path, options: LiveOptions) -> None:
        options.check()
        self.options = options
        self.bag = bag
        self.path, topic = parse_bag_spec(bag)
        self.topic = select_topic(self.path, topic)
        self.overrides = _overrides(options.node_parameters)
        self.result = LiveResult(lockstep=options.lockstep, rate=options.rate,
                                 record_out=Path(options.record_out) if options.record_out else None)
        self.writer = BagWriter(options.record_out, force=options.force) if options.record_out is not None else None
        self.nodes: list[Any] = []
        self.context: Any = None
        self.executor: Any = None
        self.spinner: threading.Thread | None = None
        self.session: _Session | None = None
        self.started = 0.0

    def start(self) -> None:
        """Both nodes and a probe node on a single-threaded executor in a private context, all discovered."""
        import rclpy
        from rclpy.context import Context
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.logging import LoggingSeverity, set_logger_level
        from sensor_msgs.msg import PointCloud2

        from pass3d_ros.ros.cluster_proposal_node import ClusterProposalNode
        from pass3d_ros.ros.qos import qos_profile
        from pass3d_ros.ros.segmentation_node import SegmentationNode

        options = self.options
        if options.log_level is not None:
            for name in NODE_NAMES:
                set_logger_level(name, LoggingSeverity[LOG_LEVELS[options.log_level.lower()]])
        self.context = Context()
        domain_id = random.randint(100, 200) if options.domain_id is None else options.domain_id
        rclpy.init(args=[], context=self.context, domain_id=domain_id)
        # Callbacks only hand frames to the nodes' worker threads. rclpy 7.1.6's MultiThreadedExecutor stalls on
        # long runs (ros2/rclpy#1452), so a single-threaded executor is both enough and reliable.
        self.executor = SingleThreadedExecutor(context=self.context)
        self.cluster = _make_node(ClusterProposalNode, self.context, self.overrides[NODE_NAMES[0]], self.nodes)
        self.segmenter = _make_node(SegmentationNode, self.context, self.overrides[NODE_NAMES[1]], self.nodes)
        probe = rclpy.create_node(f"pass3d_live_eval_{random.getrandbits(32):08x}", context=self.context)
        self.nodes.append(probe)
        labeled_topic = self.segmenter.get_parameter("labeled_topic").value
        if self.writer is not None:
            self.writer.open()
        self.session = _Session(self.result, options.keep_labels, self.writer, labeled_topic)
        output_qos = qos_profile(self.segmenter.get_parameter("output_qos").value, depth=50)
        labeled_sub = probe.create_subscription(PointCloud2, labeled_topic, self.session.on_labeled, output_qos,
                                                raw=True)
        if options.stage_timing:
            probe.create_subscription(
                PointCloud2,
                self.cluster.get_parameter("proposals_topic").value,
                self.session.on_proposals,
                qos_profile(self.cluster.get_parameter("output_qos").value, depth=50),
                raw=True,
            )
        self.publisher = probe.create_publisher(PointCloud2, self.cluster.get_parameter("input_topic").value,
                                                qos_profile("reliable", depth=10))
        for node in self.nodes:
            self.executor.add_node(node)
        self.spinner = threading.Thread(target=self.executor.spin, name="pass3d-live-eval", daemon=True)
        self.spinner.start()

        def connected() -> bool:
            return (
                self.publisher.get_subscription_count() >= 1
                and self.cluster.proposals_pub.get_subscription_count() >= 1 + int(options.stage_timing)
                and self.segmenter.labeled_pub.get_subscription_count() >= 1
                and labeled_sub.get_publisher_count() >= 1
            )

        if not _wait(connected, DISCOVERY_TIMEOUT_S):
            raise LiveEvalError(f"the nodes and the evaluator did not discover each other in {DISCOVERY_TIMEOUT_S} s")
        time.sleep(SETTLE_S)

    def play(self) -> None:
        """Publish every usable message of the bag (paced, or in lockstep with the outputs)."""
        from tqdm import tqdm

        options, result, session = self.options, self.result, self.session
        assert session is not None, "start() first"
        self.started = time.perf_counter()
        total = count_frames(self.bag)
        bar = tqdm(total=None if total is None else total * options.repeat, unit="frame", desc="live",
                   disable=not options.progress)
        pace_start, first_bag_ns, last_stamp = None, 0, None
        for index, msgtype, bag_ns, raw in _replay(self.path, self.topic, options.repeat):
            bar.update(1)
            try:
                stamp, points, truth = _input_frame(raw, msgtype)
            except LiveEvalError as exc:
                raise LiveEvalError(f"{self.path}#{self.topic}: message {index}: {exc}") from None
            except (PointCloud2Error, ValueError, IndexError, struct.error):
                result.skipped += 1  # the node would skip it too: nothing to wait for
                continue
            if points == 0 or (last_stamp is not None and stamp <= last_stamp):
                result.skipped += 1
                continue
            last_stamp = stamp
            if not options.lockstep and options.rate > 0:
                if pace_start is None:
                    pace_start, first_bag_ns = time.perf_counter(), bag_ns
                delay = pace_start + (bag_ns - first_bag_ns) / 1e9 / options.rate - time.perf_counter()
                if delay > 0:
                    time.sleep(delay)
            entry = _Pending(index, points, truth)
            with session.cond:
                if session.error is not None:
                    raise session.error
                session.pending[stamp] = entry
                result.frames_in += 1
                entry.published = time.perf_counter()
            self.publisher.publish(bytes(raw))
            if options.lockstep:
                with session.cond:
                    arrived = session.cond.wait_for(
                        lambda s=stamp: s not in session.pending or session.error is not None, options.timeout_s
                    )
                    if not arrived:
                        result.timeouts += 1
        bar.close()

    def drain(self) -> None:
        """Wait until every pending output came back or the nodes fell quiet; then take the node counters."""
        session, timeout_s = self.session, self.options.timeout_s
        assert session is not None, "start() first"

        def idle() -> bool:
            return self.cluster.worker.idle() and self.segmenter.worker.idle()

        def finished() -> bool:
            with session.cond:
                if not session.pending or session.error is not None:
                    return True
                quiet = time.perf_counter() - session.last_output >= QUIET_S
            return quiet and idle()

        _wait(finished, timeout_s)
        self.result.wall_s = time.perf_counter() - self.started
        _wait(idle, timeout_s)  # counters final
        if session.error is not None:
            raise session.error
        self.result.node_counters = {
            NODE_NAMES[0]: asdict(self.cluster.worker.counters),
            NODE_NAMES[1]: asdict(self.segmenter.worker.counters),
        }

    def stop(self, complete: bool) -> None:
        """Stop spinning, destroy the nodes (their workers join), shut the context down; then close the
        recording (`complete`) or abort it, so an unfinished run leaves no bag that looks complete."""
        import rclpy

        if self.executor is not None:
            self.executor.shutdown()
        if self.spinner is not None:
            self.spinner.join(timeout=5)
        for node in reversed(self.nodes):
            node.destroy_node()
        if self.context is not None:
            rclpy.try_shutdown(context=self.context)
        if self.writer is not None:
            if complete:
                self.writer.close()
            else:
                self.writer.abort()
