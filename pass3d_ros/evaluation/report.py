"""Reports of an evaluation: the summary dict of a live run (`score`) and plain-text tables of the stage-1,
full-pipeline and live summaries that `pass3d_evaluate`, the demo and the benchmarks print."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from pass3d_ros.classes import FOREGROUND
from pass3d_ros.core.metrics import format_metrics, format_objects, interval_text, percent_text
from pass3d_ros.core.stage1 import STEPS
from pass3d_ros.evaluation.live import LiveResult

CAR_VEHICLES_IGNORED = "car (vans/trucks ignored)"  # the table's row of car scored without non-car vehicles


def _stats(values: list[float]) -> dict[str, float] | None:
    if not values:
        return None
    v = np.asarray(values, dtype=np.float64)
    return {"median": float(np.median(v)), "mean": float(v.mean()), "p95": float(np.percentile(v, 95)),
            "max": float(v.max())}


def score(result: LiveResult) -> dict:
    """Per-class precision / recall / IoU (with frame bootstrap intervals) and mean IoU (foreground classes) plus
    the `live` counters and times."""
    summary = result.confusion.summary_with_intervals(FOREGROUND)
    has_truth = result.labeled_frames > 0
    stage1 = [f.stage1_ms for f in result.frames if f.stage1_ms is not None]
    stage2 = [f.stage2_ms for f in result.frames if f.stage2_ms is not None]
    return {
        "frames": result.labeled_frames,
        "per_class": summary["per_class"] if has_truth else None,
        "mean_iou": summary["mean_iou"] if has_truth else None,
        "mean_iou_interval": summary["mean_iou_interval"] if has_truth else None,
        "live": {
            "lockstep": result.lockstep,
            "rate": result.rate,
            "frames_in": result.frames_in,
            "frames_out": result.frames_out,
            "dropped": result.dropped,
            "mismatched": result.mismatched,
            "timeouts": result.timeouts,
            "skipped": result.skipped,
            "unmatched_outputs": result.unmatched_outputs,
            "wall_s": result.wall_s,
            "output_hz": result.frames_out / result.wall_s if result.wall_s > 0 else None,
            "latency_ms": _stats(result.latency_ms),
            "stage_ms": {"stage1": _stats(stage1), "stage2": _stats(stage2)},
            "nodes": result.node_counters,
        },
    }


def _ms(stats: dict | None) -> str:
    return "n/a" if stats is None else f"median {stats['median']:.1f} ms, p95 {stats['p95']:.1f} ms"


def format_report(scores: dict) -> str:
    """A plain-text table of a `score` dict: per-class P / R / IoU (%), mean IoU, live counters and times."""
    if scores.get("per_class"):
        lines = format_metrics(scores["per_class"], scores["mean_iou"], scores.get("mean_iou_interval"))
    else:
        lines = ["no ground-truth labels: no segmentation metrics"]
    live = scores["live"]
    mode = "lockstep" if live["lockstep"] else f"rate x{live['rate']:g}"
    lines.append(
        f"live ({mode}): {live['frames_in']} in, {live['frames_out']} out, {live['dropped']} dropped, "
        f"{live['mismatched']} mismatched, {live['timeouts']} timeouts, {live['skipped']} skipped"
    )
    lines.append(f"latency publish -> /pass3d/labeled: {_ms(live['latency_ms'])}")
    lines.append(f"stage 1 (publish -> /pass3d/proposals): {_ms(live['stage_ms']['stage1'])}")
    lines.append(f"stage 2 (/pass3d/proposals -> /pass3d/labeled): {_ms(live['stage_ms']['stage2'])}")
    return "\n".join(lines)


def _fmt(value: float | None, digits: int = 3) -> str:
    return "n/a" if value is None else f"{value:.{digits}f}"


def _budget_line(budget: dict | None, would: bool = False) -> list[str]:
    """The line saying how many proposals stage 2's budget cut (stage 1 alone: would cut)."""
    if not budget:
        return []
    what = "stage 2's budget would cut" if would else "cut by the budget"
    return [f"proposals {what} (max_proposals {budget['max_proposals']}, nearest first): "
            f"{budget['proposals_cut']} in {budget['frames_cut']} frame(s)"]


