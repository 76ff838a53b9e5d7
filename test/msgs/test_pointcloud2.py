"""PointCloud2 codec: round trips on rclpy and rosbags messages, layouts, every documented error, fuzzing."""

from __future__ import annotations

import array
import sys
import warnings
from types import SimpleNamespace

import numpy as np
import pytest
from rosbags.typesys import Stores, get_typestore

from pass3d_ros.bench.codec_fuzz import fuzz
from pass3d_ros.msgs.pointcloud2 import (
    DATATYPES,
    NO_RING,
    PointCloud2Error,
    columns_to_cloud,
    decode,
    decode_xyzi,
    encode,
    fields_dtype,
    header_stamp_ns,
    to_xyzi,
)

TYPESTORE = get_typestore(Stores.ROS2_JAZZY)
RB_CLOUD = TYPESTORE.types["sensor_msgs/msg/PointCloud2"]
RB_FIELD = TYPESTORE.types["sensor_msgs/msg/PointField"]
PC2 = "sensor_msgs/msg/PointCloud2"


def sample_columns(n: int = 257, seed: int = 1) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    return {
        "x": rng.normal(0, 20, n).astype(np.float32),
        "y": rng.normal(0, 20, n).astype(np.float32),
        "z": rng.normal(0, 2, n).astype(np.float32),
        "intensity": rng.random(n, dtype=np.float32),
        "ring": rng.integers(0, 64, n).astype(np.uint16),
        "cluster_id": rng.integers(-1, 40, n).astype(np.int32),
        "label": rng.integers(0, 4, n).astype(np.uint8),
        "t": rng.random(n),
    }


def make_msg(fields, point_step, rows: bytes | np.ndarray, height=1, width=None, row_step=None, bigendian=False):
    """A rosbags PointCloud2 from raw parts (no validation: tests build broken ones on purpose)."""
    data = np.frombuffer(bytes(rows), np.uint8).copy()
    if width is None:
        width = len(data) // point_step // max(height, 1)
    if row_step is None:
        row_step = width * point_step
    header = TYPESTORE.types["std_msgs/msg/Header"](
        stamp=TYPESTORE.types["builtin_interfaces/msg/Time"](sec=0, nanosec=0), frame_id="f"
    )
    return RB_CLOUD(
        header=header,
        height=height,
        width=width,
        fields=[RB_FIELD(name=n, offset=o, datatype=d, count=c) for n, o, d, c in fields],
        is_bigendian=bigendian,
        point_step=point_step,
        row_step=row_step,
        data=data,
        is_dense=False,
    )


def test_round_trip_rclpy_message_through_serialization() -> None:
    from rclpy.serialization import deserialize_message, serialize_message
    from sensor_msgs.msg import PointCloud2

    cloud = columns_to_cloud(sample_columns())
    msg = encode(cloud, frame_id="velodyne", stamp_ns=1_234_567_890_123)
    assert isinstance(msg, PointCloud2)
    assert isinstance(msg.data, array.array)
    assert (msg.height, msg.width, msg.point_step) == (1, len(cloud), cloud.dtype.itemsize)
    assert msg.header.frame_id == "velodyne"
    assert (msg.header.stamp.sec, msg.header.stamp.nanosec) == (1234, 567_890_123)
    assert msg.is_dense
    wire = deserialize_message(serialize_message(msg), PointCloud2)
    out = decode(wire)
    assert out.dtype.names == cloud.dtype.names
    assert out.tobytes() == cloud.tobytes()
    assert header_stamp_ns(wire) == 1_234_567_890_123
    assert np.shares_memory(out, np.frombuffer(wire.data, np.uint8)), "decode must be zero-copy"


def test_round_trip_rosbags_message_through_cdr() -> None:
    cols = sample_columns(seed=3)
    msg = encode(cols, frame_id="lidar", stamp_ns=5, typestore=TYPESTORE)
    assert type(msg) is RB_CLOUD
    back = TYPESTORE.deserialize_cdr(TYPESTORE.serialize_cdr(msg, PC2), PC2)
    out = decode(back)
    for name, values in cols.items():
        assert np.array_equal(out[name], values), name
    assert back.header.frame_id == "lidar" and header_stamp_ns(back) == 5
    via_class = encode(cols, msg_class=RB_CLOUD)
    assert type(via_class) is RB_CLOUD and np.array_equal(decode(via_class), out)


