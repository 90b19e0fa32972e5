"""`evp eval` against evo 1.38 on the shared reference trajectories: do they agree, and which is
faster? Both read, associate, align and compute APE and RPE in the same process, best of 3.

Usage: python bench/eval_vs_evo.py

Prints per trajectory pair: alignment, APE RMSE, the largest absolute difference from evo over
APE and RPE statistics, both times and their ratio. Needs ../shared/data and evo (the test extra);
seconds.
"""

from __future__ import annotations

import copy
import time
from pathlib import Path

from evo.core import metrics, sync
from evo.tools import file_interface
from results import Results

from evp.config import EvalSettings
from evp.eval.evaluate import evaluate
from evp.io.trajectory import read_trajectory

ROOT = Path(__file__).resolve().parents[2] / "shared" / "data" / "reference_trajectories"
PAIRS = [
    ("tum_fr1_xyz/groundtruth.txt", "tum_fr1_xyz/est_rgbdslam.txt", "se3"),
    ("tum_fr2_desk/groundtruth.txt", "tum_fr2_desk/est_orbslam.txt", "sim3"),
    ("euroc_v1_02/groundtruth_euroc.csv", "euroc_v1_02/est_tum.txt", "se3"),
    ("euroc_v1_01/groundtruth_body_20hz_tum.txt", "euroc_v1_01/est_openvins_tum.txt", "sim3"),
]


def _evo(ref_path: Path, est_path: Path, align: str) -> dict:
    read = file_interface.read_euroc_csv_trajectory if ref_path.suffix == ".csv" else file_interface.read_tum_trajectory_file
    ref, est = sync.associate_trajectories(read(str(ref_path)), file_interface.read_tum_trajectory_file(str(est_path)))
    est = copy.deepcopy(est)
    est.align(ref, correct_scale=align == "sim3")
    ape = metrics.APE(metrics.PoseRelation.translation_part)
    ape.process_data((ref, est))
    rpe = metrics.RPE(metrics.PoseRelation.translation_part, 1, metrics.Unit.frames)
    rpe.process_data((ref, est))
    return {"ape": ape.get_all_statistics(), "rpe": rpe.get_all_statistics()}


def _ours(ref_path: Path, est_path: Path, align: str) -> dict:
    summary = evaluate(read_trajectory(ref_path), read_trajectory(est_path), EvalSettings(align=align, max_time_diff_s=0.01)).summary()
    return {"ape": summary["ape_translation_m"], "rpe": summary["rpe"]["translation_m"]}


def _timed(function, *args, repeats: int = 3):
    best, result = float("inf"), None
    for _ in range(repeats):
        start = time.perf_counter()
        result = function(*args)
        best = min(best, time.perf_counter() - start)
    return best, result


COLUMNS = [
    ("reference / estimate", "{pair}"),
    ("align", "{align}"),
    ("APE RMSE (m)", "{ape_rmse_m:.6f}"),
    ("max abs difference vs evo", "{max_difference:.1e}"),
    ("evp time (s)", "{evp_s:.3f}"),
    ("evo time (s)", "{evo_s:.3f}"),
    ("evo / evp", "{evo_to_evp:.1f}x"),
]


def main() -> None:
    print("command: python bench/eval_vs_evo.py   (read + associate + align + APE + RPE, best of 3, same process)\n")
    table = Results("eval_vs_evo", "python bench/eval_vs_evo.py").table(
        "pairs", COLUMNS, key=["pair", "align"], caption="Read, associate, align, APE and RPE; best of 3 in one process"
    )
    print(table.header())
    for ref, est, align in PAIRS:
        t_ours, ours = _timed(_ours, ROOT / ref, ROOT / est, align)
        t_evo, theirs = _timed(_evo, ROOT / ref, ROOT / est, align)
        diff = max(abs(ours[m][k] - theirs[m][k]) for m in ("ape", "rpe") for k in ("rmse", "mean", "median", "std", "min", "max"))
        record = {
            "pair": f"{ref} / {Path(est).name}",
            "align": align,
            "ape_rmse_m": ours["ape"]["rmse"],
            "max_difference": diff,
            "evp_s": t_ours,
            "evo_s": t_evo,
        }
        print(table.add({**record, "evo_to_evp": t_evo / t_ours}))


if __name__ == "__main__":
    main()