def format_stage1(summary: dict, per_frame: bool = False) -> str:
    """Human-readable table of a stage 1 summary."""
    s = summary["stage1"]
    lines = [f"stage 1 over {summary['frames']} frame(s)"]
    rows = [
        ("foreground recall", _fmt(s["foreground_recall"]) + f"  ({s['foreground_points']} points)"),
        *[(f"  {name} recall", _fmt(value)) for name, value in s["class_recall"].items()],
        ("proposals / frame", f"median {_fmt(s['proposals_per_frame']['median'], 1)}, "
                              f"mean {_fmt(s['proposals_per_frame']['mean'], 1)}"),
        ("ms / frame", f"median {_fmt(s['ms_per_frame']['median'], 2)}, mean {_fmt(s['ms_per_frame']['mean'], 2)}"),
        *[(f"  {step} ms (median)", _fmt(s["ms_per_step"].get(step), 2)) for step in STEPS if step != "total"],
        ("ground precision", _fmt(s["ground"]["precision"]) + f"  ({s['ground_frames']} frame(s) with ground truth)"),
        ("ground recall", _fmt(s["ground"]["recall"])),
    ]
    width = max(len(name) for name, _ in rows)
    lines += [f"  {name:<{width}}  {value}" for name, value in rows]
    lines += [f"  {line}" for line in _budget_line(summary.get("budget"), would=True)]
    lines += [f"  {line}" for line in mounting_lines(summary.get("mounting"))]
    if per_frame:
        lines.append("")
        lines.append(f"  {'frame':<48} {'points':>7} {'props':>5} {'ms':>6} {'fg rec':>6} {'gnd P':>6} {'gnd R':>6}")
        for row in summary["per_frame"]:
            lines.append(
                f"  {row['frame'][-48:]:<48} {row['points']:>7} {row['proposals']:>5} {row['ms']:>6.2f} "
                f"{_fmt(row.get('foreground_recall')):>6} {_fmt(row.get('ground_precision')):>6} "
                f"{_fmt(row.get('ground_recall')):>6}"
            )
    return "\n".join(lines)


def _classifier_line(summary: dict) -> str:
    c = summary["classifier"]
    what = "size_rules (geometric baseline)" if c["kind"] == "size_rules" else f"network, weights {c['weights']}"
    return f"classifier: {what}; device {c['device']}, torch threads {c['threads']}"


def _stage_ms_line(ms: dict) -> str:
    return (f"ms / frame (median): stage 1 {_fmt(ms['stage1'], 1)}, stage 2 {_fmt(ms['stage2'], 1)}, "
            f"total {_fmt(ms['total'], 1)}")


def format_full(summary: dict, per_frame: bool = False) -> str:
    """Human-readable table of a full-pipeline summary: per-class metrics, stage times, stage-1 recap."""
    s1 = summary["stage1"]
    lines = [f"full pipeline over {summary['frames']} frame(s)", _classifier_line(summary)]
    relaxed = summary.get("car_vehicles_ignored")
    extra = [("car", CAR_VEHICLES_IGNORED, relaxed)] if relaxed else []
    lines += format_metrics(summary["classes"], summary["mean_iou"], summary.get("mean_iou_interval"), extra)
    if relaxed:
        lines.append(f"{CAR_VEHICLES_IGNORED}: {relaxed['ignored_points']} background points on vans / trucks / "
                     f"buses left out, in {relaxed['frames_with_vehicles']} frame(s); {relaxed['frames_known']} of "
                     f"{summary['frames']} frame(s) from readers that mark such vehicles")
    lines += format_objects(summary.get("objects"))
    lines.append(_stage_ms_line(summary["ms_per_frame"]))
    lines.append(f"stage 1: foreground recall {_fmt(s1['foreground_recall'])}, proposals / frame median "
                 f"{_fmt(s1['proposals_per_frame']['median'], 1)}")
    background = summary.get("background_proposals")
    if background:
        lines.append(f"background-only front-view proposals called an object: {background['called_object']} of "
                     f"{background['front_view']}")
    lines += _budget_line(summary.get("budget"))
    lines += [f"intensity of {spec}: {text}" for spec, text in (summary.get("intensity") or {}).items()]
    lines += mounting_lines(summary.get("mounting"))
    lines += format_draws(summary.get("draws"))
    if per_frame:
        lines.append("")
        lines.append(f"  {'frame':<48} {'points':>7} {'props':>5} {'s1 ms':>7} {'s2 ms':>7} {'mIoU':>6}")
        for row in summary["per_frame"]:
            lines.append(f"  {row['frame'][-48:]:<48} {row['points']:>7} {row['proposals']:>5} "
                         f"{row['stage1_ms']:>7.1f} {row['stage2_ms']:>7.1f} {_fmt(row['mean_iou']):>6}")
    return "\n".join(lines)