def test_encode_keeps_given_header_and_copies_data() -> None:
    from std_msgs.msg import Header

    cloud = columns_to_cloud(sample_columns(10))
    header = Header(frame_id="keep")
    header.stamp.sec, header.stamp.nanosec = 7, 8
    msg = encode(cloud, header=header, frame_id="ignored", stamp_ns=99)
    assert msg.header.frame_id == "keep" and header_stamp_ns(msg) == 7_000_000_008
    cloud["x"][:] = 0.0
    assert decode(msg)["x"].any(), "message must not alias the caller's array"


def test_padding_and_reordered_fields() -> None:
    n = 5
    layout = np.dtype(
        {"names": ["z", "intensity", "x", "y"], "formats": ["<f4"] * 4, "offsets": [20, 0, 12, 8], "itemsize": 32}
    )
    rows = np.zeros(n, layout)
    rows["x"], rows["y"], rows["z"], rows["intensity"] = np.arange(n), -np.arange(n), 10 + np.arange(n), 0.5
    raw = rows.tobytes()
    fields = [("z", 20, 7, 1), ("intensity", 0, 7, 1), ("x", 12, 7, 1), ("y", 8, 7, 1)]
    out = decode(make_msg(fields, 32, raw))
    assert out.dtype.itemsize == 32 and out.dtype.names == ("z", "intensity", "x", "y")
    xyzi = to_xyzi(out)
    expected = np.stack([np.arange(n), -np.arange(n), 10 + np.arange(n), np.full(n, 0.5)], axis=1)
    assert np.array_equal(xyzi.points, expected.astype(np.float32))
    assert xyzi.has_intensity and xyzi.ring is None


def test_organized_cloud_with_row_padding_is_row_major() -> None:
    height, width, step, pad = 3, 4, 12, 8
    values = np.arange(height * width * 3, dtype=np.float32).reshape(height, width * 3)
    rows = b"".join(row.tobytes() + b"\xee" * pad for row in values)
    msg = make_msg(
        [("x", 0, 7, 1), ("y", 4, 7, 1), ("z", 8, 7, 1)],
        step,
        rows,
        height=height,
        width=width,
        row_step=width * step + pad,
    )
    out = decode(msg)
    assert len(out) == height * width
    assert np.array_equal(out["x"], values.reshape(-1, 3)[:, 0])
    assert np.array_equal(out["z"], values.reshape(-1, 3)[:, 2])


def test_organized_encode_round_trip() -> None:
    cloud = columns_to_cloud(sample_columns(12))
    msg = encode(cloud, height=3, typestore=TYPESTORE)
    assert (msg.height, msg.width, msg.row_step) == (3, 4, 4 * cloud.dtype.itemsize)
    assert decode(msg).tobytes() == cloud.tobytes()
    with pytest.raises(PointCloud2Error, match="rows"):
        encode(cloud, height=5)


@pytest.mark.parametrize("bigendian", [False, True])
def test_every_datatype_and_count(bigendian: bool) -> None:
    order = ">" if bigendian else "<"
    rng = np.random.default_rng(7)
    n = 9
    names, formats, offsets, fields, offset = [], [], [], [], 0
    for code, base in DATATYPES.items():
        for count in (1, 3):
            name = "x" if (code, count) == (7, 1) else f"f{code}_{count}"
            names.append(name)
            formats.append(base.newbyteorder(order) if count == 1 else (base.newbyteorder(order), (count,)))
            offsets.append(offset)
            fields.append((name, offset, code, count))
            offset += base.itemsize * count + 1
    names += ["y", "z"]
    formats += [order + "f8", order + "i2"]
    offsets += [offset, offset + 8]
    fields += [("y", offset, 8, 1), ("z", offset + 8, 3, 1)]
    layout = np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": offset + 11})
    rows = np.frombuffer(rng.integers(0, 256, n * layout.itemsize, dtype=np.uint8).tobytes(), layout)
    out = decode(make_msg(fields, layout.itemsize, rows.tobytes(), bigendian=bigendian))
    for name in names:
        expected = rows[name]
        assert out[name].shape == expected.shape, name
        assert np.array_equal(
            out[name].astype(expected.dtype.base.newbyteorder("=")),
            expected.astype(expected.dtype.base.newbyteorder("=")),
            equal_nan=True,
        ), name
    encoded = encode(out, typestore=TYPESTORE)
    assert bool(encoded.is_bigendian) == (sys.byteorder == "big")
    again = decode(encoded)
    for name in names:
        assert np.array_equal(again[name], out[name], equal_nan=True), name


