"""The folder `pass3d_adapt` writes: `weights.pt` (only weights that passed every guard, or the last finished epoch's
after a Ctrl-C, marked partial), `pass3d_params.yaml` (the nodes' parameters for this sensor), `report.json`,
`report.md` and `view.png` (a held-out scan before and after). Built in a hidden sibling and moved into place whole
(pass3d_ros.data.outputs), so an interrupted write leaves no folder that looks complete.
"""

from __future__ import annotations

import json
import shutil
import time
from pathlib import Path

import numpy as np
import torch

from pass3d_ros.adapt.run import GUARD_DROP, AdaptResult
from pass3d_ros.classes import CLASS_NAMES
from pass3d_ros.core.stage1 import Stage1Config
from pass3d_ros.data.outputs import swap_into_place, write_marker, writing
from pass3d_ros.data.params_file import node_params_yaml
from pass3d_ros.data.partials import partial_path
from pass3d_ros.drawing.bev import Panel, render_figure, write_png

PROG = "pass3d_adapt"
SHARE_MOVE = 2.0  # a range bin whose share of proposals called an object moves by this factor either way is noted
SHARE_FLOOR = 0.1  # ... when the larger of the two shares is at least this


def write_folder(result: AdaptResult, out: Path, data: list[str]) -> Path:
    """Write the folder for `result` at `out` (replacing what is there: the caller checked it may); returns `out`."""
    build = partial_path(out)
    try:
        with writing(out):
            build.mkdir(parents=True)
            write_marker(build, PROG)
            weights = out / "weights.pt"
            if result.weights is not None and (result.accepted or result.partial):
                checkpoint = dict(result.weights)
                if result.partial:
                    checkpoint["adapted"] = {**checkpoint.get("adapted", {}), "partial": result.partial}
                torch.save(checkpoint, build / "weights.pt")
                (build / "pass3d_params.yaml").write_text(params_yaml(result, weights, data))
            elif result.settings_only is not None:  # the sensor's settings with the starting weights
                (build / "pass3d_params.yaml").write_text(params_yaml(result, None, data))
            report = report_dict(result, data)
            (build / "report.json").write_text(json.dumps(report, indent=1) + "\n")
            if result.view is not None:
                v = result.view
                write_png(build / "view.png", render_figure([Panel("before", v["points"], v["before"]),
                                                             Panel("after", v["points"], v["after"])]))
            (build / "report.md").write_text(report_markdown(report, result.view is not None))
            swap_into_place(build, out)
    except BaseException:
        shutil.rmtree(build, ignore_errors=True)
        raise
    return out


def params_yaml(result: AdaptResult, weights: Path | None, data: list[str]) -> str:
    """The nodes' parameters for this sensor, as `--ros-args --params-file` and the launch files read them. `weights`:
    the adapted ones; None names the starting weights (settings only), empty for the shipped ones."""
    s = result.sensor
    default = Stage1Config().to_dict()
    # The stage-1 values the run used that differ from the defaults (--param, the body's min_range) win over what
    # the recording said (a fitting table, the measured height): the nodes must run as the adaptation was checked.
    given = {key: list(value) if isinstance(value, tuple) else value
             for key, value in result.stage1.to_dict().items() if value != default[key]}
    stage1: dict = {"sensor": given.pop("sensor", s.laser_table)}
    if s.mounting and "sensor_height" not in given:
        stage1["sensor_height"] = float(s.mounting["height_m"])
    stage1.update(given)
    cluster: dict = {"input_topic": result.topic} if result.topic else {}
    cluster["stage1"] = stage1
    if s.intensity_divisor != 1.0:
        cluster["intensity_scale"] = float(1.0 / s.intensity_divisor)
    head = (f"# Written by {PROG} on {time.strftime('%Y-%m-%d %H:%M')} from {', '.join(data)}.\n"
            f"# Sensor read: {s.n_rings} rings ({s.ring_source}), lowest laser {s.bottom_deg:.1f} deg, "
            f"{s.simulated_how} simulated {s.nearest_simulated}; "
            f"laser table {s.laser_table}.\n"
            + ("# PARTIAL: interrupted during the fine-tune; these weights were never checked.\n"
               if result.partial else "")
            + (f"# SETTINGS ONLY ({result.settings_only}): the starting weights, not adapted.\n"
               if result.settings_only else ""))
    return node_params_yaml(cluster, {"weights": _weights_value(result, weights)}, head)


