"""What ``evp info`` reports about a dataset."""

from __future__ import annotations

import numpy as np

from evp.io.dataset import Dataset


def _rate(stamps: np.ndarray) -> float | None:
    if len(stamps) < 2:
        return None
    return float((len(stamps) - 1) / (stamps[-1] - stamps[0])) if stamps[-1] > stamps[0] else None


def summarise(dataset: Dataset) -> dict:
    """JSON-ready description of a dataset (nothing is decoded but headers)."""
    out: dict = {"name": dataset.name, "format": dataset.format, "path": str(dataset.root), "frames": dataset.num_frames}
    if dataset.num_frames:
        t = dataset.frame_times
        out.update(start_s=float(t[0]), duration_s=float(t[-1] - t[0]), rate_hz=_rate(t))
    sensors = {}
    for name, attribute in (
        ("imu", "imu"),
        ("gps", "gps"),
        ("baro", "baro"),
        ("wheel", "wheel"),
        ("wifi", "wifi"),
        ("range", "ranges"),
        ("beacon", "beacon_ranges"),
    ):
        records = getattr(dataset, attribute)
        if records:
            stamps = np.array([r.timestamp for r in records])
            sensors[name] = {"samples": len(records), "rate_hz": _rate(stamps), "duration_s": float(stamps[-1] - stamps[0])}
    out["sensors"] = sensors
    if dataset.beacons:
        out["beacons"] = {name: list(position) for name, position in dataset.beacons.items()}
    if dataset.camera is not None:
        c = dataset.camera
        out["calibration"] = {
            "name": c.name,
            "width": c.width,
            "height": c.height,
            "fx": c.fx,
            "fy": c.fy,
            "cx": c.cx,
            "cy": c.cy,
            "lens": c.lens.value,
            "distortion": c.distortion.tolist(),
        }
    else:
        out["calibration"] = None
    gt = dataset.ground_truth
    if gt is not None:
        out["ground_truth"] = {
            "poses": len(gt),
            "duration_s": gt.duration if gt.timestamps is not None else None,
            "path_length_m": gt.path_length,
            "rate_hz": _rate(gt.timestamps) if gt.timestamps is not None else None,
            "note": dataset.ground_truth_note,
        }
    else:
        out["ground_truth"] = None
    if dataset.trajectories:
        out["trajectories"] = {
            name: {"poses": len(t), "path_length_m": t.path_length, "duration_s": t.duration if t.timestamps is not None else None}
            for name, t in dataset.trajectories.items()
        }
    out["notes"] = list(dataset.notes)
    out["warnings"] = list(dataset.warnings)
    return out


def _duration(seconds: float | None) -> str:
    """A trajectory's time span, or that it has none (KITTI poses: 0.00 s would read as a fact)."""
    return "no times (KITTI poses: evp eval takes --ref-times/--est-times)" if seconds is None else f"{seconds:.2f} s"


def describe(summary: dict) -> str:
    """Human-readable text of :func:`summarise`'s output."""
    lines = [f"{summary['name']}  [{summary['format']}]  {summary['path']}"]
    if summary["frames"]:
        rate = f"{summary['rate_hz']:.2f} Hz" if summary.get("rate_hz") else "n/a"
        lines.append(f"  camera frames: {summary['frames']}, rate {rate}, duration {summary['duration_s']:.2f} s")
    else:
        lines.append("  camera frames: none")
    for name, s in summary["sensors"].items():
        rate = f"{s['rate_hz']:.1f} Hz" if s["rate_hz"] else "n/a"
        lines.append(f"  {name}: {s['samples']} samples, {rate}, {s['duration_s']:.2f} s")
    for name, position in summary.get("beacons", {}).items():
        lines.append(f"  beacon {name}: at ({', '.join(f'{v:.3f}' for v in position)}) m")
    c = summary["calibration"]
    if c:
        d = ", ".join(f"{v:g}" for v in c["distortion"])
        lines.append(
            f"  calibration: {c['name']} {c['width']}x{c['height']} fx {c['fx']:.3f} fy {c['fy']:.3f} cx {c['cx']:.3f} cy {c['cy']:.3f} {c['lens']} [{d}]"
        )
    else:
        lines.append("  calibration: none")
    g = summary["ground_truth"]
    if g:
        lines.append(f"  ground truth: {g['poses']} poses, {_duration(g['duration_s'])}, path length {g['path_length_m']:.3f} m ({g['note']})")
    else:
        lines.append("  ground truth: none")
    for name, t in summary.get("trajectories", {}).items():
        lines.append(f"  trajectory {name}: {t['poses']} poses, {t['path_length_m']:.3f} m, {_duration(t['duration_s'])}")
    lines += [f"  note: {n}" for n in summary["notes"]]
    lines += [f"  warning: {w}" for w in summary["warnings"]]
    return "\n".join(lines)
