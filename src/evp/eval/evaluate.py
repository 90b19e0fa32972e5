"""One call that turns a reference and an estimate into every number EVP reports."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from evp.config import EvalSettings
from evp.errors import EvaluationError
from evp.eval.association import associate
from evp.eval.metrics import (
    Alignment,
    DeltaUnit,
    RelativeErrors,
    align_trajectory,
    ape_rotation_deg,
    ape_translation,
    ape_translation_xy,
    relative_pose_errors,
)
from evp.eval.plane import Plane, motion_plane
from evp.eval.statistics import error_statistics
from evp.geometry.alignment import Similarity
from evp.types import Trajectory


@dataclass(frozen=True)
class EvaluationResult:
    options: EvalSettings
    ref: Trajectory  # matched reference poses
    est: Trajectory  # matched estimate poses, aligned
    alignment: Similarity
    ape_translation: np.ndarray
    ape_translation_xy: np.ndarray
    ape_rotation_deg: np.ndarray | None  # None: the reference is position-only (options.rotation false), or the alignment degenerate
    rpe: RelativeErrors | None
    plane: Plane
    ape_translation_plane: np.ndarray  # in the plane the reference moves in (or the one options.plane names)
    subset_mask: np.ndarray | None = field(default=None)
    frame_indexed: bool = False  # the "times" are frame numbers (KITTI files without times.txt): figures say so

    def summary(self) -> dict:
        """JSON-ready numbers: APE translation statistics at the top level (the CLI contract)."""
        out: dict = dict(error_statistics(self.ape_translation))
        out["matched_poses"] = len(self.ref)
        out["xy_rmse"] = float(np.sqrt(np.mean(self.ape_translation_xy**2)))
        out["ape_translation_m"] = error_statistics(self.ape_translation)
        out["ape_translation_xy_m"] = error_statistics(self.ape_translation_xy)
        out["plane"] = self.plane.name
        out["plane_rmse"] = float(np.sqrt(np.mean(self.ape_translation_plane**2)))
        out["reference_orientation"] = self.options.rotation
        if self.ape_rotation_deg is not None:
            out["ape_rotation_deg"] = error_statistics(self.ape_rotation_deg)
        if self.rpe is not None:
            out["rpe"] = {
                "delta": self.options.rpe_delta,
                "unit": self.options.rpe_unit,
                "pairs": len(self.rpe.pairs),
                "translation_m": error_statistics(self.rpe.translation),
                "rotation_deg": error_statistics(self.rpe.rotation_deg),
            }
        if self.subset_mask is not None:
            selected = self.ape_translation[self.subset_mask]
            out["subset"] = {
                "rule": f"|z_ref - {self.options.z_target_m}| < {self.options.z_tolerance_m} m",
                "poses": int(self.subset_mask.sum()),
                "ape_translation_m": error_statistics(selected) if selected.size else None,
                "xy_rmse": float(np.sqrt(np.mean(self.ape_translation_xy[self.subset_mask] ** 2))) if selected.size else None,
            }
        out["alignment"] = {
            "mode": self.options.align,
            "n_align": self.options.n_align,
            "scale": self.alignment.scale,
            "rotation": self.alignment.rotation.tolist(),
            "translation": self.alignment.translation.tolist(),
            "degenerate": self.alignment.degenerate,
        }
        out["reference_path_length_m"] = self.ref.path_length
        out["options"] = {
            "align": self.options.align,
            "n_align": self.options.n_align,
            "max_diff_s": self.options.max_time_diff_s,
            "offset_s": self.options.time_offset_s,
            "rpe_delta": self.options.rpe_delta,
            "rpe_unit": self.options.rpe_unit,
            "z_target_m": self.options.z_target_m,
            "z_tolerance_m": self.options.z_tolerance_m,
            "rotation": self.options.rotation,
            "plane": self.options.plane,
        }
        return out


def evaluate(ref: Trajectory, est: Trajectory, options: EvalSettings) -> EvaluationResult:
    """Associate, align, and compute APE (translation, XY, in the path's plane, rotation), RPE and
    the z subset; a position-only reference (``options.rotation`` false) gets no rotation APE or RPE,
    and a degenerate alignment (a straight path: the rotation about it is arbitrary) no rotation APE.

    ``options.max_time_diff_s`` must be a number: a None (the frame-rate default) is resolved
    where the dataset is known (``evp.run_setup.resolve_settings``)."""
    if options.max_time_diff_s is None:
        raise ValueError("max_time_diff_s is unresolved: give the number of seconds (resolve_settings does for a dataset)")
    ref_matched, est_matched = associate(ref, est, options.max_time_diff_s, options.time_offset_s)
    aligned, transform = align_trajectory(ref_matched, est_matched, Alignment(options.align), options.n_align)
    rpe = None
    if options.rotation:  # relative poses are taken in each reference pose's frame: meaningless without its orientation
        try:
            rpe = relative_pose_errors(ref_matched, aligned, options.rpe_delta, DeltaUnit(options.rpe_unit), options.rpe_all_pairs)
        except EvaluationError:
            rpe = None
    plane = motion_plane(ref_matched.positions, options.plane)
    mask = None
    if options.z_target_m is not None:
        mask = np.abs(ref_matched.positions[:, 2] - options.z_target_m) < options.z_tolerance_m
    return EvaluationResult(
        options=options,
        ref=ref_matched,
        est=aligned,
        alignment=transform,
        ape_translation=ape_translation(ref_matched, aligned),
        ape_translation_xy=ape_translation_xy(ref_matched, aligned),
        ape_rotation_deg=ape_rotation_deg(ref_matched, aligned) if options.rotation and not transform.degenerate else None,
        rpe=rpe,
        plane=plane,
        ape_translation_plane=np.linalg.norm(plane.project(aligned.positions - ref_matched.positions), axis=1),
        subset_mask=mask,
    )