def _weights_value(result: AdaptResult, weights: Path | None) -> str:
    """segmentation_node's `weights`: the adapted file, else the starting one ("" for the shipped weights)."""
    if weights is not None:
        return str(weights.resolve())
    return str(Path(result.start_weights).resolve()) if result.start_weights else ""


def report_dict(result: AdaptResult, data: list[str]) -> dict:
    """Everything measured, as plain values (report.json)."""
    verdict = ("settings only" if result.settings_only is not None else "partial" if result.partial
               else "accepted" if result.accepted else "refused" if result.weights is not None else "no weights")
    return {
        "data": list(data), "verdict": verdict, "refused": list(result.refused), "partial": result.partial,
        "settings_only": result.settings_only,
        "seconds": round(result.seconds, 1), "sensor": result.sensor.to_dict(),
        "scans": {"read": len(result.scan_names), "adapt": _names(result, result.split.adapt),
                  "check": _names(result, result.split.check), "left_out": len(result.split.left_out)},
        "before": result.before, "after": result.after,
        "guard": {"drop_allowed": GUARD_DROP, "before": result.guard_before, "after": result.guard_after},
        "notes": share_notes(result.before, result.after),
        "training": {k: v for k, v in result.training.items() if k != "history"},
        "history": result.training.get("history", []),
    }


def share_notes(before: dict, after: dict | None) -> list[str]:
    """Range bins where the share of held-out proposals called an object moved by SHARE_MOVE or more: a network can
    agree with itself more by calling far blobs background (or everything a car), which agreement alone hides."""
    if after is None:
        return []
    notes = []
    for bin_name, row in before["class_shares"].items():
        if not row["proposals"]:
            continue
        old, new = 1.0 - (row["background"] or 0.0), 1.0 - (after["class_shares"][bin_name]["background"] or 0.0)
        if max(old, new) >= SHARE_FLOOR and (new * SHARE_MOVE <= old or old * SHARE_MOVE <= new):
            notes.append(f"{bin_name} m: proposals called an object {100 * old:.1f} % before, {100 * new:.1f} % "
                         f"after ({row['proposals']} proposals): look at view.png before trusting the agreement")
    return notes


def _names(result: AdaptResult, positions: np.ndarray) -> list[str]:
    return [result.scan_names[int(i)] for i in positions]


def _pct(value: float | None) -> str:
    return "-" if value is None else f"{100 * value:.1f}"