def mounting_lines(mountings: dict | None) -> list[str]:
    """One line per spec of the "mounting" section: the sensor's height and tilt its stream read
    (pass3d_ros.core.stage1.mounting), held or from how many scans so far."""
    return [f"mounting of {spec}: sensor {m['height_m']:.2f} m above the ground, tilted {m['tilt_deg']:.1f} deg "
            f"(roll {m['roll_deg']:.1f}, pitch {m['pitch_deg']:.1f}; "
            + ("held" if m["held"] else f"{m['scans']} scan(s), not yet held") + ")"
            for spec, m in (mountings or {}).items()]


def _draw_row(name: str, row: dict, key: str = "iou") -> str:
    """One line of the draws table: each draw's value (`key`), their mean and min..max, in %."""
    each = " ".join(f"{percent_text(v):>6}" for v in row[key])
    span = "n/a" if row["min"] is None else f"{percent_text(row['min']).strip()}..{percent_text(row['max']).strip()}"
    return f"{name:<12}{each}  {percent_text(row['mean']):>6}  {span}"


def format_draws(draws: dict | None) -> list[str]:
    """Table lines of the "draws" section: per class (and the mean IoU) the IoU % (or, in a view-agreement run,
    the agreement %) of each N-point sample draw, their mean and the draw-to-draw range; none without draws."""
    if not draws:
        return []
    count, key = draws["count"], draws.get("measure", "iou")
    measure = "view agreement" if key == "agreement" else "IoU"
    lines = ["", f"{measure} % over {count} draws of the N-point sample (the table above is draw 0):",
             f"{'class':<12}" + " ".join(f"{'d' + str(d):>6}" for d in range(count))
             + f"  {'mean':>6}  draw-to-draw range"]
    lines += [_draw_row(name, row, key) for name, row in draws["classes"].items()]
    if "mean_iou" in draws:
        lines.append(_draw_row("mean IoU", draws["mean_iou"], key))
    return lines


def format_live(summary: dict, per_frame: bool = False) -> str:
    """Human-readable report of a live summary (per-class metrics, counters, latency, stage times)."""
    report = format_report({"per_class": summary["classes"], "mean_iou": summary["mean_iou"],
                            "mean_iou_interval": summary.get("mean_iou_interval"), "live": summary["live"]})
    lines = [f"live pipeline over {summary['frames']} scored frame(s)", _classifier_line(summary), report,
             _stage_ms_line(summary["ms_per_frame"])]
    if summary["record_out"]:
        lines.append(f"recorded /pass3d/labeled -> {summary['record_out']}")
    return "\n".join(lines)


