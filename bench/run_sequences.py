"""`evp run` on every shared image sequence with ground truth and on a rendered 640x380 circle:
accuracy, how much is tracked, and speed. The main bench of the SLAM engine.

Each sequence goes through the same code as `evp run` (estimator `auto`: SLAM for video, the
nadir mosaic odometry and survey adjustment for survey photos), mapping inline, so ATE and
tracking are deterministic; milliseconds are not. Also relocalisation on EuRoC MH01 after a covered
lens (first 150 frames mapped, 3 frames black, frames 100-119 shown again; the trial lives in
`tests/slam/relocalisation_trials.py`, shared with the tests), and the circle (seed 1,
26 s, one lap, rendered by `evp sim`) with the light VO as well.

Usage: python bench/run_sequences.py [--out runs/bench] [--estimator auto|slam|klt-vo] [--only SEQ ...] [--set SECTION.KEY=VALUE ...] [--circle-seeds N ...]

Prints one Markdown row per sequence: ATE (Sim3-aligned RMSE, m; against GPS for the Toledo
photos) and as a share of the path, frames tracked in trajectory.tum and answered live, frames to
initialise, tracking ms per frame (median, p95; without inline mapping, which is listed apart as
mapping ms per keyframe), its ratio to OpenCV's own ORB timed on the same frames (the steadier
speed figure), loops closed and peak memory. `--only` runs just those sequences (no
relocalisation, no circle unless `--circle-seeds`); `--set` changes a setting for the run (its
rows are kept apart from the defaults'). Needs ../shared/data (missing sequences are listed as
such). `evp run`'s outputs for each sequence go to `--out`.
"""

from __future__ import annotations

import argparse
import itertools
import json
import platform
import resource
import sys
import tempfile
from pathlib import Path

import yaml
from pydantic import ValidationError
from results import Results

from evp.config import Settings
from evp.io.registry import open_dataset
from evp.io.run_outputs import write_outputs
from evp.pipeline import run_dataset
from evp.run_setup import camera_for, make_estimator, resolve_settings

SHARED = Path(__file__).resolve().parents[2] / "shared" / "data"
SEQUENCES = ["euroc_mh_01_easy_moving_360", "kitti_odom_06_f000-050", "davis_slider_depth", "aerial_nadir_odm_toledo_fc350"]


def render_circle(folder: Path, seed: int = 1) -> Path:
    from evp.sim.generate import generate
    from evp.sim.scenarios import SimOptions

    # 26 s: standing 2 s, one lap of the 2.2 m circle (~20 s), then 1.5 m over the start again,
    # so the circle closes as seed 000's did (20 s stopped 0.6 m short of the start)
    generate("circle-indoor", SimOptions(duration_s=26.0, fps=30.0, seed=seed), folder, workers=2)
    return folder


COLUMNS = [
    ("sequence", "{sequence}"),
    ("estimator", "{estimator}"),
    ("ATE Sim3 (m)", "{ate_m:.4f}"),
    ("ATE / path", "{ate_path_percent:.2f} %"),
    ("tracked (in trajectory.tum; answered live)", "{tracked_percent:.1f} % ({tracked_frames}/{frames}; {tracked_live_frames} live)"),
    ("frames to initialise", "{init_frame}"),
    ("ms/frame median", "{tracking_ms_median:.1f}"),
    ("p95", "{tracking_ms_p95:.1f}"),
    ("ratio to OpenCV ORB", "{orb_ratio:.2f}"),
    ("mapping ms/keyframe", "{mapping_ms_median:.0f}"),
    ("loops closed", "{loops_closed}"),
    ("peak memory so far (MB)", "{peak_memory_mb:.0f}"),
]
RELOCALISATION_COLUMNS = [
    ("relocalisation after a covered lens", "{sequence}"),
    ("frames to relocalise", "{frames_to_relocalise}"),
    ("position vs first pass (map units)", "{position_error:.4f}"),
    ("rotation (deg)", "{rotation_error_deg:.3f}"),
]


def _record(name: str, path: Path, settings: Settings, out: Path) -> dict:
    dataset = open_dataset(path)
    settings = resolve_settings(settings, dataset)
    estimator = make_estimator(camera_for(dataset, settings), settings, dataset)
    result = run_dataset(dataset, estimator, None, settings.orb.n_features)
    metrics = write_outputs(result, dataset, settings, out / name)
    timing = json.loads((out / name / "timing.json").read_text())
    return {
        "sequence": name,
        "estimator": type(estimator).__name__,
        "ate_m": metrics.get("rmse"),
        "ate_path_percent": 100 * metrics["rmse"] / metrics["reference_path_length_m"] if "rmse" in metrics else None,
        "tracked_percent": 100 * metrics["tracked_fraction"],
        "tracked_frames": metrics["tracked_frames"],
        "frames": metrics["frames"],
        "tracked_live_frames": metrics["tracked_live_frames"],
        "init_frame": metrics["init_frame"],
        "tracking_ms_median": timing["tracking_ms_median"],
        "tracking_ms_p95": timing["tracking_ms_p95"],
        "orb_ratio": timing.get("tracking_to_orb_ratio"),
        "mapping_ms_median": timing.get("mapping_ms_median"),
        "loops_closed": len(metrics["loop_closures"]) if "loop_closures" in metrics else None,
        "peak_memory_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
    }