def test_nan_points_kept_or_dropped() -> None:
    cols = sample_columns(6)
    cols["x"][1] = np.nan
    cols["z"][4] = np.nan
    msg = encode(cols)
    assert not msg.is_dense
    kept = decode(msg)
    assert len(kept) == 6 and np.isnan(kept["x"][1])
    dropped = decode(msg, skip_nans=True)
    assert len(dropped) == 4
    assert np.array_equal(dropped["y"], cols["y"][[0, 2, 3, 5]])
    assert decode_xyzi(msg, skip_nans=True).points.shape == (4, 4)


@pytest.mark.parametrize("view", ["rows", "every_other_row", "reversed", "columns_swapped"])
def test_columns_of_one_point_array_encode_like_copies(view: str) -> None:
    """x, y, z, intensity taken from one N x 4 array (copied as one block when they lie side by side) give the
    same bytes as the same columns copied apart."""
    base = np.random.default_rng(3).normal(size=(40, 4)).astype(np.float32)
    points = {"rows": base, "every_other_row": base[::2], "reversed": base[::-1],
              "columns_swapped": base[:, [1, 0, 2, 3]]}[view]
    cols = {"x": points[:, 0], "y": points[:, 1], "z": points[:, 2], "intensity": points[:, 3],
            "label": np.arange(len(points), dtype=np.uint8)}
    copies = {name: np.array(values) for name, values in cols.items()}
    assert bytes(encode(cols).data) == bytes(encode(copies).data)
    assert np.array_equal(decode(encode(cols))["z"], points[:, 2])


@pytest.mark.parametrize("layout", ["xyzi_float32", "float64"])
def test_decode_xyzi_drops_nan_points_with_their_rings(layout: str) -> None:
    """The one-pass copy (x, y, z, intensity consecutive float32) and the column path drop the same points, and the
    ring of each point that stays."""
    n = 9
    dtype = np.float32 if layout == "xyzi_float32" else np.float64
    cols = {axis: np.arange(n, dtype=dtype) + k for k, axis in enumerate(("x", "y", "z"))}
    cols["intensity"] = np.linspace(0, 1, n).astype(np.float32)
    cols["ring"] = np.arange(n, dtype=np.uint16) * 3
    cols["y"][2] = np.nan
    cols["z"][7] = np.nan
    scan = decode_xyzi(encode(cols), skip_nans=True)
    keep = [0, 1, 3, 4, 5, 6, 8]
    np.testing.assert_array_equal(scan.ring, cols["ring"][keep])
    np.testing.assert_array_equal(scan.points[:, 0], cols["x"][keep].astype(np.float32))
    np.testing.assert_array_equal(scan.points[:, 3], cols["intensity"][keep])
    whole = decode_xyzi(encode(cols))
    assert len(whole.points) == n and np.isnan(whole.points[2, 1]) and len(whole.ring) == n


@pytest.mark.parametrize("alias", ["intensity", "i", "reflectance"])
def test_intensity_aliases(alias: str) -> None:
    cols = sample_columns(20)
    values = cols.pop("intensity")
    cols[alias] = values.astype(np.float64) if alias == "reflectance" else values
    result = decode_xyzi(encode(cols))
    assert result.has_intensity
    assert np.array_equal(result.points[:, 3], values)
    assert np.array_equal(result.ring, cols["ring"])
    assert np.array_equal(result.points[:, 0], cols["x"])


def test_missing_intensity_gives_zeros_and_flag() -> None:
    cols = {k: v for k, v in sample_columns(8).items() if k in ("x", "y", "z")}
    result = decode_xyzi(encode(cols))
    assert not result.has_intensity and result.ring is None
    assert np.array_equal(result.points[:, 3], np.zeros(8, np.float32))
    assert np.array_equal(result.points[:, 2], cols["z"])


def test_empty_cloud() -> None:
    msg = encode({"x": np.zeros(0, np.float32), "y": np.zeros(0, np.float32), "z": np.zeros(0, np.float32)})
    assert len(decode(msg)) == 0 and decode_xyzi(msg).points.shape == (0, 4)


XYZ = [("x", 0, 7, 1), ("y", 4, 7, 1), ("z", 8, 7, 1)]