def _per_10s(row: dict, what: str) -> str:
    """One flicker row: class changes per object per 10 s, scan-by-scan and voted, and how much the vote removed."""
    if row["per_10s_scan"] is None:
        return f"  {what}: none seen twice"
    cut = "" if row["reduction"] is None else f", {100.0 * row['reduction']:.0f} % fewer"
    return (f"  {what}: {row['per_10s_scan']:.2f} scan-by-scan -> {row['per_10s_voted']:.2f} voted class changes per "
            f"object per 10 s ({row['changes_scan']} -> {row['changes_voted']} changes, {row['objects']} objects, "
            f"{row['life_s']:.1f} s of life{cut})")


def format_tracking(summary: dict, per_frame: bool = False) -> str:
    """Human-readable `--tracking` run: IoU scan-by-scan and voted with the paired difference, flicker, id switches
    and fragmentations, the tracks' own flicker."""
    lines = [f"objects over time: {summary['frames']} frame(s), tracker on", _classifier_line(summary)]
    for spec, row in summary["streams"].items():
        lines.append(f"  {spec}: {row['frames']} scans, period {row['scan_period_s']:.3f} s (from "
                     f"{row['period_from']}), {row['frames_with_pose']} with a pose")
    if summary.get("iou"):
        lines.append("IoU %: scan-by-scan, voted, voted minus scan-by-scan [paired 90 % frame bootstrap interval]")
        for name, row in summary["iou"].items():
            diff = "n/a" if row["difference"] is None else f"{100.0 * row['difference']:+.1f}"
            lines.append(f"  {name:<11} {percent_text(row['scan']):>6} {percent_text(row['voted']):>6} {diff:>6}  "
                         f"{interval_text(row)}")
    if summary.get("flicker"):
        lines.append(_per_10s(summary["flicker"], "ground-truth objects"))
        mot, most = summary["mot"], summary["mot_most_points"]
        if mot["object_tracks"]:
            lines.append(f"  id switches {mot['id_switches']} ({mot['id_switches_per_100']:.1f} per 100 object-tracks),"
                         " "
                         f"fragmentations {mot['fragmentations']} ({mot['fragmentations_per_100']:.1f} per 100), "
                         f"{mot['object_tracks']} object-tracks, {mot['matched']} of {mot['sightings']} sightings "
                         "matched (CLEAR-MOT: object and instance hold more than half of each other's points)")
            lines.append(f"  by the object holding most of each instance's points: id switches {most['id_switches']} "
                         f"({most['id_switches_per_100']:.1f} per 100), fragmentations {most['fragmentations']} "
                         f"({most['fragmentations_per_100']:.1f} per 100), {most['matched']} matched")
    elif summary.get("instances"):
        lines.append(f"  instances {summary['instances']}")
    lines.append(_per_10s(summary["track_flicker"], "tracks (label-free)"))
    ms = summary["track_ms"]
    if ms["median"] is not None:
        lines.append(f"tracker + vote: median {ms['median']:.2f} ms a scan, max {ms['max']:.2f} ms")
    if per_frame:
        lines += [f"  {row['frame'][-48:]}" for row in summary.get("per_frame", [])]
    return "\n".join(lines)


def format_agreement(summary: dict, per_frame: bool = False) -> str:
    """Human-readable view agreement: per class, the share of proposals all 8 views agree on."""
    lines = [f"view agreement over {summary['frames']} frame(s) (labels unused)", _classifier_line(summary)]
    for name, row in summary["agreement"].items():
        lines.append(f"  {name:<11} {percent_text(row['agreement']):>6} % of {row['proposals']:>5} proposals  "
                     f"{interval_text(row['interval'])}")
    lines.append("proposals counted under the class most of their 8 views give them; 90 % frame bootstrap intervals")
    lines += [f"intensity of {spec}: {text}" for spec, text in (summary.get("intensity") or {}).items()]
    lines += format_draws(summary.get("draws"))
    if per_frame:
        lines += [f"  {row['frame'][-48:]:<48} {row['proposals']:>5}" for row in summary["per_frame"]]
    return "\n".join(lines)


PRINTERS: dict[str, Callable[..., str]] = {"stage1": format_stage1, "full": format_full, "live": format_live,
                                           "view_agreement": format_agreement, "tracking": format_tracking}
