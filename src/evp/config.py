"""Typed settings (pydantic), loaded from YAML; ORB-SLAM-style settings files are understood too.

Every command that writes results writes the effective settings beside them (``settings.yaml``).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Literal

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from evp.errors import ConfigError


class _Section(BaseModel):
    model_config = ConfigDict(extra="forbid", validate_assignment=True)


class OrbSettings(_Section):
    """The ORB extractor parameters the seed 000 operator GUI exposes."""

    n_features: int = Field(1000, ge=50, le=20000, description="features per image")
    pyramid_levels: int = Field(8, ge=1, le=16, description="scale pyramid levels")
    scale_factor: float = Field(1.2, gt=1.0, le=2.0, description="scale between pyramid levels")
    ini_fast_threshold: int = Field(20, ge=1, le=255, description="FAST threshold tried first")
    min_fast_threshold: int = Field(7, ge=1, le=255, description="FAST threshold where a cell has too few corners")


class CameraSettings(_Section):
    """Where the calibration comes from when the dataset has none (or to override it)."""

    calibration_file: Path | None = Field(None, description="OpenCV/ROS/ORB-SLAM/Kalibr calibration file")
    profile: str | None = Field(None, description="named profile shipped with EVP, e.g. nexus5x_640x380")
    fps: float = Field(30.0, gt=0, description="nominal frame rate")
    color_space: Literal["gray", "bgr", "rgb"] = "gray"


class EvalSettings(_Section):
    """How a trajectory is compared with its reference (``evp run``, ``evp eval``; evo's conventions)."""

    align: Literal["none", "se3", "sim3"] = Field("sim3", description="Umeyama alignment of the estimate before the errors are taken")
    n_align: int | None = Field(None, ge=3, description="align on the first N matched poses only")
    max_time_diff_s: float | None = Field(
        None,
        gt=0,
        description="largest time difference of matched poses; None: half the dataset's median frame period, so each estimate matches at most its own frame's stamp (evp run writes the number it used)",
    )
    time_offset_s: float = Field(0.0, description="added to the estimate's stamps")
    rpe_delta: float = Field(1.0, gt=0, description="relative pose error pair distance")
    rpe_unit: Literal["frames", "m"] = "frames"
    rpe_all_pairs: bool = Field(False, description="every pair at the distance, not consecutive ones")
    z_target_m: float | None = Field(None, description="also report the poses whose reference z is within z_tolerance_m of this")
    z_tolerance_m: float = Field(2.0, gt=0)
    rotation: bool = Field(
        True,
        description="the reference measures orientation: APE rotation and RPE are reported; false for position-only references (GPS, 2-D tracks), whose placeholder orientation would give meaningless figures (evp run sets it from the dataset)",
    )
    plane: Literal["auto", "xy", "xz", "yz"] = Field(
        "auto", description="plane of the top view and the in-plane error; auto: the one the reference moves in (evp.eval.plane), e.g. x-z for a KITTI drive"
    )


class VoSettings(_Section):
    """The light keyframe visual odometry (``evp.vo.klt_vo``)."""

    max_features: int = Field(600, ge=50, description="corners kept per keyframe")
    min_feature_distance_px: float = Field(8.0, gt=0)
    init_min_parallax_px: float = Field(12.0, gt=0, description="median KLT displacement needed to initialise")
    init_min_points: int = Field(60, ge=8)
    min_tracked_points: int = Field(25, ge=6, description="fewer PnP inliers than this: tracking is lost")
    keyframe_parallax_px: float = Field(25.0, gt=0, description="median displacement since the keyframe that makes a new one")
    keyframe_min_map_ratio: float = Field(0.6, gt=0, lt=1, description="keyframe when fewer of its 3-D points are still tracked")
    ransac_threshold_px: float = Field(1.0, gt=0)
    min_triangulation_angle_deg: float = Field(1.0, gt=0)
    init_min_angle_deg: float = Field(1.5, gt=0, description="median ray angle the initial map needs")
    init_max_frames: int = Field(60, ge=5, description="frames after which an initialisation reference is replaced")
    max_step_depth_ratio: float = Field(0.5, gt=0, description="largest frame-to-frame step, in median scene depths")


class SlamSettings(_Section):
    """The ORB-SLAM-style engine (``evp.slam``); names follow ORB-SLAM where it has one."""

    mapping: Literal["thread", "inline"] = Field(
        "inline",
        description="inline: each keyframe mapped before the next frame (deterministic; offline runs and replays); thread: a worker fed by a keyframe queue (live)",
    )
    init_min_matches: int = Field(100, ge=20, description="matches to the initial reference needed to try initialising")
    init_search_radius_px: float = Field(100.0, gt=0, description="window for initial matching")
    init_min_parallax_deg: float = Field(
        3.0,
        gt=0,
        description="parallax the initial map needs (ORB-SLAM: 1); at 3 its depths are known to ~4 % instead of ~12 % (1 px at fx 500): a hovering start's 1-degree map bent when live mapping lagged",
    )
    init_min_triangulated: int = Field(50, ge=8)
    start_backfill_frames: int = Field(
        300,
        ge=0,
        description="the refined trajectory localises up to this many frames from before initialisation against the final map (their features are kept until then; 0 = off)",
    )
    homography_ratio: float = Field(0.40, gt=0, lt=1, description="RH above this selects the homography")
    gyro_aided_tracking: bool = Field(
        True,
        description="with an IMU and the camera's mounting on it (a dataset's, or the phone's config live), tracking predicts each frame's rotation with the gyro and holds the pose to it, weighed by navigation.gyro_noise_density and navigation.initial_gyro_bias_sigma (a hand-held pan: 87-96 % tracked without, 100 % with)",
    )
    initial_median_depth_m: float = Field(1.0, gt=0, description="scale of the initial map (a known scene depth, e.g. altitude for a nadir camera)")
    motion_search_radius_px: float = Field(15.0, gt=0, description="guided search window around the motion-model prediction")
    local_map_search_radius_px: float = Field(4.0, gt=0, description="window for local map points (times the level scale)")
    min_tracked_inliers: int = Field(30, ge=6, description="fewer inliers after local-map tracking: LOST")
    min_relocalised_inliers: int = Field(50, ge=10)
    restart_max_keyframes: int = Field(
        5,
        ge=2,
        description="a map of at most this many keyframes that tracking loses was a failed start: discarded and initialised again (ORB-SLAM); a larger map is kept and relocalised against",
    )
    keyframe_max_frames: int = Field(30, ge=1, description="a keyframe at least this often (frames) when tracking is weak")
    keyframe_ref_ratio: float = Field(0.9, gt=0, lt=1, description="a keyframe when tracked points fall below this share of the reference keyframe's")
    keyframe_depth_change: float = Field(
        0.2,
        gt=0,
        description="a keyframe also when the tracked points' median depth differs from the reference keyframe's by this share: moving along the optical axis (a down-looking camera climbing, a car driving on) keeps the reference's points in view, shrinking or spreading over the image, so the tracked share never falls; the rendered square's climb from 7 to 12 m took no keyframe for 6 s and drifted 4 m",
    )
    keyframe_min_interval_s: float = Field(
        0.08,
        ge=0,
        description="an idle mapper takes a keyframe no sooner than this after the last (a weak frame still gets one at once): a live ORB-SLAM mapper is busy about 0.1 s per keyframe, so at 30 Hz and over inline mapping ORB-SLAM's idle rule took one almost every frame and new points came from short baselines",
    )
    covisible_keyframes: int = Field(10, ge=2, description="neighbours used to triangulate new points")
    new_point_min_parallax_deg: float = Field(
        2.0,
        gt=0,
        description="parallax a new map point needs between two keyframes (ORB-SLAM: 1.1); a keyframe's tilt error moves a point's depth by about that error over the parallax, so at 1.1 a 1-degree error on a nadir floor put points off the floor that tracking then followed",
    )
    local_ba_keyframes: int = Field(8, ge=2, description="keyframes optimised by local bundle adjustment")
    ba_evaluations: int = Field(6, ge=1, description="solver evaluations per outlier round")
    keyframe_redundancy: float = Field(0.9, gt=0, le=1, description="a keyframe whose points this share is seen by 3 others is culled")
    loop_closing: bool = Field(True, description="detect returns to mapped places and correct the drift (pose graph + global bundle adjustment)")
    vocabulary: str = Field(
        "", description="bag-of-words vocabulary file for place recognition ('' = the one shipped, trained on EVP's renders; evp vocabulary build)"
    )
    loop_min_matches: int = Field(40, ge=20, description="map point matches that confirm a loop")
    map: str = Field(
        "",
        description="a map saved by an earlier run (its map.npz) to start from: tracking relocalises in it instead of initialising, and a georeferenced map georeferences the run at once ('' = start a new map)",
    )
    map_relocalise_timeout_s: float = Field(
        60.0,
        gt=0,
        description="with slam.map: seconds without relocalising in it before SLAM gives up and starts a new map (a vehicle waits on its pad for a minute; a take-off climbs into the mapped altitudes within seconds)",
    )
    final_bundle_adjustment: bool = Field(
        True,
        description="offline runs: one global bundle adjustment of the whole map before trajectory.tum is written (trajectory_live.tum keeps the live poses)",
    )
    final_ba_points_per_keyframe: int = Field(
        150,
        ge=0,
        description="the final global bundle adjustment sets the poses on each keyframe's this many longest-tracked points, then adjusts the other points on them (0 = every point at once)",
    )


class AlignmentSettings(_Section):
    """The alignment phase of seed 002 (``evp align``)."""

    mode: str = Field("3d+baro", pattern=r"^(2d|3d)\+baro$", description="2d+baro or 3d+baro (seed 002)")
    visual_track: Literal["refined", "live"] = Field(
        "refined",
        description="refined: the estimator's trajectory adjusted at the end (SLAM's global bundle adjustment, the survey adjustment; what evp run writes as trajectory.tum), when it offers one; live: the poses as answered frame by frame (faster, weaker: Toledo 3.5 m mean error against 1.8 m)",
    )
    model: str = Field("auto", pattern="^(affine|similarity|auto)$", description="auto: chosen by the grid search")
    window_s: float = Field(70.0, gt=0, description="alignment phase length (paper: 70 s)")
    target_altitude_m: float | None = Field(None, description="None: the flight's typical altitude (90th percentile of GPS up)")
    altitude_tolerance_m: float = Field(5.0, gt=0, description="the phase starts once GPS up is within this of the target")
    max_clock_offset_s: float = Field(1.5, ge=0, description="search range of the camera-vs-GPS clock offset")
    min_pairs: int = Field(15, ge=4)
    validation_fraction: float = Field(0.3, gt=0, lt=0.9)
    ransac_thresholds_m: list[float] = Field(default_factory=lambda: [1.0, 2.0, 4.0, 8.0])
    height_tolerances_m: list[float] = Field(default_factory=lambda: [2.0, 5.0, 1e9])
    max_speeds_m_s: list[float] = Field(default_factory=lambda: [4.0, 8.0, 1e9])
    max_gap_s: float = Field(1.0, gt=0, description="odometry gaps longer than this are not interpolated")


class MonitorSettings(_Section):
    """The GPS consistency check (spoofing / jamming)."""

    window_s: float = Field(1.0, gt=0, description="innovations averaged over this window")
    false_alarm_probability: float = Field(1e-9, gt=0, lt=0.1, description="per test, under the noise model")
    gps_sigma_m: float = Field(2.0, gt=0, description="horizontal GPS error (1 sigma, per axis), correlated over the window")
    visual_drift_m_per_m: float = Field(0.01, ge=0, description="visual drift per metre travelled since the last realignment")
    visual_sigma_floor_m: float = Field(1.0, ge=0)
    realign_time_constant_s: float = Field(20.0, gt=0, description="how fast the drift correction follows consistent GPS")
    max_correction_rate_m_s: float = Field(0.3, gt=0, description="cap on how fast the correction may move (slow spoofers)")
    recovery_s: float = Field(10.0, gt=0, description="consistent time needed before GPS is trusted again")
    outage_s: float = Field(2.0, gt=0, description="no fix for this long means GPS unavailable")


class NavigationSettings(_Section):
    """The navigation filter (``evp.fusion.navigation_filter``): an error-state Kalman filter driven
    by the IMU, fusing visual poses, barometer, range finder, GPS, wheels and beacon ranges.

    IMU noise densities default to EuRoC's ADIS16448 (its ``imu0/sensor.yaml``, Kalibr's
    convention: continuous-time densities). A phone-class IMU's datasheet gives the same order
    (Bosch BMI160: accelerometer 180 ug/sqrt(Hz) = 1.8e-3 m/s^2/sqrt(Hz), gyroscope 0.007 deg/s/sqrt(Hz)
    = 1.2e-4 rad/s/sqrt(Hz)); Kalibr advises inflating datasheet values for real use, which the
    filter's gate then tolerates less tightly.
    """

    gravity_m_s2: float = Field(9.80665, gt=0, description="standard gravity (CGPM 1901); the world is ENU, z up")
    gyro_noise_density: float = Field(1.6968e-4, gt=0, description="gyroscope white noise, rad/s/sqrt(Hz) (EuRoC ADIS16448)")
    accel_noise_density: float = Field(2.0e-3, gt=0, description="accelerometer white noise, m/s^2/sqrt(Hz) (EuRoC ADIS16448)")
    gyro_bias_random_walk: float = Field(1.9393e-5, gt=0, description="gyroscope bias random walk, rad/s^2/sqrt(Hz) (EuRoC ADIS16448)")
    accel_bias_random_walk: float = Field(3.0e-3, gt=0, description="accelerometer bias random walk, m/s^3/sqrt(Hz) (EuRoC ADIS16448)")
    max_imu_gap_s: float = Field(
        0.1, gt=0, description="a longer gap between IMU samples is still integrated as one step (rates interpolated across it) but reported (warning imu_gap)"
    )
    history_s: float = Field(
        1.0,
        gt=0,
        description="delayed horizon: measurements up to this much older than the newest IMU sample are fused at their own time (PX4 EKF2 buffers ~0.5 s; SLAM answers can lag more)",
    )
    gate_probability: float = Field(
        0.9999, gt=0.5, lt=1, description="chi-square gate: a measurement whose normalised innovation squared is beyond this quantile is rejected"
    )
    initial_position_sigma_m: float = Field(1.0, gt=0, description="initial position uncertainty (1 sigma, per axis)")
    initial_velocity_sigma_m_s: float = Field(0.5, gt=0)
    saved_map_velocity_sigma_m_s: float = Field(
        10.0,
        gt=0,
        description="started from a saved map's georeference, the filter's velocity is unknown (zero, this sigma per axis: a multirotor's cruise); the visual poses give it within a second",
    )
    initial_attitude_sigma_rad: float = Field(0.05, gt=0, description="initial roll/pitch/yaw uncertainty")
    initial_yaw_sigma_rad: float = Field(3.2, gt=0, description="initial heading uncertainty: unknown (about pi) until GPS or a map says")
    initial_gyro_bias_sigma: float = Field(0.01, gt=0, description="rad/s")
    initial_accel_bias_sigma: float = Field(0.2, gt=0, description="m/s^2")
    initial_log_scale_sigma: float = Field(2.0, gt=0, description="visual map scale, natural log (2: a factor e^2 = 7.4 either way)")
    initial_map_attitude_sigma_rad: float = Field(3.2, gt=0, description="visual map rotation in the world when (re)anchored")
    initial_map_position_sigma_m: float = Field(10.0, gt=0, description="visual map origin in the world when (re)anchored")
    initial_baro_bias_sigma_m: float = Field(5.0, gt=0, description="barometer bias after its first sample set it")
    scale_known_sigma: float = Field(0.02, gt=0, description="the visual scale counts as known once its relative uncertainty (1 sigma) is below this")
    log_scale_random_walk: float = Field(
        3e-4,
        ge=0,
        description="visual scale drift, 1/sqrt(s): SLAM's map scale on the rendered 300 s flight and seed 002's flight E stays within 0.5-0.8 % of one value over 300 s (docs/decisions.md)",
    )
    map_attitude_random_walk: float = Field(1e-4, ge=0, description="visual map rotation drift, rad/sqrt(s)")
    map_position_random_walk: float = Field(1e-2, ge=0, description="visual map origin drift, m/sqrt(s)")
    baro_bias_random_walk: float = Field(0.05, ge=0, description="barometer bias drift (weather, temperature), m/sqrt(s)")
    visual_position_sigma_m: float = Field(0.02, gt=0, description="visual camera position noise (1 sigma), in metres at the estimated scale")
    visual_position_sigma_per_depth: float = Field(
        0.005,
        ge=0,
        description="visual camera position noise as a share of the tracked scene's median depth, where the estimator gives it (the larger of this and visual_position_sigma_m is used): 2 cm suits a camera 1-4 m from what it sees; at 15 m over a field it made the filter refuse every visual pose within 10 s (docs/decisions.md)",
    )
    visual_attitude_sigma_rad: float = Field(0.01, gt=0, description="visual camera attitude noise (1 sigma)")
    baro_sigma_m: float = Field(0.5, gt=0, description="barometer altitude noise (1 sigma)")
    range_sigma_m: float = Field(0.05, gt=0, description="range finder noise (1 sigma)")
    range_max_tilt_rad: float = Field(
        0.5, gt=0, lt=1.5, description="range finder readings at a larger tilt from the vertical are rejected (beam off the flat ground)"
    )
    gps_default_sigma_m: float = Field(2.5, gt=0, description="GPS position noise when the fix gives no accuracy")
    gps_velocity_sigma_m_s: float = Field(0.3, gt=0, description="GPS velocity noise when the fix gives none")
    visual_jump_reset_s: float = Field(
        1.0,
        gt=0,
        description="visual poses all refused by the gate for this long are a jump of the visual map the estimator did not announce (SLAM's loop correction moved the 300 s drone flight's poses 3.8 m at 268 s, and the filter coasted on the IMU to the end): the map's pose is re-anchored, its scale kept (PX4 EKF2 likewise resets to an aiding source its gate has refused for a timeout)",
    )
    gps_correlation_time_s: float = Field(
        60.0,
        gt=0,
        description="GPS position error's correlation time (first-order Gauss-Markov state): a single-frequency receiver's multipath and ionospheric errors change over about a minute (the simulator's model, evp.sim.sensors.GpsConfig)",
    )
    gps_white_share: float = Field(
        0.3,
        ge=0,
        lt=1,
        description="share of a fix's error variance that is white from fix to fix; the rest is the correlated error state (the simulator's model: 30 %)",
    )
    wheel_speed_sigma_m_s: float = Field(0.05, gt=0, description="wheel forward speed noise")
    non_holonomic_sigma_m_s: float = Field(0.1, gt=0, description="lateral and vertical body speed of a ground vehicle (non-holonomic constraint)")
    yaw_rate_sigma_rad_s: float = Field(0.01, gt=0)
    beacon_range_sigma_m: float = Field(0.1, gt=0)
    marker_position_sigma_m: float = Field(
        0.02,
        gt=0,
        description="camera position from one marker (1 sigma): the marker's tilt error (marker_attitude_sigma_rad) swings the camera by ~2 cm at seed 003's 0.45 m flight level",
    )
    marker_attitude_sigma_rad: float = Field(
        0.05, gt=0, description="camera attitude from one marker (1 sigma): a small square's tilt is ambiguous by a few degrees (IPPE's two solutions)"
    )
    enabled: bool = Field(
        True, description="evp run: fuse the IMU (and barometer, range finder) with SLAM when the dataset has an IMU and its camera extrinsic"
    )
    refine_offline: bool = Field(
        True,
        description="evp run: once the estimator has refined its trajectory (SLAM's final bundle adjustment, loops closed), run the stage again on it with the same telemetry; trajectory.tum is then that pass, trajectory_live.tum the fused poses as answered live",
    )
    use_baro: bool = Field(True, description="fuse the barometer's altitude when the dataset has one")
    use_range: bool = Field(True, description="fuse the range finder's height when the dataset has one")
    use_gps: bool = Field(True, description="fuse GPS fixes (ENU at the take-off point) while the GPS monitor trusts them, when the dataset has GPS")
    gps_align_min_spread_m: float = Field(
        20.0,
        gt=0,
        description="GPS fixes paired with the filter's track give the world's heading once they spread this far (RMS from their centroid): 1.5 m GPS error over 20 m is ~4 deg, which GPS updates then refine",
    )
    gps_align_on_loss_max_heading_sigma_deg: float = Field(
        15.0,
        gt=0,
        description="GPS lost (no fix for gps_monitor.outage_s) before the paired fixes spread gps_align_min_spread_m: the heading is fitted on what they have if its 1-sigma (a fix's error over their spread) is below this, with that uncertainty in the covariance (a climb jammed before the cruise: better a heading to +-15 deg than none); else the world stays the map's, not georeferenced",
    )
    hold_map_on_gps_loss: bool = Field(
        True,
        description="when GPS stops being trusted (spoofing alarm, outage), fit the visual map's scale and pose to the GPS fixes of the trusted phase and hold the scale, attitude and east-north placement there (the barometer keeps the height) until GPS is trusted again (evp.fusion.gps_map_fit; seed 002's 15 flights: docs/decisions.md)",
    )
    use_wheels: bool = Field(
        True,
        description="fuse the wheels' forward speed (with the non-holonomic constraint) and yaw rate when the dataset has them, and start from the wheel odometry's scale while the visual-inertial one is not observable",
    )
    wheel_init_min_distance_m: float = Field(
        0.3,
        gt=0,
        description="start from wheel odometry: the wheels must cover this much path over the keyframe window (the scale's relative error is about the encoder error over it)",
    )
    predict_max_s: float = Field(
        0.2,
        gt=0,
        description="live answers: the newest IMU-propagated state is carried to the frame's time at its velocity for at most this long (a late IMU stream is not extrapolated further)",
    )
    quality_zero_sigma_m: float = Field(
        5.0,
        gt=0,
        description="answer quality (0-100, MAVLink's) falls linearly with the horizontal 1-sigma to 0 here: 5 m is where a position is no better than a consumer GPS's (PX4's EV fusion ignores quality below EKF2_EV_QMIN)",
    )
    vi_init_keyframe_interval_s: float = Field(
        0.25, gt=0, description="visual-inertial initialisation: a tracked pose at least this long after the previous one is taken as a keyframe"
    )
    vi_init_window_keyframes: int = Field(
        10, ge=3, description="visual-inertial initialisation: the newest this many keyframes are solved together (VINS-Mono's window: 10)"
    )
    vi_init_min_keyframes: int = Field(5, ge=3, description="visual-inertial initialisation: keyframes needed before gravity and scale are solved for")
    vi_init_min_acceleration_std_m_s2: float = Field(
        0.1,
        gt=0,
        description="visual-inertial initialisation: spread of the mean specific force over the keyframe intervals below which scale is not observable (VINS-Mono computes the same at 0.25 but only logs it); whether the scale is determined is decided by its uncertainty (vi_init_max_scale_sigma)",
    )
    vi_init_baro_min_climb_m: float = Field(
        3.0,
        gt=0,
        description="visual-inertial initialisation: a barometer climb over the keyframe window at least this large checks the scale (10x a phone barometer's 0.3 m noise)",
    )
    vi_init_baro_scale_tolerance: float = Field(
        0.25,
        gt=0,
        description="visual-inertial initialisation: a scale whose climb differs from the barometer's by more than this share is refused (the filter needs the scale within ~25 %)",
    )
    vi_init_max_scale_sigma: float = Field(
        0.1,
        gt=0,
        description="visual-inertial initialisation: a scale whose least-squares 1-sigma is above this share is not yet determined (the filter starts with this scale uncertainty); a walker's first steps after standing gave 0.39 m/unit for 1.26",
    )
    vi_init_accel_bias_sigma: float = Field(
        0.1,
        ge=0,
        description="visual-inertial initialisation: the accelerometer bias (1 sigma per axis, m/s^2) the linear alignment allows for; its scale sigma includes what such a bias, which the solve leaves out, could move the scale by, so a start on a sway or a slow walk's first steps waits (a calibrated MEMS accelerometer's offset; measured against 0.05 and 0.2 on the rendered circle, drone flights and EuRoC MH01: docs/decisions.md)",
    )
    vi_init_max_gravity_error_m_s2: float = Field(
        0.5, gt=0, description="visual-inertial initialisation: a solved gravity whose magnitude is further than this from g is refused (VINS-Mono: 0.5)"
    )
    vi_refine_position_sigma_m: float = Field(
        0.007,
        gt=0,
        description="inertial refinement: the keyframe positions' noise (1 sigma per axis, metres); SLAM's refined poses on the rendered circle scatter 5-7 mm about the truth frame to frame, white (their second differences shrink as 1/dt^2)",
    )
    vi_refine_max_scale_sigma: float = Field(
        0.04,
        gt=0,
        description="inertial refinement: the filter starts only once the refined scale's 1-sigma is below this share (the rendered circle: 7.6-9.2 s into the walk at 4 %; 3 % was never reached within 10 s windows)",
    )
    refine_scale_after_start: bool = Field(
        True,
        description="after a visual-inertial start, the inertial refinement over the keyframes kept since the map began is run again 1, 2.5, 5 and 15 s after it (ORB-SLAM3's re-runs at 5 and 15 s, two earlier for our earlier start) and its scale replaces the filter's where it is known better, while no GPS fix or wheel speed has been fused and the map's scale is one number over the keyframes (evp.fusion.scale_refinement): a start on a slow walk's barely determined scale is corrected within seconds (rendered circle seed 2: 22 % off at the start, -4.6 % after 23 s without, +2 % from 4.5 s on with)",
    )
    vi_init_refine: bool = Field(
        True,
        description="visual-inertial initialisation: when the newest window's linear alignment leaves the scale undetermined (its sigma, with what an accelerometer bias of vi_init_accel_bias_sigma could move it by, over vi_init_max_scale_sigma), that alignment seeds the maximum-likelihood refinement (ORB-SLAM3's inertial-only optimisation, evp.fusion.inertial_refinement) over every keyframe since the first, which starts the filter once its scale sigma is under vi_refine_max_scale_sigma: a walker's slow circle, whose scale a bias along its centripetal acceleration mimics (rendered circle SE3 ATE 8.8/7.5/1.8 -> 2.2/2.8/1.8 cm on the same SLAM poses)",
    )


class MavlinkSettings(_Section):
    """Pose output to a flight controller (``evp serve --mavlink``)."""

    mount: Literal["down", "forward"] = Field("down", description="camera mounting: down (image top towards the nose) or forward")
    mount_rpy_deg: list[float] = Field(
        default_factory=lambda: [0.0, 0.0, 0.0], min_length=3, max_length=3, description="extra rotation of the mount, body axes"
    )
    mount_offset_m: list[float] = Field(
        default_factory=lambda: [0.0, 0.0, 0.0], min_length=3, max_length=3, description="camera position in the body frame (FRD)"
    )
    profile: Literal["ardupilot", "px4"] = Field(
        "ardupilot",
        description="the autopilot: ODOMETRY frames as it accepts them (ardupilot: LOCAL_FRD/BODY_FRD; px4: LOCAL_NED once the heading is known, else LOCAL_FRD)",
    )
    rate_hz: float = Field(
        50.0, ge=1.0, le=400.0, description="ODOMETRY per second (ArduPilot wants >= 4 Hz, PX4 30-50 Hz; the pose is carried forward between answers)"
    )
    max_extrapolation_s: float = Field(0.2, ge=0.0, description="how long the last pose is carried forward before output stops")
    system_id: int = Field(1, ge=1, le=255, description="source system id; each further vehicle on the default endpoint gets the next one")
    component_id: int = Field(197, ge=1, le=255, description="197: MAV_COMP_ID_VISUAL_INERTIAL_ODOMETRY")
    gps_input: bool = Field(False, description="also send the georeferenced position as GPS_INPUT (5 Hz), only while the answers are georeferenced")
    vehicles: dict[str, str] = Field(
        default_factory=dict,
        description="per-vehicle endpoints: mobile station device name (its hello.device) -> pymavlink URL; other vehicles share --mavlink, one system id each",
    )


class MarkerSettings(_Section):
    """Marker tracking and the marker map (``evp.markers``; seed 003)."""

    dictionary: str = Field("DICT_4X4_100", description="OpenCV ArUco/AprilTag dictionary of the markers (the simulated floor: DICT_4X4_100)")
    marker_size_m: float = Field(0.098, gt=0, description="black square's side (seed 003: 98 mm)")
    corner_refinement: Literal["none", "subpix", "contour", "apriltag"] = Field(
        "contour",
        description="corner refinement: contour fits lines to the marker's edges; on the real AprilTag rotation series it keeps every yaw within 7 deg (subpix: 8.0)",
    )
    threshold_window_min_px: int = Field(
        13, ge=3, description="smallest adaptive-threshold window; 13 = largest = one pass, 3x faster than OpenCV's 3-23 and as good on the rendered floor"
    )
    threshold_window_max_px: int = Field(13, ge=3, description="largest adaptive-threshold window (OpenCV's default: 23)")
    threshold_window_step_px: int = Field(
        10,
        ge=1,
        description="adaptive-threshold window step (OpenCV's default 10); the real AprilTag rotation series' 70-degree tag in clutter needs windows 3-23 by 4",
    )
    fast_detection: bool = Field(
        True, description="OpenCV's ArUco 3 mode (Romero-Ramirez et al. 2018): candidates found on a downscaled image, corners refined on the full one"
    )
    max_quality_distance_m: float = Field(
        0.8, gt=0, description="an adjacency seen from this far has quality 0 (seed 003: markers track from 100 to 800 mm; quality falls with the distance)"
    )
    duplicate_tolerance_m: float = Field(
        0.15, gt=0, description="a marker observed this far from where the map has it is a duplicate id (two markers, one id): rejected and logged"
    )
    lone_marker_tolerance_m: float = Field(
        0.3,
        gt=0,
        description="the only mapped marker in view putting the camera this far from where its motion has it is a duplicate id: rejected and logged; wider than duplicate_tolerance_m as a lone marker at the image edge jitters by +-6 cm and the velocity from it more (seed 0's exploration: 0.16 m on a genuine one)",
    )
    refine_every_markers: int = Field(
        10, ge=1, description="the metric map is refined by its pose graph after this many new markers (a refinement costs ~10-50 ms: not every frame)"
    )


class AutopilotSettings(_Section):
    """The seed 003 autopilot (``evp.autopilot``): gains, timings and limits. Times in seconds."""

    flight_level_m: float = Field(
        0.45, gt=0, description="range-finder height held in flight: inside seed 003's 200-700 mm tracking band, nearer the low end for bigger markers"
    )
    band_low_m: float = Field(0.2, gt=0, description="seed 003: markers track robustly between 200 and 700 mm")
    band_high_m: float = Field(0.7, gt=0)
    climb_rate_m_s: float = Field(0.4, gt=0, description="lift-off climb rate")
    altitude_gain: float = Field(2.0, gt=0, description="climb rate per metre of height error (1/s)")
    max_speed_m_s: float = Field(0.6, gt=0, description="fastest commanded horizontal speed")
    position_gain: float = Field(1.6, gt=0, description="speed per metre to the target (1/s): the push grows with the distance (seed 003, 3.2.4)")
    velocity_gain: float = Field(
        0.35, gt=0, description="tilt (rad) per m/s of velocity error: the drift correction (seed 003, 3.2.5) closes this loop on marker motion"
    )
    max_tilt_rad: float = Field(0.25, gt=0, lt=0.8, description="largest tilt the autopilot commands")
    drift_correction: bool = Field(True, description="close the velocity loop on the marker motion between frames (off: the paper's uncorrected hover)")
    velocity_smoothing_s: float = Field(0.1, gt=0, description="time constant of the marker-motion velocity estimate")
    edge_timeout_s: float = Field(0.75, gt=0, description="seed 003: no marker for 750 ms at a tracking height means the map's edge")
    counter_steer_tilt_rad: float = Field(
        0.1,
        gt=0,
        description="tilt of the counter-steer, held (with the trims) until markers return: blind, a firm push beats a velocity loop on a guessed velocity",
    )
    vote_weights: list[float] = Field(
        default_factory=lambda: [2.0, 1.0, 1.0],
        min_length=3,
        max_length=3,
        description="W_p, W_m, W_d of Eq. 4; seed 003 weights m stronger, here p is: its exit position is carried forward from the last marker by the velocity estimate, while m misleads while the map is partial",
    )
    edge_land_after_s: float = Field(4.0, gt=0, description="no marker for this long after an edge: land where it is rather than fly on blind (logged)")
    trim_gain: float = Field(0.3, ge=0, description="trim (rad) learned per m/s of velocity error per second: the paper's trims, taking up a steady drift")
    max_trim_rad: float = Field(0.08, ge=0, description="largest learned trim")
    drag_per_s: float = Field(
        0.4, ge=0, description="the airframe's linear drag (1/s): with the commanded tilt it carries the velocity estimate over frames without markers"
    )
    close_radius_m: float = Field(
        0.14,
        gt=0,
        description="an unexplored place the camera passes this close to at the flight level without finding a marker lies beyond the map's edge: a marker there would be whole in the view (0.45 m up, the image's half height covers 0.22 m; 0.14 + half a marker + 2 cm)",
    )
    target_timeout_s: float = Field(8.0, gt=0, description="an exploration target not reached in this long is given up (logged)")
    explore_interval_s: float = Field(0.4, gt=0, description="no new marker for this long: a new exploration target (seed 003, 3.2.3)")
    reached_radius_m: float = Field(0.06, gt=0, description="a navigation target counts as reached within this")
    land_radius_m: float = Field(0.015, gt=0, description="descent onto the target starts when the camera is this close above its centre")
    land_max_speed_m_s: float = Field(0.05, gt=0, description="... and slower than this")
    land_rate_m_s: float = Field(0.25, gt=0, description="descent rate when landing")
    touchdown_m: float = Field(0.12, gt=0, description="range below which the vehicle is on the ground (landing gear)")
    min_marker_frames: int = Field(
        2, ge=1, description="a new marker is mapped once seen in this many consecutive frames (one frame at the image edge is noise)"
    )
    frame_timeout_s: float = Field(0.5, gt=0, description="no frame for this long: hold (level, no push); frames still missing after land_after_s: land")
    land_after_s: float = Field(3.0, gt=0, description="frames missing this long: land where it is")
    range_timeout_s: float = Field(0.3, gt=0, description="no valid range reading for this long: hold height from the marker poses' height, logged")
    vehicles: list[str] = Field(
        default_factory=list,
        description="evp serve: the mobile stations (their hello.device) that fly marker missions: their frames and range telemetry drive this autopilot, its velocity set-points go to their MAVLink endpoint (mavlink.vehicles, else --mavlink)",
    )
    watchdog_period_s: float = Field(
        0.1, gt=0, description="evp serve: how often the watchdog looks for stopped frames (well under frame_timeout_s, so a hold starts within 0.6 s)"
    )


class StationSettings(_Section):
    """The base station (``evp serve``): what it asks the phones for."""

    encoding: Literal["jpeg", "png", "raw"] = Field("jpeg", description="image encoding asked of phones")
    jpeg_quality: int = Field(85, ge=1, le=100)
    min_free_disk_mb: float = Field(
        256.0,
        ge=0,
        description="below this much free space in the data folder the station refuses new recording (storage_full) rather than lose data: 12 s of the fastest stream measured (21 MiB/s), plus room for SQLite's journal",
    )
    max_estimator_restarts: int = Field(
        3,
        ge=0,
        description="an estimator process that dies is restarted (its frame in flight answered with estimator_failed); after this many deaths without a pose in between it stays down until the next config",
    )
    estimate_on_connect: bool = Field(True, description="start estimating as soon as a mobile station is configured (else wait for the operator)")
    resume_window_s: float = Field(
        60.0,
        gt=0,
        description="an interrupted session keeps its estimator (and map) this long for a reconnect; later it resumes with a new map (a dead link is seen within heartbeat_timeout_s, so a phone that comes back does so within seconds; 60 s frees the process and file of one that does not)",
    )
    vision_process: bool = Field(
        True,
        description="each session's estimator (SLAM) in a process of its own beside the one that answers the frames: the answers never wait for SLAM's Python (measured with py-spy: the answering thread waited for the interpreter more than it worked); false: one process per session, as offline",
    )
    vision_nice: int = Field(
        0,
        ge=0,
        le=19,
        description="how much nicer (Linux nice) the threads that run each session's estimator are than the station's (in the vision process, or the actor on a cluster's worker): when the cores are all busy, the answers and the link run first and SLAM takes what is left. Measured on 2 cores (docs/decisions.md): 5 halves the answers' p95 with two 30 fps flights, but SLAM then starves and a vehicle's filter may never start; one flight meets its latency target at 0",
    )
    cluster: str = Field(
        "",
        description="a Dask scheduler's address (tcp://HOST:8786): each session's estimator runs there, one long-lived actor per session, when the station's own cores are not enough; the answers, the navigation filter and the recording stay on the station",
    )
    vision_wait_s: float = Field(
        1.0,
        gt=0,
        description="live: telemetry waits this long at most for vision's pose of the same time before the navigation filter takes it (the filter runs on that delayed horizon, answers are carried ahead of it on the newest IMU); keep it within navigation.history_s",
    )
    max_clock_jump_s: float = Field(
        5.0,
        gt=0,
        description="telemetry whose time jumps further ahead than this (per kind) is an operator event (clock_jump): a phone's sensor clock reset, not a pause (GPS fixes come at >= 1 Hz)",
    )
    pairing_code_ttl_s: float = Field(600.0, gt=0, le=86400, description="a one-time pairing code (QR code, operator login link) is void after this long")
    dev_loopback: bool = Field(
        False,
        description="development only: no credentials at all (every client may stream and operate); the station then refuses to listen on anything but loopback",
    )
    allowed_origins: list[str] = Field(
        default_factory=list,
        description="web origins (scheme://host:port) besides the station's own that may open its WebSockets and POST to it (a reverse proxy's public address)",
    )
    heartbeat_interval_s: float = Field(
        1.0, gt=0, description="the station sends a heartbeat message (for pages, which cannot see WebSocket pings) and a WebSocket ping this often"
    )
    heartbeat_timeout_s: float = Field(
        3.0,
        gt=0,
        description="a link silent this long is dead (a Wi-Fi handover leaves no close frame): the station interrupts the session, a phone reconnects and resumes; must exceed heartbeat_interval_s",
    )
    # limits: one hostile or broken client must not starve the others (issue 34's measurements)
    max_sessions: int = Field(
        16, ge=1, description="live sessions (connected or awaiting a resume) at most; a new one first releases the oldest interrupted one"
    )
    max_connections: int = Field(
        512, ge=8, description="open TCP connections at most (half of a usual 1024-descriptor limit: the rest is for recordings, estimator pipes, the database)"
    )
    max_connections_per_client: int = Field(64, ge=2, description="open TCP connections from one address at most")
    header_timeout_s: float = Field(
        10.0,
        gt=0,
        description="a connection must complete its request headers within this long (slow-header clients are closed, and evicted first when the station is full)",
    )
    max_body_bytes: int = Field(1024 * 1024, ge=1024, description="an HTTP request body larger than this is refused (413) before it is read")
    session_quota_bytes: int = Field(
        4 * 1024**3, ge=1024 * 1024, description="one session's recording may grow to this size; later frames are refused (quota) and not recorded"
    )
    full_estimators: int | None = Field(
        None,
        ge=0,
        description="sessions estimating with the configured estimator at once (None: one per CPU core); sessions beyond it get the light VO (klt-vo), and the phone and the operator are told: even degradation instead of every session collapsing",
    )
    overload_lag_s: float = Field(
        0.25, gt=0, description="the station's event loop this late on its 1 s tick means CPU overload: every session gets the same, lower frame rate"
    )
    overload_min_fps: float = Field(5.0, gt=0, description="under overload no session is capped below this frame rate")
    overload_recover_s: float = Field(10.0, gt=0, description="this long without lag before the overload cap starts to rise again")
    log_burst: int = Field(20, ge=1, description="the same log message at most this many times per log_window_s; the rest are counted and summarised")
    log_window_s: float = Field(10.0, gt=0)
    pairing_max_failures: int = Field(
        5,
        ge=1,
        description="failed pairing attempts a client (IP address) may make per pairing_failure_window_s; more are answered 429 unchecked and unlogged (a code is 128 random bits: the limit guards the event log and the disk, not the code)",
    )
    pairing_failure_window_s: float = Field(60.0, gt=0)
    background_image: str = Field(
        "",
        description="an orthophoto or mosaic (PNG or JPEG, north up) drawn under the operator's top view of georeferenced sessions; needs background_bounds_deg",
    )
    background_bounds_deg: tuple[float, float, float, float] | None = Field(
        None,
        description="the background image's edges in WGS-84 degrees: south, west, north, east (a KML GroundOverlay's LatLonBox; gdalinfo's corner coordinates)",
    )

    @model_validator(mode="after")
    def _heartbeat_fits(self) -> StationSettings:
        if self.heartbeat_timeout_s <= self.heartbeat_interval_s:
            raise ValueError(f"heartbeat_timeout_s ({self.heartbeat_timeout_s:g}) must exceed heartbeat_interval_s ({self.heartbeat_interval_s:g})")
        return self

    @model_validator(mode="after")
    def _background_placed(self) -> StationSettings:
        if bool(self.background_image) != (self.background_bounds_deg is not None):
            raise ValueError("background_image and background_bounds_deg go together: the image and where its edges are")
        if self.background_bounds_deg is not None:
            south, west, north, east = self.background_bounds_deg
            if not (-90.0 <= south < north <= 90.0 and -180.0 <= west < east <= 180.0):
                raise ValueError(
                    f"background_bounds_deg {list(self.background_bounds_deg)}: give south < north within +-90 and west < east within +-180 degrees"
                )
        if self.background_image and Path(self.background_image).suffix.lower() not in (".png", ".jpg", ".jpeg"):
            raise ValueError(f"background_image {self.background_image!r}: a PNG or JPEG image (convert a GeoTIFF with gdal_translate -of PNG)")
        return self


class EkfSlamSettings(_Section):
    """Seed 001's EKF-SLAM (``estimator: ekf-slam``, :mod:`evp.ekf_slam`): a wheeled robot's planar
    pose, gyro bias, camera position on the robot and inverse-depth features in one EKF."""

    max_features: int = Field(100, ge=5, le=400, description="features in the state at most (the update's cost grows with the square of the state)")
    min_matched_features: int = Field(
        15, ge=3, description="fewer features matched in a frame than this: new ones are initialised (MonoSLAM keeps ~12 visible)"
    )
    new_features_per_frame: int = Field(5, ge=1, description="features initialised per frame at most")
    max_updates_per_frame: int = Field(40, ge=3, description="matched features used per update at most (the least uncertain first)")
    pixel_sigma: float = Field(1.0, gt=0, description="feature position noise in the image (1 sigma, pixels): FAST corners at their pixel")
    initial_inverse_depth: float = Field(
        0.5, gt=0, description="inverse depth (1/m) a new feature starts at: 2 m, the middle of a 6 x 5 m room (Civera: 0.1 outdoors)"
    )
    initial_inverse_depth_sigma: float = Field(
        0.5, gt=0, description="its 1 sigma: the 95 % region, 0.5 +- 1, spans 0.67 m to infinity (Civera's rule: include infinity)"
    )
    euclidean_linearity: float = Field(
        0.1, gt=0, description="an inverse-depth feature whose linearity index falls below this becomes a Euclidean point (Civera et al. 2008: 0.1)"
    )
    wheel_speed_sigma_m_s: float = Field(
        0.02,
        gt=0,
        description="forward speed noise per wheel sample (1 sigma): one encoder tick per 20 ms sample is 0.03 m/s on the simulated robot, plus slip",
    )
    wheel_speed_sigma_fraction: float = Field(0.01, ge=0, description="speed noise proportional to the speed (wheel radius, slip)")
    lateral_slip_m_per_sqrt_s: float = Field(
        0.02,
        ge=0,
        description="sideways slip the unicycle model misses, as a random walk (the rendered robot slides up to 1.6 cm/s in its turns, ~3 cm per turn)",
    )
    gyro_sigma_rad_s: float = Field(0.005, gt=0, description="yaw rate noise per sample (1 sigma)")
    initial_gyro_bias_sigma_rad_s: float = Field(0.01, gt=0, description="gyro bias prior: a phone gyro's turn-on bias (BMI160: 0.5 deg/s)")
    gyro_bias_walk_rad_s_per_sqrt_s: float = Field(
        2e-5,
        ge=0,
        description="gyro bias random walk (EuRoC's ADIS16448: 1.9e-5, as navigation.gyro_bias_random_walk); 1e-4 let the bias absorb visual errors (ATE 5.0 against 2.6 cm on the rendered room's seed 3)",
    )
    camera_offset_sigma_m: float = Field(0.02, gt=0, description="prior on the camera's position on the robot, per axis (a tape measure's calibration)")
    max_speed_m_s: float = Field(2.0, gt=0, description="a wheel speed beyond this is an encoder jump or counter wrap, not motion")
    gyro_saturation_rad_s: float = Field(4.36, gt=0, description="gyro range: a reading at it is saturated (250 deg/s, a phone gyro's smallest range)")
    bad_input_sigma_factor: float = Field(
        10.0, ge=1, description="an interval with a bad wheel or gyro reading is predicted from the last good one, its noise times this"
    )
    fast_threshold: int = Field(20, ge=1, le=255, description="FAST corner threshold")
    match_max_hamming: int = Field(
        50,
        ge=1,
        le=256,
        description="ORB descriptor distance a match may have (ORB-SLAM: 50 strict, 100 loose); 70 let wrong matches in on the rendered room (ATE 3.1-3.6 cm against 2.7-3.0)",
    )
    new_feature_min_distance_px: float = Field(20.0, gt=0, description="a new feature keeps this far from the features predicted in the image")
    image_margin_px: float = Field(16.0, ge=0, description="features predicted this close to the border are not searched (the ORB patch needs room)")
    search_gate_probability: float = Field(0.99, gt=0.5, lt=1, description="a feature is searched inside this share of its predicted measurement's Gaussian")
    low_innovation_probability: float = Field(
        0.9,
        gt=0,
        lt=1,
        description="matches whose innovation is inside this share of the prediction's Gaussian are fused first, the rest re-tested on the corrected state (Civera et al. 2010's low/high-innovation split)",
    )
    delete_min_attempts: int = Field(10, ge=1, description="a feature searched this many times ...")
    delete_max_miss_ratio: float = Field(0.5, gt=0, lt=1, description="... and missed more than this share of them is deleted (MonoSLAM's rule)")
    consistency_window_frames: int = Field(30, ge=1, description="the innovations of this many updates are tested together")
    consistency_probability: float = Field(
        0.999, gt=0.5, lt=1, description="their summed NIS beyond this chi-square quantile: the filter is inconsistent (warning)"
    )
    start_pose: list[float] | None = Field(
        None,
        min_length=3,
        max_length=3,
        description="the robot's start [x m, y m, heading deg] in the radio map's frame (a dock surveyed in the building); none: the world is the start. WiFi fixes (wifi.radio_map) need it",
    )
    start_position_sigma_m: float = Field(0.05, ge=0, description="1 sigma of start_pose's position, per axis (a dock marked on the floor)")
    start_heading_sigma_deg: float = Field(2.0, ge=0, description="1 sigma of start_pose's heading")


class RobotSettings(_Section):
    """A wheel robot on the station's link (seed 001: the robot sends its encoder counts, the
    station may drive it): its encoders, and the watchdog that stops it when the link drops."""

    metres_per_tick: float = Field(
        2 * math.pi * 0.035 / 360, gt=0, description="wheel travel per encoder tick: the rendered robot's 3.5 cm wheel, 360 ticks per turn"
    )
    counter_bits: int = Field(16, ge=8, le=64, description="the encoder counters' width: they wrap at 2^bits (a microcontroller's 16-bit timer)")
    wheel_base_m: float = Field(0.3, gt=0, description="distance between the wheels: the turn rate from the encoders when the robot sends no gyro")
    max_wheel_speed_m_s: float = Field(2.0, gt=0, description="an encoder difference meaning more than this is a jump (reset, glitch), not motion")
    watchdog_timeout_s: float = Field(
        0.5,
        gt=0,
        description="the robot stops (zero velocity) when no velocity command came for this long: the station repeats them while it drives (ROS cmd_vel timeouts: 0.25-0.5 s)",
    )
    command_interval_s: float = Field(0.1, gt=0, description="the station repeats the current velocity command this often (10 Hz): well inside the watchdog")
    max_linear_m_s: float = Field(0.5, gt=0, description="the largest forward speed a command may ask (the rendered robot drives at 0.3 m/s)")
    max_angular_rad_s: float = Field(1.5, gt=0, description="the largest turn rate a command may ask")

    @model_validator(mode="after")
    def _watchdog_outlasts_the_repeats(self) -> RobotSettings:
        if self.watchdog_timeout_s <= self.command_interval_s:
            raise ValueError(f"watchdog_timeout_s ({self.watchdog_timeout_s:g}) must exceed command_interval_s ({self.command_interval_s:g})")
        return self


class WifiSettings(_Section):
    """WiFi RSS fingerprinting (``evp wifi``, :mod:`evp.wifi`)."""

    not_detected_dbm: float = Field(
        -105.0,
        lt=-90.0,
        description="RSS an access point not heard counts as: below the weakest reading (UJI long-term data: -98 dBm; its authors' baselines use -105)",
    )
    place_tolerance_m: float = Field(
        0.05, gt=0, description="survey samples this close (each axis, same floor) are one surveyed place (UJI's survey marks are >= 0.6 m apart)"
    )
    k_candidates: list[int] = Field(
        default_factory=lambda: [1, 3, 5, 7, 9, 11, 15, 20, 25, 30],
        min_length=1,
        description="wknn_cv: the k values leave-one-place-out cross-validation inside the radio map chooses from",
    )
    radio_map: str | None = Field(
        None,
        description="a radio map (evp wifi build, or the rendered room's wifi_radio_map.npz): estimator ekf-slam then fuses the dataset's WiFi scans as weak absolute positions",
    )
    method: Literal["knn3", "wknn_paper", "wknn_cv"] = Field("wknn_cv", description="the method that locates the scans fused (evp wifi eval compares them)")
    gate_probability: float = Field(
        0.9973,
        gt=0.5,
        lt=1,
        description="a WiFi fix whose innovation is beyond this chi-square quantile is not fused (3 sigma: a fix 2-4 m off is common, one beyond that is a wrong place)",
    )


class Settings(_Section):
    estimator: Literal["auto", "slam", "klt-vo", "nadir", "ekf-slam"] = Field(
        "auto",
        description="auto: nadir homography odometry for sparse imagery (frames > 1 s apart, e.g. survey photos), else SLAM; klt-vo is the light VO mode; ekf-slam: seed 001's wheel robot (wheels + gyro + camera, metric)",
    )
    orb: OrbSettings = OrbSettings()
    camera: CameraSettings = CameraSettings()
    vo: VoSettings = VoSettings()
    slam: SlamSettings = SlamSettings()
    align: AlignmentSettings = AlignmentSettings()
    gps_monitor: MonitorSettings = MonitorSettings()
    navigation: NavigationSettings = NavigationSettings()
    eval: EvalSettings = EvalSettings()
    station: StationSettings = StationSettings()
    mavlink: MavlinkSettings = MavlinkSettings()
    wifi: WifiSettings = WifiSettings()
    robot: RobotSettings = RobotSettings()
    ekf_slam: EkfSlamSettings = EkfSlamSettings()
    markers: MarkerSettings = MarkerSettings()
    autopilot: AutopilotSettings = AutopilotSettings()


# ORB-SLAM2/3 settings keys and where they go in EVP's settings.
ORBSLAM_KEYS = {
    "ORBextractor.nFeatures": ("orb", "n_features"),
    "ORBextractor.nLevels": ("orb", "pyramid_levels"),
    "ORBextractor.scaleFactor": ("orb", "scale_factor"),
    "ORBextractor.iniThFAST": ("orb", "ini_fast_threshold"),
    "ORBextractor.minThFAST": ("orb", "min_fast_threshold"),
    "Camera.fps": ("camera", "fps"),
    "Camera1.fps": ("camera", "fps"),
}


def _from_orbslam(path: Path, data: dict) -> dict:
    nested: dict = {}
    for key, (section, field) in ORBSLAM_KEYS.items():
        if key in data:
            nested.setdefault(section, {})[field] = data[key]
    if "Camera.RGB" in data:
        nested.setdefault("camera", {})["color_space"] = "rgb" if data["Camera.RGB"] else "bgr"
    if "Camera.fx" in data or "Camera1.fx" in data:
        nested.setdefault("camera", {})["calibration_file"] = path
    return nested


def read_settings_yaml(path: Path) -> dict:
    """A YAML mapping (OpenCV FileStorage headers allowed); problems raise ConfigError naming the line."""
    from evp.calib.camera_files import load_yaml_mapping

    return load_yaml_mapping(path, lambda p, msg, line=None: ConfigError(f"{p}" + (f", line {line}" if line else "") + f": {msg}"))


def validation_message(exc: ValidationError, model: type[BaseModel] | None = None) -> str:
    """The first problem pydantic found, as 'field.path: message (got value)'; a key that does not
    exist in ``model`` (the settings class validated) gets the nearest key of its section named."""
    first = exc.errors()[0]
    where = ".".join(str(p) for p in first["loc"])
    if first["type"] == "extra_forbidden" and model is not None:
        return f"{where}: no such setting{_did_you_mean(model, first['loc'])}"
    return f"{where}: {first['msg']} (got {first.get('input')!r})"


def _did_you_mean(model: type[BaseModel], loc: tuple) -> str:
    """'; did you mean section.key?' for the unknown key at ``loc``, or the section's keys when none is close."""
    from difflib import get_close_matches

    section = model
    for part in loc[:-1]:
        field = section.model_fields.get(str(part))
        annotation = field.annotation if field is not None else None
        if not (isinstance(annotation, type) and issubclass(annotation, BaseModel)):
            return ""
        section = annotation
    prefix = "".join(f"{part}." for part in loc[:-1])
    names = list(section.model_fields)
    close = get_close_matches(str(loc[-1]), names, n=1, cutoff=0.6)
    if close:
        return f"; did you mean {prefix}{close[0]}?"
    return f"; {prefix.rstrip('.') or 'the top level'} has " + ", ".join(names)


def load_settings(path: str | Path | None = None) -> Settings:
    """Defaults, overridden by a YAML file (EVP layout or ORB-SLAM settings)."""
    if path is None:
        return Settings()
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"{path}: settings file not found")
    data = read_settings_yaml(path)
    if any(key in data for key in ORBSLAM_KEYS) or "Camera.fx" in data:
        data = _from_orbslam(path, data)
    try:
        return Settings.model_validate(data)
    except ValidationError as exc:
        raise ConfigError(f"{path}: {validation_message(exc, Settings)}") from exc