@pytest.mark.parametrize(
    ("fields", "step", "kwargs", "nbytes", "match"),
    [
        (XYZ, 12, {}, 35, "data has 35 bytes, expected"),
        (XYZ, 12, {"row_step": 20, "width": 3}, 36, "row_step 20 < width 3"),
        (XYZ[:2], 12, {}, 36, "missing field.*z"),
        ([*XYZ, ("intensity", 10, 7, 1)], 16, {}, 48, "overlap"),
        ([*XYZ, ("intensity", 12, 7, 1)], 14, {}, 42, "out of range of point_step 14"),
        ([*XYZ, ("intensity", 12, 7, 2)], 20, {}, 60, "count 2 not supported"),
        ([*XYZ, ("intensity", 12, 7, 0)], 16, {}, 48, "count is 0"),
        ([*XYZ, ("intensity", 12, 9, 1)], 16, {}, 48, "unknown datatype 9"),
        (XYZ, 0, {"width": 3, "row_step": 0}, 0, "point_step is 0"),
        ([*XYZ, ("y", 12, 7, 1)], 16, {}, 48, "duplicate field name 'y'"),
        ([("x", -4, 7, 1), *XYZ[1:]], 12, {}, 36, "offset must be >= 0"),
        (XYZ, 12, {"width": 2**31}, 24, "data has 24 bytes, expected height 1 \\* row_step 25769803776"),
        (XYZ, 12, {"height": 2**31, "width": 2**31, "row_step": 12 * 2**31}, 24, "data has 24 bytes"),
    ],
)
def test_documented_errors(fields, step, kwargs, nbytes, match) -> None:
    msg = make_msg(fields, step, bytes(nbytes), **({"width": 3} | kwargs))
    with pytest.raises(PointCloud2Error, match=match):
        decode(msg)


class CountedName(str):
    """A field name that counts how often it is compared."""

    compared = 0

    def __eq__(self, other: object) -> bool:
        CountedName.compared += 1
        return str.__eq__(self, other)

    __hash__ = str.__hash__


def test_field_names_are_checked_in_linear_time() -> None:
    """The duplicate-name check costs a few comparisons per field, not one per earlier field: a message of 20k
    named fields (400 kB) held a node's worker for 2 s."""
    n = 2000
    fields = [SimpleNamespace(name=CountedName(name), offset=offset, datatype=7, count=1) for name, offset, _, _ in XYZ]
    fields += [SimpleNamespace(name=CountedName(f"f{k}"), offset=12 + k, datatype=2, count=1) for k in range(n)]
    CountedName.compared = 0
    assert len(fields_dtype(fields, 12 + n).names) == n + 3
    assert CountedName.compared < 10 * n


def test_not_a_message_and_bad_data() -> None:
    with pytest.raises(PointCloud2Error, match="not a PointCloud2"):
        decode(SimpleNamespace(height=1))
    msg = make_msg(XYZ, 12, bytes(12))
    msg.data = ["a"] * 12
    with pytest.raises(PointCloud2Error, match="not a byte buffer"):
        decode(msg)
    msg.data = list(range(12))
    assert len(decode(msg)) == 1


def test_unnamed_fields_are_padding() -> None:
    out = decode(make_msg([*XYZ, ("", 12, 2, 4)], 16, bytes(32)))
    assert out.dtype.names == ("x", "y", "z") and len(out) == 2


def test_encode_errors() -> None:
    with pytest.raises(PointCloud2Error, match="no PointField datatype"):
        encode({"x": np.zeros(2, np.float32), "y": np.zeros(2), "z": np.zeros(2), "id": np.zeros(2, np.int64)})
    with pytest.raises(PointCloud2Error, match="missing field"):
        encode({"x": np.zeros(2), "y": np.zeros(2)})
    with pytest.raises(PointCloud2Error, match="differ in length"):
        encode({"x": np.zeros(2), "y": np.zeros(2), "z": np.zeros(3)})
    with pytest.raises(PointCloud2Error, match="structured"):
        encode(np.zeros(3, np.float32))


def test_big_endian_input_array_encodes_native() -> None:
    cloud = np.zeros(4, dtype=[("x", ">f4"), ("y", ">f4"), ("z", ">f8")])
    cloud["x"] = [1, 2, 3, 4]
    msg = encode(cloud, typestore=TYPESTORE)
    assert bool(msg.is_bigendian) == (sys.byteorder == "big")
    assert np.array_equal(decode(msg)["x"], [1, 2, 3, 4])


# ---- fuzzing: every corrupted message decodes to what its bytes say, or raises PointCloud2Error ----

