"""`pass3d_evaluate --tracking` (pass3d_ros.evaluation.tracking): flicker, CLEAR-MOT id switches and fragmentations
counted case by case, an instance's sighting (the object holding most of its points) and its one-to-one match, and the
command line's JSON and errors."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

import pass3d_ros.synthetic  # noqa: F401  (registers synthetic:)
from pass3d_ros.classes import BACKGROUND, CAR, PEDESTRIAN
from pass3d_ros.core.objects import FrameObjects, LabelledObject
from pass3d_ros.core.stage1 import Stage1Config
from pass3d_ros.core.stage2 import open_classifier
from pass3d_ros.core.stage2.config import tracker_from_params
from pass3d_ros.core.stream.tracks import Tracked, TrackerConfig
from pass3d_ros.core.tracked_scan import NO_TRACK
from pass3d_ros.data.spec import resolve_dataset
from pass3d_ros.evaluation.report import format_tracking
from pass3d_ros.evaluation.tracking import (
    Flicker,
    Mot,
    Sighting,
    StreamHistory,
    TrackingEvaluation,
    evaluate_tracking,
    instance_sightings,
    scan_period,
)
from pass3d_ros.tools import evaluate


def seen(track: int, cls: int = CAR) -> Sighting:
    return Sighting(0.0, cls, cls, track, cls if track != NO_TRACK else BACKGROUND, cls, track)


def test_id_switches_and_fragmentations_are_counted_as_clear_mot_counts_them() -> None:
    mot = Mot()
    mot.add([seen(NO_TRACK), seen(4), seen(4), seen(NO_TRACK), seen(4), seen(7), seen(7)], CAR)  # a gap, a switch
    mot.add([seen(NO_TRACK), seen(2), seen(NO_TRACK), seen(NO_TRACK), seen(9)], CAR)  # a gap that ends in a switch
    mot.add([seen(5)], CAR)  # seen once: no object-track
    out = mot.summary()
    assert (out["id_switches"], out["fragmentations"], out["object_tracks"]) == (2, 2, 2)
    assert out["id_switches_per_100"] == pytest.approx(100.0) and out["matched"] == 8 and out["sightings"] == 13


@pytest.mark.parametrize(("tracks", "counts"), [
    ([NO_TRACK, NO_TRACK, NO_TRACK], (0, 0, 1, 0)),  # never matched: misses only
    ([NO_TRACK, NO_TRACK, 4, 4], (0, 0, 1, 2)),  # matched late: no fragmentation before its first match
    ([4, 4, NO_TRACK, NO_TRACK], (0, 0, 1, 2)),  # lost at the end: never resumed, no fragmentation
    ([4, NO_TRACK, NO_TRACK, 4], (0, 1, 1, 2)),  # one gap of two scans: one fragmentation
    ([4, NO_TRACK, 4, NO_TRACK, 4], (0, 2, 1, 3)),  # two gaps
    ([1, 2, 1], (2, 0, 1, 3)),  # there and back: two switches
    ([5], (0, 0, 0, 1)),  # seen once: matched, but no object-track
    ([], (0, 0, 0, 0)),
])
def test_clear_mot_counts_of_one_instance(tracks: list[int], counts: tuple[int, int, int, int]) -> None:
    mot = Mot()
    mot.add([seen(t) for t in tracks], CAR)
    assert (mot.id_switches, mot.fragmentations, mot.object_tracks, mot.matched) == counts
    assert mot.sightings == len(tracks)


def test_clear_mot_counts_swapped_and_reused_tracks_per_instance() -> None:
    mot = Mot()
    mot.add([seen(1), seen(1), seen(2), seen(2)], CAR)  # two instances swap their tracks: a switch each
    mot.add([seen(2), seen(2), seen(1), seen(1)], CAR)
    mot.add([seen(3), seen(NO_TRACK), seen(2)], CAR)  # then takes a track another instance had: a switch, a gap
    out = mot.summary()
    assert (out["id_switches"], out["fragmentations"], out["object_tracks"]) == (3, 1, 3)
    assert out["id_switches_per_100"] == pytest.approx(100.0) and out["fragmentations_per_100"] == pytest.approx(
        100.0 / 3)
    assert Mot().summary()["id_switches_per_100"] is None  # no object-tracks: no rate


def test_flicker_pools_changes_over_the_summed_lives() -> None:
    flicker = Flicker()
    flicker.add([CAR, PEDESTRIAN], [CAR, CAR], 0.2)  # a short life with a change
    flicker.add([CAR] * 99 + [PEDESTRIAN], [CAR] * 100, 9.8)  # a long one with one change
    out = flicker.summary()
    assert out["life_s"] == pytest.approx(10.0) and out["per_10s_scan"] == pytest.approx(2.0)  # not (50 + 1.02) / 2
    assert out["per_10s_voted"] == 0.0 and out["reduction"] == pytest.approx(1.0)
    assert Flicker().summary()["per_10s_scan"] is None and Flicker().summary()["reduction"] is None


def test_flicker_counts_class_changes_per_object_per_ten_seconds_of_life() -> None:
    flicker = Flicker()
    flicker.add([CAR, BACKGROUND, CAR, CAR], [CAR, CAR, CAR, CAR], 0.4)
    flicker.add([PEDESTRIAN, CAR], [PEDESTRIAN, PEDESTRIAN], 0.6)
    flicker.add([CAR], [CAR], 0.1)  # seen once: no object over time
    out = flicker.summary()
    assert out["objects"] == 2 and out["changes_scan"] == 3 and out["changes_voted"] == 0
    assert out["per_10s_scan"] == pytest.approx(30.0) and out["reduction"] == pytest.approx(1.0)


def test_an_instance_s_sighting_is_the_object_holding_most_of_its_points() -> None:
    truth = np.array([CAR] * 14 + [PEDESTRIAN] * 12 + [PEDESTRIAN] * 3, np.uint8)
    instance = np.array([1] * 14 + [2] * 12 + [3] * 3, np.int32)  # instance 3 is too small to be seen
    scan = np.array([CAR] * 4 + [PEDESTRIAN] * 6 + [BACKGROUND] * 4 + [BACKGROUND] * 7 + [PEDESTRIAN] * 5
                    + [PEDESTRIAN] * 3, np.uint8)
    cluster = np.array([1] * 4 + [8] * 6 + [1] * 4 + [2] * 12 + [3] * 3, np.int32)
    voted = np.where(cluster == 8, CAR, scan).astype(np.uint8)
    track = np.array([11] * 4 + [12] * 6 + [NO_TRACK] * 4 + [NO_TRACK] * 12 + [NO_TRACK] * 3, np.int32)
    out = instance_sightings(truth, instance, scan, voted, cluster, track, 0.5)
    assert set(out) == {1, 2}
    car = out[1]  # 4 car points in object 1, 6 pedestrian points in object 8: object 8 holds most
    assert car.track == 12 and car.object_class_scan == PEDESTRIAN and car.object_class_voted == CAR
    assert car.scan_class == PEDESTRIAN and car.voted_class == CAR
    person = out[2]  # 7 of its 12 points background: its class flickers to background; its object is tentative
    assert person.scan_class == BACKGROUND and person.track == NO_TRACK and person.object_class_scan == PEDESTRIAN
    voted[14:21] = PEDESTRIAN  # a track held its background points: an object with tracking on, of no class before
    track[14:21] = 13
    held = instance_sightings(truth, instance, scan, voted, cluster, track, 0.5)[2]
    assert held.track == 13 and held.object_class_scan == BACKGROUND and held.object_class_voted == PEDESTRIAN


def test_a_joined_object_corresponds_to_the_instance_holding_most_of_it_only() -> None:
    truth = np.full(22, PEDESTRIAN, np.uint8)
    instance = np.array([1] * 10 + [2] * 12, np.int32)
    labels = truth.copy()
    cluster = np.full(22, 5, np.int32)  # stage 1 joined two people: one object, one track
    track = np.full(22, 21, np.int32)
    out = instance_sightings(truth, instance, labels, labels, cluster, track, 0.0)
    assert out[1].track == out[2].track == 21  # each holds its points in that object
    assert out[1].match == NO_TRACK and out[2].match == 21  # 10 of 22 points are not more than half of the object
    cluster[:10] = 6  # apart again: each object holds all of its instance's points and nothing else
    track[:10] = 20
    out = instance_sightings(truth, instance, labels, labels, cluster, track, 0.1)
    assert (out[1].match, out[2].match) == (20, 21)


def test_a_scan_without_road_user_instances_has_no_sightings() -> None:
    truth = np.array([BACKGROUND] * 15 + [CAR] * 5, np.uint8)
    instance = np.array([-1] * 15 + [-1] * 5, np.int32)  # a car without an instance id, the rest background
    cluster = np.full(20, -1, np.int32)
    assert instance_sightings(truth, instance, truth, truth, cluster, cluster, 0.0) == {}
    empty = np.zeros(0, np.uint8)  # a scan of no points
    none = np.zeros(0, np.int32)
    assert instance_sightings(empty, none, empty, empty, none, none, 0.1) == {}


def test_a_tracking_run_goes_on_through_scans_without_instances() -> None:
    frames = list(resolve_dataset("synthetic:drive=3,seed=3,sensor=hdl32e").frames())
    blank = frames[1]  # the middle scan: its road users labelled, none with an instance id
    frames[1] = replace(blank, instance=np.full(len(blank.points), -1, np.int32))
    run = evaluate_tracking(iter(("drive", frame) for frame in frames), Stage1Config(),
                            open_classifier(None, "size_rules"))
    assert run["frames"] == 3 and run["instances"] == "persistent"
    assert run["mot"]["sightings"] > 0 and run["mot"]["object_tracks"] > 0


def test_labelled_scans_without_instance_ids_say_so_and_count_no_switches() -> None:
    """Labels but no instance ids (KITTI object frames): no object-track can be followed, so the run says `none`
    and reports no id switches or ground-truth flicker (it said "persistent" with zero object-tracks)."""
    frames = [replace(frame, instance=None) for frame in resolve_dataset("synthetic:drive=2,seed=3").frames()]
    run = evaluate_tracking(iter(("drive", frame) for frame in frames), Stage1Config(),
                            open_classifier(None, "size_rules"))
    assert run["instances"].startswith("none") and "mot" not in run and "flicker" not in run
    assert run["iou"]["car"]["scan"] is not None


def test_clear_mot_counts_a_scan_in_a_neighbour_s_object_as_a_gap_not_two_switches() -> None:
    def joined(neighbour: int) -> Sighting:
        return Sighting(0.0, PEDESTRIAN, PEDESTRIAN, neighbour, PEDESTRIAN, PEDESTRIAN, NO_TRACK)

    def alone(own: int) -> Sighting:
        return Sighting(0.0, PEDESTRIAN, PEDESTRIAN, own, PEDESTRIAN, PEDESTRIAN, own)

    history = [alone(7), joined(21), alone(7), alone(7)]
    clear, most = Mot(), Mot(most_points=True)
    clear.add(history, PEDESTRIAN)
    most.add(history, PEDESTRIAN)
    assert (clear.id_switches, clear.fragmentations, clear.matched) == (0, 1, 3)
    assert (most.id_switches, most.fragmentations, most.matched) == (2, 0, 4)


def test_a_track_with_two_objects_in_one_scan_is_sighted_once_there() -> None:
    def scan(parts: list[tuple[int, int, int]], voted: int) -> SimpleNamespace:
        """One scan's published objects, (track, scan-by-scan class, points) each, all voted `voted`."""
        labels = np.concatenate([np.full(n, cls, np.uint8) for _, cls, n in parts])
        cluster = np.concatenate([np.full(n, k, np.int32) for k, (_, _, n) in enumerate(parts)])
        objects = [LabelledObject((0.0, 0.0, 0.0), (1.0, 1.0, 1.0), 0.0, cls, 1.0, k)
                   for k, (_, cls, _) in enumerate(parts)]
        tracked = [Tracked(track, voted, 1.0, True) for track, _, _ in parts]
        return SimpleNamespace(published=FrameObjects(labels, cluster, objects),
                               tracked=SimpleNamespace(ms=1.0, tracked=tracked))

    run = TrackingEvaluation(per_frame_instances=False)
    history = StreamHistory(0.1)
    frame = SimpleNamespace(name="f", labels=None)  # label-free data: the tracks' own flicker only
    scans = [scan([(7, CAR, 40), (7, PEDESTRIAN, 12)], CAR),  # a car and a part of it stage 2 called a person
             scan([(7, PEDESTRIAN, 12), (7, CAR, 40)], CAR),
             scan([(7, CAR, 40), (7, PEDESTRIAN, 12)], CAR)]
    for k, labelled in enumerate(scans):
        run.frame("s", frame, labelled, 0.1 * k, history)
    run.end_stream("s", history)
    flicker = run.summary()["track_flicker"]
    assert (flicker["objects"], flicker["changes_scan"], flicker["changes_voted"]) == (1, 0, 0)  # the part: no change
    assert flicker["life_s"] == pytest.approx(0.3)
    history = StreamHistory(0.1)
    run = TrackingEvaluation(per_frame_instances=False)
    for k, labelled in enumerate([scans[0], scan([(7, PEDESTRIAN, 40), (7, CAR, 12)], CAR), scans[2]]):
        run.frame("s", frame, labelled, 0.1 * k, history)
    run.end_stream("s", history)
    flicker = run.summary()["track_flicker"]  # the track's larger object called a person once: there and back
    assert (flicker["objects"], flicker["changes_scan"], flicker["changes_voted"]) == (1, 2, 0)