def settings_yaml(settings: Settings) -> str:
    return yaml.safe_dump(settings.model_dump(mode="json"), sort_keys=False)


def write_settings(settings: Settings, directory: Path) -> Path:
    """The effective settings beside a command's results."""
    directory.mkdir(parents=True, exist_ok=True)
    path = directory / "settings.yaml"
    path.write_text(settings_yaml(settings))
    return path


def _field_names(model: type[BaseModel], prefix: str = "") -> list[str]:
    names = []
    for name, info in model.model_fields.items():
        kind = info.annotation
        if isinstance(kind, type) and issubclass(kind, BaseModel):
            names.extend(_field_names(kind, f"{prefix}{name}."))
        else:
            names.append(prefix + name)
    return names


def with_overrides(settings: Settings, overrides: dict[str, object]) -> Settings:
    """``settings`` with dotted names set (``{"orb.n_features": 500}``, as ``evp sweep --set``
    gives them), validated as a settings file would be; an unknown name is refused with the
    closest known ones. The settings given before stay given (``resolve_settings`` looks)."""
    import difflib

    known = _field_names(Settings)
    data = settings.model_dump(exclude_unset=True)
    for name, value in overrides.items():
        if name not in known:
            close = difflib.get_close_matches(name, known, n=3, cutoff=0.6)
            raise ConfigError(f"unknown setting {name!r}" + (f"; did you mean {', '.join(close)}?" if close else " (evp config dump lists them)"))
        *sections, field = name.split(".")
        target = data
        for section in sections:
            target = target.setdefault(section, {})
        target[field] = value
    try:
        return Settings.model_validate(data)
    except ValidationError as exc:
        raise ConfigError(f"setting {validation_message(exc)}") from exc
