"""`pass3d_benchmark fuzz`: corrupted PointCloud2 messages against the codec, each checked against an independent
restatement of its rules: every message decodes to exactly what its bytes say, or raises PointCloud2Error.

Layouts are random (shuffled fields, gaps, tail padding, organized rows, either byte order), then mutated (offsets,
datatypes, counts, names, steps, sizes, truncated data, wrong types). The suite reports how many decoded and how
many were rejected, and any disagreement (exit 1). The test suite runs a smaller seeded share of the same.
"""

from __future__ import annotations

import argparse
import array
import sys
import time

import numpy as np
from rosbags.typesys import Stores, get_typestore

from pass3d_ros.msgs.errors import UserError
from pass3d_ros.msgs.pointcloud2 import DATATYPES, PointCloud2Error, decode
from pass3d_ros.tools.cli import number

TYPESTORE = get_typestore(Stores.ROS2_JAZZY)
EXTRA_NAMES = ["intensity", "ring", "t", "label", "extra", "i"]
SCALAR = {"x", "y", "z", "ring", "intensity", "i", "reflectance", "cluster_id", "cluster_id2", "label"}


def random_message(rng: np.random.Generator) -> tuple:
    """A valid random layout: shuffled fields, gaps, tail padding, organized rows, either byte order."""
    names = ["x", "y", "z", *rng.choice(EXTRA_NAMES, rng.integers(0, 4), replace=False)]
    fields, offset = [], 0
    for name in names:
        code = int(rng.choice([7, 8])) if name in "xyz" and rng.random() < 0.8 else int(rng.integers(1, 9))
        count = 1 if name in SCALAR else int(rng.integers(1, 4))
        offset += int(rng.integers(0, 3))
        fields.append([name, offset, code, count])
        offset += DATATYPES[code].itemsize * count
    order = rng.permutation(len(fields))
    fields = [fields[k] for k in order]
    step = offset + int(rng.integers(0, 4))
    height, width = int(rng.integers(1, 4)), int(rng.integers(0, 6))
    row_step = width * step + (int(rng.integers(0, 6)) if rng.random() < 0.4 else 0)
    data = rng.integers(0, 256, height * row_step, dtype=np.uint8).tobytes()
    return fields, step, data, height, width, row_step, bool(rng.random() < 0.3)


def _shift(value: object, delta: int, floor: int) -> object:
    """value + delta, not below floor; a value an earlier mutation made junk (not a plain int) stays as it is."""
    return max(floor, value + delta) if isinstance(value, int) and not isinstance(value, bool) else value


def mutate(rng: np.random.Generator, parts: tuple) -> tuple:
    """One random corruption of a message's layout or data (any field, step, size, byte order, or a junk type)."""
    fields, step, data, height, width, row_step, big = parts
    if not fields:
        return parts
    fields = [list(f) for f in fields]
    kind = int(rng.integers(0, 13))
    k = int(rng.integers(0, len(fields)))
    if kind == 0:
        fields[k][1] = _shift(fields[k][1], int(rng.integers(-4, 5)), -2)
    elif kind == 1:
        fields[k][2] = int(rng.integers(-1, 11))
    elif kind == 2:
        fields[k][3] = int(rng.integers(0, 4))
    elif kind == 3:
        fields[k][0] = str(rng.choice(["", "xx", fields[int(rng.integers(0, len(fields)))][0]]))
    elif kind == 4:
        del fields[k]
    elif kind == 5:
        fields.append(list(fields[k]))
    elif kind == 6:
        step = _shift(step, int(rng.integers(-3, 4)), -1) if rng.random() < 0.8 else 0
    elif kind == 7:
        row_step = _shift(row_step, int(rng.integers(-5, 6)), 0)
    elif kind == 8:
        height = _shift(height, int(rng.choice([-1, 1])), 0)
    elif kind == 9:
        width = _shift(width, int(rng.choice([-1, 1])), 0)
    elif kind == 10:
        cut = int(rng.integers(-6, 7))
        data = data[:cut] if cut < 0 else data + bytes(cut)
    elif kind == 11:
        big = not big
    else:
        junk = [None, 2.5, "4", True][int(rng.integers(0, 4))]
        target = int(rng.integers(0, 7))
        if target < 3:
            fields[k][1 + target] = junk
        else:
            step, row_step, height, width = [
                junk if t == target else v for t, v in zip((3, 4, 5, 6), (step, row_step, height, width), strict=True)
            ]
    return fields, step, data, height, width, row_step, big


def expected_valid(fields: list, step: object, data: bytes, height: object, width: object, row_step: object) -> bool:
    """The codec's documented rules, restated independently."""
    numbers = [step, height, width, row_step, *(value for f in fields for value in f[1:])]
    if any(isinstance(v, bool) or not isinstance(v, int) for v in numbers):
        return False
    if step <= 0 or row_step < width * step or len(data) != height * row_step:
        return False
    spans, names = [], []
    for name, offset, code, count in fields:
        if code not in DATATYPES or count < 1 or offset < 0:
            return False
        end = offset + DATATYPES[code].itemsize * count
        if end > step or (name in SCALAR and count != 1):
            return False
        spans.append((offset, end))
        if name:
            names.append(name)
    overlap = any(a[0] < b[1] and b[0] < a[1] for i, a in enumerate(spans) for b in spans[i + 1 :])
    return not overlap and len(set(names)) == len(names) and {"x", "y", "z"} <= set(names)