def test_fuzz_corrupted_messages() -> None:
    """A seeded share of `pass3d_benchmark fuzz` (10,000 there): every corrupted message decodes to what its bytes
    say or raises PointCloud2Error, checked against an independent restatement of the rules."""
    outcomes = fuzz(1500, 20240611)
    assert outcomes["decoded"] > 200 and outcomes["rejected"] > 500, outcomes


def test_codec_benchmark_runs(capsys: pytest.CaptureFixture[str]) -> None:
    from pass3d_ros.bench.benchmark import main

    assert main(["codec", "--points", "2000", "--repeat", "3"]) == 0
    out = capsys.readouterr().out
    assert "2000 points" in out and "ring:uint16" in out
    for name in ("encode", "decode", "decode_xyzi"):
        assert f"\n{name} " in out


def test_packed_rgb_gives_each_class_its_colour_and_unknown_labels_grey() -> None:
    from pass3d_ros.classes import BACKGROUND, CLASS_COLORS_RGB, packed_rgb

    for labels in (np.array([0, 1, 2, 3, 4, 255], dtype=np.uint8), np.array([0, 1, 2, 3, 4, 1000])):
        packed = packed_rgb(labels).view(np.uint32)
        rgb = np.stack([(packed >> 16) & 255, (packed >> 8) & 255, packed & 255], axis=1)
        expected = CLASS_COLORS_RGB[[0, 1, 2, 3, BACKGROUND, BACKGROUND]]
        assert np.array_equal(rgb, expected), labels.dtype


def test_a_channel_field_is_read_as_the_ring_when_there_is_no_ring() -> None:
    """Autoware's drivers name the laser index `channel`; a `ring` field wins when both are there."""
    n = 5
    xyz = {axis: np.arange(n, dtype=np.float32) for axis in "xyz"}
    channel = np.arange(n, dtype=np.uint16)[::-1].copy()
    scan = decode_xyzi(encode({**xyz, "intensity": np.ones(n, np.float32), "channel": channel}))
    np.testing.assert_array_equal(scan.ring, channel)
    both = decode_xyzi(encode({**xyz, "ring": np.zeros(n, np.uint16), "channel": channel}))
    np.testing.assert_array_equal(both.ring, np.zeros(n))


WILD_FLOAT_RINGS = [-1, 65539, 2.5, np.nan]


@pytest.mark.parametrize(("dtype", "wild"), [(np.int8, [-1]), (np.int32, [-1, 65539]), (np.uint32, [65539]),
                                           (np.float32, WILD_FLOAT_RINGS), (np.float64, WILD_FLOAT_RINGS)])
def test_a_ring_value_uint16_cannot_hold_reads_past_every_laser(dtype: type, wild: list[float]) -> None:
    """A ring field of any integer or float type reads its values; one uint16 cannot hold (negative, past 65535,
    fractional, NaN) reads NO_RING, which stage 1's ring check refuses, never another laser's index (65539 -> 3)."""
    ring = np.array([0, 3, 63, *wild], dtype=dtype)
    xyz = {axis: np.ones(len(ring), np.float32) for axis in "xyz"}
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        scan = decode_xyzi(encode({**xyz, "ring": ring}))
    assert scan.ring.dtype == np.uint16
    np.testing.assert_array_equal(scan.ring, [0, 3, 63] + [NO_RING] * len(wild))


def test_warm_up_compiles_what_decoding_runs() -> None:
    """The codec's kernel compiled by warm_up for every view a decode gives (x, y, z, intensity alone or beside a
    ring, in a writable array or read-only bytes): a node's first message runs compiled code."""
    from pass3d_ros.msgs import pointcloud2

    pointcloud2.warm_up()
    compiled = list(pointcloud2._copy_xyzi.signatures)
    xyzi = np.random.default_rng(0).random((50, 4)).astype(np.float32)
    alone = {"x": xyzi[:, 0], "y": xyzi[:, 1], "z": xyzi[:, 2], "intensity": xyzi[:, 3]}
    for fields in (alone, {**alone, "ring": np.zeros(50, np.uint16)}):
        msg = pointcloud2.encode(fields, frame_id="lidar")
        np.testing.assert_array_equal(pointcloud2.decode_xyzi(msg).points, xyzi)
        msg.data = bytes(msg.data)
        np.testing.assert_array_equal(pointcloud2.decode_xyzi(msg).points, xyzi)
    assert [s for s in pointcloud2._copy_xyzi.signatures if s not in compiled] == []