def report_markdown(report: dict, picture: bool) -> str:
    """report.md: the verdict, then before / after tables a reader can act on."""
    lines = [f"# pass3d_adapt: {report['verdict']}", ""]
    if report["verdict"] == "accepted":
        lines += ["The adapted weights passed the guard. Use them:",
                  "`ros2 launch pass3d_ros pass3d.launch.py params_file:=" + "pass3d_params.yaml`; score them on "
                  "labelled scans of your own with `pass3d_evaluate --params-file pass3d_params.yaml --data SPEC`.",
                  ""]
    elif report["verdict"] == "refused":
        lines += ["No weights written: " + "; ".join(report["refused"]) + ".", ""]
    elif report["verdict"] == "settings only":
        lines += [f"Settings only: {report['settings_only']}. `pass3d_params.yaml` holds what was read of your "
                  "sensor with the starting weights, unchanged; record more scans to adapt the network. The check "
                  "below read every scan (none could be held out).", ""]
    elif report["verdict"] == "partial":
        lines += ["Interrupted during the fine-tune: `weights.pt` holds the last finished epoch, never checked; "
                  "do not deploy it without running again.", ""]
    if report["notes"]:
        lines += ["Notes: " + "; ".join(report["notes"]) + ".", ""]
    s = report["sensor"]
    chosen = "simulated sensor named by --sensor" if s["simulated_how"] == "named" else "nearest simulated sensor"
    scans = report["scans"]
    split = ("every one checked, none adapted on" if report["settings_only"] else
             f"{len(scans['adapt'])} adapted on, {len(scans['check'])} held out ({scans['left_out']} between them "
             "left out)")
    lines += [f"Data: {', '.join(report['data'])}; {scans['read']} scan(s) read, {split}; "
              f"{report['seconds'] / 60:.1f} min.",
              f"Sensor: {s['n_rings']} rings ({s['ring_source']}), resolution {s['vertical_deg']:.2f} x "
              f"{s['horizontal_deg']:.3f} deg, lowest laser {s['bottom_deg']:.1f} deg; "
              f"{chosen} {s['nearest_simulated']} (distance {s['distance']:.2f}); laser table {s['laser_table']}; "
              f"mounting {s['mounting']}" + ("" if s.get("constant_intensity") is None else
                                    f"; intensity {s['constant_intensity']:g} on every point (none to learn from)")
              + ".", ""]
    body = s.get("self_returns")
    if body:
        lines += [f"The vehicle's own returns: {body['note']}" + (f"; left out nearer than {body['radius_m']:.1f} m "
                  "(`stage1.min_range` in pass3d_params.yaml; delete it if the robot works among objects that near)."
                  if body["radius_m"] > 0 else "."), ""]
    before, after = report["before"], report["after"]
    lines += ["## All scans, no labels (none held out)" if report["settings_only"] else "## Held-out scans, no labels",
              "",
              "View agreement: the share of proposals all 8 canonical views give the same class (mean over "
              f"{before['draws']} point draws, range, and draw 0's 90 % scan-bootstrap interval).", "",
              "| class | before | after |", "|---|---|---|"]
    for name in before["agreement"]:
        lines.append(f"| {name} | {_agreement_cell(before['agreement'][name])} | "
                     f"{_agreement_cell(after['agreement'][name]) if after else '-'} |")
    if before.get("draw_agreement"):
        lines += ["", "Draw agreement: the share of proposals whose views' majority is the same class in every point "
                  f"draw: all proposals {_draw_cell(before, 'all')} before, {_draw_cell(after, 'all')} after; those "
                  f"some draw calls an object {_draw_cell(before, 'objects')} before, "
                  f"{_draw_cell(after, 'objects')} after."]
    lines += ["", f"Proposals per scan: median {before['proposals_per_scan']['median']}.", "",
              "Share of proposals each class takes, by range (views' majority, draw 0):", "",
              "| range (m) | proposals | before: " + " / ".join(CLASS_NAMES) + " | after |", "|---|---|---|---|"]
    for bin_name, row in before["class_shares"].items():
        other = after["class_shares"][bin_name] if after else None
        lines.append(f"| {bin_name} | {row['proposals']} | {' / '.join(_pct(row[c]) for c in CLASS_NAMES)} | "
                     f"{' / '.join(_pct(other[c]) for c in CLASS_NAMES) if other else '-'} |")
    guard = report["guard"]
    if guard["before"] is not None:
        lines += ["", f"## Guard: unseen synthetic scenes of the {s['simulated_how']} simulated sensor", "",
                  f"`{guard['before']['spec']}`: mean IoU over draws {_guard_cell(guard['before'])} before, "
                  f"{_guard_cell(guard['after']) if guard['after'] else '-'} after; the adapted weights may lose at "
                  f"most {guard['drop_allowed']:g} point.", ""]
    else:
        lines.append("")
    if picture:
        lines += ["## A held-out scan", "", "![before and after](view.png)", ""]
    if not report["settings_only"]:
        lines += ["When not to ship the result: a refused or partial verdict; agreement that fell; shares that moved "
                  "toward one class at all ranges (the network calling everything a car is self-consistent too).", ""]
    return "\n".join(lines)


def _agreement_cell(row: dict) -> str:
    if row["mean"] is None:
        return "no proposals"
    interval = row["interval"]
    low, high = (interval.get("low"), interval.get("high")) if isinstance(interval, dict) else (None, None)
    bounds = f" [{_pct(low)}, {_pct(high)}]" if low is not None and high is not None else ""
    return (f"{_pct(row['mean'])} % ({_pct(row['min'])}..{_pct(row['max'])}){bounds}, "
            f"{sum(row['proposals'])} proposals")


def _draw_cell(check: dict | None, key: str) -> str:
    row = ((check or {}).get("draw_agreement") or {}).get(key)
    if not row or row["share"] is None:
        return "-"
    return f"{_pct(row['share'])} % of {row['proposals']}"


def _guard_cell(guard: dict) -> str:
    d = guard["draws"]["mean_iou"]
    return f"{_pct(d['mean'])} ({_pct(d['min'])}..{_pct(d['max'])})"