def _relocalisation(path: Path) -> dict:
    """Map the first 150 frames, cover the lens for 3, show frames 100-119 again."""
    from evp.io.vocabulary_files import load_configured_vocabulary
    from evp.slam.system import SlamSystem

    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the relocalisation trials the tests use
    from tests.slam.relocalisation_trials import cover_lens_then_revisit, relocalisation_error

    dataset = open_dataset(path)
    frames = list(itertools.islice(dataset.frames(), 150))
    settings = Settings()
    first, again = cover_lens_then_revisit(
        SlamSystem(dataset.camera, settings.orb, settings.slam, vocabulary=load_configured_vocabulary(settings.slam.vocabulary)), frames, 150, slice(100, 120)
    )
    result = relocalisation_error(first, again, slice(100, 120))
    if result is None:
        return {"sequence": path.name, "frames_to_relocalise": "not relocalised in 20", "position_error": None, "rotation_error_deg": None}
    index, distance, angle = result
    return {"sequence": path.name, "frames_to_relocalise": index + 1, "position_error": distance, "rotation_error_deg": angle}


def settings_with_changes(estimator: str, changes: list[str]) -> Settings:
    """The default settings with ``SECTION.KEY=VALUE`` changes (values parsed as YAML scalars)."""
    data: dict = {"estimator": estimator}
    for change in changes:
        key, _, value = change.partition("=")
        section, _, name = key.partition(".")
        if not name or not value:
            raise SystemExit(f"--set takes SECTION.KEY=VALUE, got {change!r}")
        data.setdefault(section, {})[name] = yaml.safe_load(value)
    try:
        return Settings.model_validate(data)
    except ValidationError as exc:
        raise SystemExit(f"--set: {exc}") from exc


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--out", type=Path, default=Path("runs/bench"))
    parser.add_argument("--estimator", default="auto", choices=["auto", "slam", "klt-vo"])
    parser.add_argument("--only", nargs="+", choices=SEQUENCES, help="just these shared sequences (no relocalisation; no circle unless --circle-seeds)")
    parser.add_argument("--set", nargs="+", default=[], metavar="SECTION.KEY=VALUE", help="settings to change, e.g. slam.mapping=thread")
    parser.add_argument("--circle-seeds", nargs="+", type=int, help="render the circle with these seeds (default: 1; none with --only unless given)")
    args = parser.parse_args()
    circle_seeds = args.circle_seeds or ([] if args.only else [1])
    settings = settings_with_changes(args.estimator, args.set)
    only = f" --only {' '.join(args.only)}" if args.only else ""
    changed = f" --set {' '.join(args.set)}" if args.set else ""
    seeds = f" --circle-seeds {' '.join(map(str, args.circle_seeds))}" if args.circle_seeds else ""
    changes = " ".join(args.set)  # part of each row's key: a run with --set does not replace the defaults' rows
    command = f"python bench/run_sequences.py --out {args.out} --estimator {args.estimator}{only}{changed}{seeds}"
    print(f"command: {command}  ({platform.node()}, {platform.machine()})\n")
    results = Results("run_sequences", command)
    table = results.table("sequences", COLUMNS, key=["sequence", "estimator", "changes"], caption="`evp run` on each sequence (inline mapping, deterministic)")
    print(table.header())
    for name in args.only or SEQUENCES:
        path = SHARED / name
        if not path.exists():
            print(f"| {name} | missing |" + " |" * 10)
            continue
        print(table.add({**_record(name, path, settings, args.out), "changes": changes}))
        sys.stdout.flush()
    euroc = SHARED / SEQUENCES[0]
    if euroc.exists() and not args.only:
        relocalisation = results.table("relocalisation", RELOCALISATION_COLUMNS, key=["sequence", "changes"], caption="Relocalisation after a covered lens")
        print("\n" + relocalisation.header())
        print(relocalisation.add({**_relocalisation(euroc), "changes": changes}))
    if circle_seeds:
        print()
        print(table.header())
    for seed in circle_seeds:
        with tempfile.TemporaryDirectory() as tmp:
            circle = render_circle(Path(tmp) / "circle", seed)
            print(table.add({**_record(f"sim circle-indoor 640x380 (26 s, one lap, seed {seed})", circle, settings, args.out), "changes": changes}), flush=True)
            if seed == circle_seeds[0] and not args.only:
                print(
                    table.add({**_record("sim circle-indoor 640x380, VO mode", circle, Settings(estimator="klt-vo"), args.out), "changes": changes}), flush=True
                )


if __name__ == "__main__":
    main()