def test_an_instance_s_life_spans_missing_scans_and_the_report_prints_the_json_numbers() -> None:
    run = TrackingEvaluation(per_frame_instances=False)
    run.labelled = True
    history = StreamHistory(0.1)
    for stamp, track, cls in [(0.0, 4, CAR), (0.1, 4, PEDESTRIAN), (0.5, 9, CAR)]:  # scans 0.2 to 0.4 missing
        history.instances[3].append(replace(seen(track, cls), stamp_s=stamp))
    history.instances[8].append(seen(2))  # seen once: neither flicker nor an object-track
    run.truth_class[("s", 3)][CAR] = 3
    run.truth_class[("s", 8)][CAR] = 1
    run.end_stream("s", history)
    flicker, mot = run.instance_flicker.summary(), run.mot.summary()
    assert flicker["objects"] == 1 and flicker["life_s"] == pytest.approx(0.6) and flicker["changes_scan"] == 2
    assert (mot["object_tracks"], mot["id_switches"], mot["fragmentations"], mot["sightings"]) == (1, 1, 0, 4)
    summary = {"frames": 4, "streams": {}, "classifier": {"kind": "size_rules", "device": "cpu", "threads": 1},
               "flicker": flicker, "mot": mot, "mot_most_points": run.mot_most_points.summary(),
               "track_flicker": Flicker().summary(), "track_ms": {"median": None, "max": None}}
    text = format_tracking(summary)
    assert "(2 -> 2 changes, 1 objects, 0.6 s of life" in text
    assert "id switches 1 (100.0 per 100 object-tracks), fragmentations 0 (0.0 per 100), 1 object-tracks, " \
           "4 of 4 sightings matched" in text