def reference_column(
    field: list, step: int, data: bytes, width: int, height: int, row_step: int, big: bool
) -> np.ndarray:
    """One field's values gathered byte by byte from the raw data (no structured dtype involved)."""
    _, offset, code, count = field
    base = DATATYPES[code].newbyteorder(">" if big else "<")
    raw = np.frombuffer(data, np.uint8)
    index = np.arange(height * width)
    starts = (index // max(width, 1)) * row_step + (index % max(width, 1)) * step + offset
    gathered = raw[starts[:, None] + np.arange(base.itemsize * count)[None, :]]
    values = np.ascontiguousarray(gathered).view(base)
    return values.reshape(-1) if count == 1 else values.reshape(-1, count)



def build_message(parts: tuple, data_kind: int) -> object:
    """A rosbags PointCloud2 from raw parts, no validation (data as numpy, array.array or bytes by `data_kind`)."""
    fields, step, data, height, width, row_step, big = parts
    types = TYPESTORE.types
    header = types["std_msgs/msg/Header"](stamp=types["builtin_interfaces/msg/Time"](sec=0, nanosec=0), frame_id="f")
    msg = types["sensor_msgs/msg/PointCloud2"](
        header=header, height=0, width=0,
        fields=[types["sensor_msgs/msg/PointField"](name=n, offset=o, datatype=d, count=c) for n, o, d, c in fields],
        is_bigendian=big, point_step=0, row_step=0, data=np.frombuffer(bytes(data), np.uint8).copy(), is_dense=False,
    )
    msg.point_step, msg.row_step, msg.height, msg.width = step, row_step, height, width
    if data_kind == 1:
        msg.data = array.array("B", data)
    elif data_kind == 2:
        msg.data = data
    return msg


def check_one(trial: int, parts: tuple, skip_nans: bool) -> bool:
    """Decode one message and compare with the independent reference; True if it decoded. AssertionError names
    the trial on any disagreement."""
    fields, step, data, height, width, row_step, big = parts
    valid = expected_valid(fields, step, data, height, width, row_step)
    try:
        out = decode(build_message(parts, trial % 3), skip_nans=skip_nans)
    except PointCloud2Error:
        assert not valid, f"trial {trial}: valid message rejected: {parts}"
        return False
    assert valid, f"trial {trial}: invalid message accepted: {parts}"
    named = [f for f in fields if f[0]]
    assert list(out.dtype.names) == [f[0] for f in named]
    keep = np.ones(height * width, bool)
    if skip_nans:
        for f in named:
            if f[0] in "xyz" and DATATYPES[f[2]].kind == "f":
                keep &= ~np.isnan(reference_column(f, step, data, width, height, row_step, big))
    for f in named:
        expected = reference_column(f, step, data, width, height, row_step, big)[keep]
        assert out[f[0]].dtype == expected.dtype and out[f[0]].shape == expected.shape
        assert out[f[0]].tobytes() == expected.tobytes(), f"trial {trial}: field {f[0]} differs"
    return True


def fuzz(messages: int, seed: int) -> dict[str, int]:
    """Run `messages` corrupted messages; {"decoded": n, "rejected": n}."""
    rng = np.random.default_rng(seed)
    outcomes = {"decoded": 0, "rejected": 0}
    for trial in range(messages):
        parts = random_message(rng)
        for _ in range(int(rng.integers(1, 3))):
            parts = mutate(rng, parts)
        outcomes["decoded" if check_one(trial, parts, skip_nans=trial % 5 == 0) else "rejected"] += 1
    return outcomes


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of `pass3d_benchmark fuzz`."""
    parser.add_argument("--messages", type=int, default=10_000, help="corrupted messages to try (default 10000)")
    parser.add_argument("--seed", type=number(int, 0), default=20240611, help="random seed (default 20240611)")


def run(args: argparse.Namespace) -> int:
    """Fuzz and print the counts; 1 when the codec disagrees with the reference, UserError on bad options."""
    if args.messages < 1:
        raise UserError("--messages must be >= 1")
    started = time.perf_counter()
    try:
        outcomes = fuzz(args.messages, args.seed)
    except AssertionError as exc:
        print(f"pass3d_benchmark: codec disagrees with the reference: {exc}", file=sys.stderr)
        return 1
    took = time.perf_counter() - started
    print(f"{args.messages} corrupted messages (seed {args.seed}) in {took:.1f} s: {outcomes['decoded']} decoded "
          f"exactly as their bytes say, {outcomes['rejected']} rejected with PointCloud2Error, 0 disagreements")
    return 0
