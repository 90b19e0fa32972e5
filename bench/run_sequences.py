"""`evp run` on every shared image sequence with ground truth, plus a rendered seed-000 circle at
640x380: one Markdown table (the SLAM issue's bench).

Usage: python bench/run_sequences.py [--out runs/bench] [--estimator auto|slam|klt-vo] [--only NAME ...]

Also: relocalisation on EuRoC MH01 after a forced loss (`evp.slam.trials`).

Speed is reported as measured in the same run: tracking ms/frame (median, p95; for SLAM without
the inline mapping, which is listed apart) and its ratio to OpenCV's own ORB (same feature count)
timed on the same frames.
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

from evp.config import Settings
from evp.io.registry import open_dataset
from evp.pipeline import run_dataset, write_outputs
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


TABLE_HEADER = (
    "| sequence | estimator | ATE Sim3 (m) | ATE / path | tracked (in trajectory.tum; answered live) | frames to initialise | ms/frame median | p95 | ratio to OpenCV ORB "
    "| mapping ms/keyframe | loops closed | peak memory so far (MB) |\n" + "|---" * 12 + "|"
)


def _row(name: str, path: Path, settings: Settings, out: Path) -> str:
    dataset = open_dataset(path)
    settings = resolve_settings(settings, dataset)
    estimator = make_estimator(camera_for(dataset, settings), settings, dataset)
    result = run_dataset(dataset, estimator, None, settings.orb.n_features)
    metrics = write_outputs(result, dataset, settings, out / name)
    timing = json.loads((out / name / "timing.json").read_text())
    ate = f"{metrics['rmse']:.4f}" if "rmse" in metrics else "n/a"
    share = f"{100 * metrics['rmse'] / metrics['reference_path_length_m']:.2f} %" if "rmse" in metrics else "n/a"
    mapping = f"{timing['mapping_ms_median']:.0f}" if "mapping_ms_median" in timing else "-"
    loops = len(metrics["loop_closures"]) if "loop_closures" in metrics else "-"
    kind = type(estimator).__name__
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    return (
        f"| {name} | {kind} | {ate} | {share} | {100 * metrics['tracked_fraction']:.1f} % ({metrics['tracked_frames']}/{metrics['frames']}; {metrics['tracked_live_frames']} live) | {metrics['init_frame']} "
        f"| {timing['tracking_ms_median']:.1f} | {timing['tracking_ms_p95']:.1f} | {timing.get('tracking_to_orb_ratio', float('nan')):.2f} | {mapping} | {loops} | {peak:.0f} |"
    )


def _relocalisation(path: Path) -> str:
    """Map the first 150 frames, cover the lens for 3, show frames 100-119 again."""
    from evp.slam.system import SlamSystem
    from evp.slam.trials import cover_lens_then_revisit, relocalisation_error

    dataset = open_dataset(path)
    frames = list(itertools.islice(dataset.frames(), 150))
    settings = Settings()
    first, again = cover_lens_then_revisit(SlamSystem(dataset.camera, settings.orb, settings.slam), frames, 150, slice(100, 120))
    result = relocalisation_error(first, again, slice(100, 120))
    if result is None:
        return f"| {path.name} | not relocalised in 20 frames | | |"
    index, distance, angle = result
    return f"| {path.name} | {index + 1} | {distance:.4f} | {angle:.3f} |"


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
    print(
        f"command: python bench/run_sequences.py --out {args.out} --estimator {args.estimator}{only}{changed}{seeds}  ({platform.node()}, {platform.machine()})\n"
    )
    print(TABLE_HEADER)
    for name in args.only or SEQUENCES:
        path = SHARED / name
        if not path.exists():
            print(f"| {name} | missing |" + " |" * 10)
            continue
        print(_row(name, path, settings, args.out))
        sys.stdout.flush()
    euroc = SHARED / SEQUENCES[0]
    if euroc.exists() and not args.only:
        print("\n| relocalisation after a covered lens | frames to relocalise | position vs first pass (map units) | rotation (deg) |")
        print("|---|---|---|---|")
        print(_relocalisation(euroc))
    if circle_seeds:
        print()
        print(TABLE_HEADER)
    for seed in circle_seeds:
        with tempfile.TemporaryDirectory() as tmp:
            circle = render_circle(Path(tmp) / "circle", seed)
            print(_row(f"sim circle-indoor 640x380 (26 s, one lap, seed {seed})", circle, settings, args.out), flush=True)
            if seed == circle_seeds[0] and not args.only:
                print(_row("sim circle-indoor 640x380, VO mode", circle, Settings(estimator="klt-vo"), args.out), flush=True)


if __name__ == "__main__":
    main()