def test_scan_period_is_the_stamps_median_step() -> None:
    assert scan_period([0, 100_000_000, 200_000_000, 400_000_000]) == pytest.approx(0.1)
    assert scan_period([5, 5]) is None and scan_period([0]) is None


def test_tracking_mode_json(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    out = tmp_path / "tracking.json"
    args = ["--tracking", "--data", "synthetic:drive=5,seed=3,sensor=hdl32e", "--classifier", "size_rules"]
    assert evaluate.main([*args, "--json", str(out), "--no-progress"]) == 0
    data = json.loads(out.read_text())
    assert data["mode"] == "tracking" and data["frames"] == 5 and data["labelled"]
    (stream,) = data["streams"].values()
    assert stream["period_from"] == "stamps" and stream["scan_period_s"] == pytest.approx(0.1)
    assert stream["frames_with_pose"] == 5
    assert set(data["iou"]) == {"car", "pedestrian", "cyclist"}
    assert {"scan", "voted", "difference", "low", "high"} <= set(data["iou"]["car"])
    assert data["mot"]["object_tracks"] > 0 and data["flicker"]["objects"] > 0
    assert data["mot_most_points"]["object_tracks"] == data["mot"]["object_tracks"]
    assert data["mot_most_points"]["matched"] >= data["mot"]["matched"]
    assert data["track_flicker"]["objects"] > 0 and len(data["per_frame"]) == 5
    assert "id switches" in capsys.readouterr().out
    per_frame = tmp_path / "per_frame.json"
    assert evaluate.main([*args, "--per-frame-instances", "--scan-rate", "2", "--json", str(per_frame),
                          "--no-progress"]) == 0
    data = json.loads(per_frame.read_text())
    assert "mot" not in data and "mot_most_points" not in data and "flicker" not in data
    assert data["instances"].startswith("per-frame")
    (stream,) = data["streams"].values()
    assert stream["period_from"] == "--scan-rate" and stream["scan_period_s"] == pytest.approx(0.5)


def test_tracking_options_need_tracking(capsys: pytest.CaptureFixture) -> None:
    assert evaluate.main(["--data", "synthetic:frames=1", "--scan-rate", "2"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--tracking only" in err[0]
    assert evaluate.main(["--data", "synthetic:frames=1", "--track", "track_fill_shapes=true"]) == 2
    assert "--tracking only" in capsys.readouterr().err


@pytest.mark.parametrize(("item", "says"), [("fill_shapes=true", "track_fill_shapes"),
                                             ("track_fill_shapes=maybe", "true or false"),
                                             ("track_gate_car=far", "a number"),
                                             ("track_gate_car=-1", "outside"),
                                             ("track_min_hits=2.5", "an integer")])
def test_a_wrong_track_setting_is_named_before_the_run(item: str, says: str, capsys: pytest.CaptureFixture) -> None:
    assert evaluate.main(["--tracking", "--data", "synthetic:drive=2,seed=3", "--track", item]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and says in err[0] and "Traceback" not in err[0]


def test_track_settings_reach_the_tracker(tmp_path: Path) -> None:
    assert tracker_from_params([]) == TrackerConfig()
    tracker = tracker_from_params(["track_fill_shapes=true", "segmentation_node.track_gate_car=2.5"])
    assert tracker.fill_shapes is True and tracker.gate(CAR) == 2.5
    assert tracker_from_params(["track_fill_shapes=on", "track_min_hits=4"]) == replace(
        TrackerConfig(), fill_shapes=True, min_hits=4)  # read as --param reads stage 1's values
    out = tmp_path / "tracking.json"
    args = ["--tracking", "--data", "synthetic:drive=3,seed=3,sensor=hdl32e", "--classifier", "size_rules",
            "--no-progress", "--json", str(out)]
    assert evaluate.main([*args, "--track", "track_fill_shapes=true"]) == 0
    assert json.loads(out.read_text())["tracker"]["fill_shapes"] is True
    assert evaluate.main(args) == 0
    assert json.loads(out.read_text())["tracker"]["fill_shapes"] is False
