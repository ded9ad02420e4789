"""The one configuration object of bsslam, with every parameter named and its unit.

Built in one place (:func:`SLAMConfig.from_dict`, used by the YAML loader in
``bsslam.io.config_file``) and written next to every run's results.
Names carry their units: ``_m`` metres, ``_rad`` radians.

Values are typed by the dataclass annotations, checked in :func:`SLAMConfig.from_dict`
before any work: a ``bool`` field takes only true/false (never ``'no'`` or ``0``), an
``int`` only integers (not ``8.5``), a ``float`` any finite number; each section's
``__post_init__`` then checks the ranges, with upper bounds where a value sizes an
allocation (the scan matcher's search grids and likelihood fields) or stops making
physical sense (σ of metres beyond 10 m, of angles beyond 2π).
"""

from __future__ import annotations

import dataclasses
import math
import types
import typing
from dataclasses import dataclass, field
from typing import Any, Literal

from bsslam.errors import ConfigError
from bsslam.input_limits import InputLimits


def _check(condition: bool, message: str) -> None:
    if not condition:
        raise ConfigError(message)


# physical ceilings shared by several sections
MAX_SIGMA_M = 10.0          # a standard deviation of a range or position beyond 10 m says nothing
MAX_SIGMA_RAD = 2 * math.pi   # … of an angle beyond a full turn
MAX_BEARING_SIGMA_RAD = 0.1   # a beam's bearing σ (rad) beyond ~6°: no laser's beam is that wide
MAX_FACTOR = 1e6            # inflation factors on variances


def _kind(value: Any) -> str:
    if value is None:
        return "null"
    text = repr(value)
    return f"{text if len(text) <= 40 else text[:37] + '...'} ({type(value).__name__})"


def _typed(value: Any, hint: Any, key: str, nullable: bool = False) -> Any:
    """``value`` checked against the annotation ``hint`` (bool, int, float, str, Literal,
    X | None, tuple[...]) and converted where lossless (an integer for a float field).

    Raises:
        ConfigError: naming ``key`` and the expected type.
    """
    def wrong(expected: str, detail: str = "") -> ConfigError:
        return ConfigError(f"{key}: expected {expected}{' or null' if nullable else ''}{detail}, got {_kind(value)}")

    origin, args = typing.get_origin(hint), typing.get_args(hint)
    if origin in (types.UnionType, typing.Union):
        inner = [a for a in args if a is not type(None)]
        if len(inner) != 1 or len(args) != 2:
            raise TypeError(f"unsupported annotation {hint!r} of {key}")   # a programming error
        return None if value is None else _typed(value, inner[0], key, nullable=True)
    if origin is Literal:
        if isinstance(value, str) and value in args:
            return value
        raise wrong("one of " + ", ".join(map(repr, args)))
    if origin is tuple:
        if not isinstance(value, (list, tuple)) or len(value) != len(args):
            raise wrong(f"a list of {len(args)} values")
        return tuple(_typed(v, a, f"{key}[{i}]") for i, (v, a) in enumerate(zip(value, args)))
    if hint is bool:
        if isinstance(value, bool):
            return value
        raise wrong("true or false")
    if hint is int:
        # every integer setting is a count or a degree; 2³¹ also keeps them inside the
        # compiled kernels' int64 arithmetic
        if isinstance(value, int) and not isinstance(value, bool) and abs(value) < 2 ** 31:
            return value
        raise wrong("an integer", " below 2³¹" if isinstance(value, int) and not isinstance(value, bool) else "")
    if hint is float:
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            try:
                number = float(value)
            except OverflowError:
                number = math.inf
            if math.isfinite(number):
                return number
            raise wrong("a finite number")
        raise wrong("a number")
    if hint is str:
        if isinstance(value, str):
            return value
        raise wrong("a string")
    raise TypeError(f"unsupported annotation {hint!r} of {key}")


def _typed_fields(cls: type, values: dict[str, Any], prefix: str) -> dict[str, Any]:
    """``values`` (keys already known to be fields of dataclass ``cls``) typed by its
    annotations; keys named ``prefix.key`` in errors."""
    hints = typing.get_type_hints(cls)
    return {name: _typed(value, hints[name], f"{prefix}{name}") for name, value in values.items()}


@dataclass(frozen=True)
class SplineConfig:
    """Shape of the map features.

    Attributes:
        degree: polynomial degree p of every spline (order κ = p + 1); 1 … 4.
        knot_spacing_m: target distance ρ between consecutive knots along the curve (m).
        min_knot_spacing_m: the finest spacing a spline entering the map may be refined
            to where a finer fit shows it biased (``mapping.fit_bias_sigmas``) (m).
        max_noise_gain: fits use fewer spans while some control point would amplify range
            noise more than this (largest row norm of Φ; dimensionless). Well-posed fits stay
            below ~2.5; nearly unsupported basis functions reach 10⁶–10¹⁰ and, in the state,
            made the covariance indefinite within tens of scans at ρ = 0.2 m.
    """

    degree: int = 3
    knot_spacing_m: float = 1.0
    min_knot_spacing_m: float = 0.25
    max_noise_gain: float = 10.0

    def __post_init__(self) -> None:
        _check(1 <= self.degree <= 4, f"spline.degree must be 1..4, got {self.degree}")
        _check(self.knot_spacing_m > 0, "spline.knot_spacing_m must be > 0")
        _check(0 < self.min_knot_spacing_m <= self.knot_spacing_m,
               "spline.min_knot_spacing_m must be in (0, knot_spacing_m]")
        _check(self.max_noise_gain > 1.0, "spline.max_noise_gain must be > 1")


@dataclass(frozen=True)
class SegmentationConfig:
    """Splitting a scan into runs of points that belong to one wall (paper §III-A).

    Attributes:
        alpha_max_rad: largest turn between consecutive point-to-point vectors (α_max, rad).
        eta: largest ratio of consecutive point spacings (η, dimensionless, ≥ 1).
        max_gap_m: largest distance between consecutive points of one segment (m).
        min_points: fewest points in a segment (n_pr).
        min_length_m: shortest segment kept (chord length, m); shorter ones are dropped
            as small or dynamic objects.
        min_range_m: beams at or below this range are invalid (m). The same quantity as
            ``frontend.min_range_m`` (the laser's shortest valid range), with the same
            default; the front end reads only its own section, so set both for a laser whose
            minimum differs.
        no_return_m: ranges at or above this value mean "no return" to the map (m); None
            (the default) uses the scan's own ``max_range`` only. Not the reader's
            ``ReaderConfig.no_return_m`` (80 m): that one says which raw values in a *log* are
            the logger's no-return code (a property of the recording; the reader turns them
            into +inf and lowers the scan's ``max_range`` to it); this one is an optional,
            lower limit of the *filter*, e.g. to keep sparse far beams out of the map. It
            must exceed ``min_range_m``, or every beam would be "no return".
    """

    alpha_max_rad: float = math.radians(30.0)
    eta: float = 2.0
    max_gap_m: float = 0.5
    min_points: int = 8
    min_length_m: float = 0.3
    min_range_m: float = 0.05
    no_return_m: float | None = None

    def __post_init__(self) -> None:
        _check(0 < self.alpha_max_rad < math.pi, "segmentation.alpha_max_rad must be in (0, π)")
        _check(self.eta >= 1.0, "segmentation.eta must be ≥ 1")
        _check(self.max_gap_m > 0, "segmentation.max_gap_m must be > 0")
        _check(self.min_points >= 2, "segmentation.min_points must be ≥ 2")
        _check(self.min_length_m >= 0, "segmentation.min_length_m must be ≥ 0")
        _check(self.min_range_m >= 0, "segmentation.min_range_m must be ≥ 0")
        # a limit at or below the minimum range makes every beam "no return": an empty map
        _check(self.no_return_m is None or self.no_return_m > self.min_range_m,
               f"segmentation.no_return_m must be > min_range_m ({self.min_range_m}) or null, got {self.no_return_m!r}")


@dataclass(frozen=True)
class MotionNoiseConfig:
    """Odometry noise, σ = a + b·|Δ| per component of the increment (paper §IV).

    The filter's prediction uses this model only for increments that come without a
    covariance: the raw odometry when the front end is off (the simulator's experiments, which
    also draw their odometry noise from it). With the front end on, the filter gets the scan
    matcher's covariance, and the front end's own odometry model (``frontend.odom_sigma_*``)
    is its prior. The two differ on purpose: this one describes the paper's (and the
    simulator's) odometry — 1 mm + 10 % of the step; the front end's must cover real wheel
    odometry, off by up to ~20° in one step of the 1 Hz Intel log, since a prior narrower
    than the true error would pull a good match towards the odometry.

    Attributes:
        a_xy_m, b_xy: σ of Δx and Δy: a_xy_m + b_xy·|Δ| (m).
        a_phi_rad, b_phi: σ of Δφ: a_phi_rad + b_phi·|Δφ| (rad).
        b_phi_per_m_rad: extra σ of Δφ per metre travelled (rad/m); 0 in the paper.
    """

    a_xy_m: float = 0.001
    b_xy: float = 0.1
    a_phi_rad: float = 0.02
    b_phi: float = 0.1
    b_phi_per_m_rad: float = 0.0

    def __post_init__(self) -> None:
        for name in ("a_xy_m", "b_xy", "a_phi_rad", "b_phi", "b_phi_per_m_rad"):
            _check(getattr(self, name) >= 0, f"motion.{name} must be ≥ 0")
        for name, ceiling in (("a_xy_m", MAX_SIGMA_M), ("b_xy", 10.0), ("a_phi_rad", MAX_SIGMA_RAD),
                              ("b_phi", 10.0), ("b_phi_per_m_rad", MAX_SIGMA_RAD)):
            _check(getattr(self, name) <= ceiling, f"motion.{name} must be ≤ {ceiling:g}, got {getattr(self, name)!r}")


@dataclass(frozen=True)
class ObservationConfig:
    """The range observation model and its gates (paper §III-D, §III-E).

    Attributes:
        sigma_range_m: σ of one laser range against the map spline it hits (m), in the
            filter's update. Not ``frontend.range_sigma_m`` (0.02 m): that one is the stated
            floor of the scan matcher's point-to-line residual against the neighbouring
            reference points' local line, which sees no spline's shape error, and is
            replaced by the residuals' own σ when larger and then inflated ×10
            (``covariance_inflation``). The default here is for real lasers and
            buildings: a SICK LMS's few-centimetre range error plus walls that are not the
            smooth curves a spline draws (door frames, skirting, posters). The simulator's
            experiments set it to the simulated 5 mm.
        sigma_model_m: σ of the map splines' unmodelled error along a beam — what is left of
            the fit bias after ``mapping.fit_bias_sigmas``, the fixed chord-length parameters
            of (40)–(46) — added in quadrature to ``sigma_range_m`` (m). Measured, 20 runs ×
            60 steps without extension, mean NEES over the steps (3 dof): rounded-room 3.4 /
            2.7 / 1.7 for 0 / 2.5 / 5 mm; with 2.5 mm corridor-loop 3.6 and mixed 3.2. 5 mm
            was needed only while corner bias went undetected (see ``fit_bias_sigmas``).
        sigma_bearing_rad: σ of a beam's bearing (rad): the beam is a cone, not a ray, and
            its direction is known only as well as the scan's timing and the de-skewing of
            the robot's motion during the sweep. On a wall met at incidence i from z metres
            it moves the range by z·tan(i)·σ, added to the range's own variance beam by
            beam in the update: far, oblique beams weigh less. 0 = the paper's exact
            bearings (the simulator's experiments set 0: its bearings are exact). 10 mrad
            (0.57°, about half the shared logs' 1° beam spacing) was measured against 5
            mrad and 0 on the shared logs; new splines keep the range noise alone, since
            carrying the bearing's share into their covariance cost CSAIL and the campus
            (docs/real_logs.md, "A beam's bearing").
        sigma_shared_m: σ of a range error shared by every beam of one scan that hits the
            same map spline (m), on top of their independent ``sigma_range_m``: a wall that
            is not where its spline says, a laser biased on one surface. Without it the ~90
            beams of a wall count as 90 independent looks and a wall fixes the pose to
            σ/√90; with it, to no better than about this σ. 0 = the paper's independent beams.
        significant_bends_only: what the beams on one map spline say along that spline is
            scaled by w = max(0, 1 − σ²/Δθ²), Δθ the angle the spline turns between its
            first and last hit and σ its prior σ: a straight wall says nothing along itself,
            whatever its fitted wiggles (:mod:`bsslam.slam.bends`). False = the paper's
            update, which reads the wiggles as shape (what ``bsslam experiment`` runs
            without ``--config``). On by default: with the invariant EKF the simulated
            double loops stay in their NEES band on 91 % of the steps in rounded-room and
            mixed (49 % and 90 % with the paper's update), and the real logs' ATE moves
            within their seeds' scatter (README, Consistency).
        significant_wall_angles: what the walls of one scan say along their common direction
            is limited the same way: the scan's weakest direction (where Σ g gᵀ of its rows
            is smallest) keeps w = max(0, 1 − N/λ) of what its rows say along it, λ that
            information and N what walls truly parallel would give it through their
            directions' prior noise (:mod:`bsslam.slam.bends`). Two straight walls a few
            milliradians from parallel otherwise tell the linearised update where along a
            corridor the robot is, from their fits' noise (docs/consistency.md, "Between the
            walls"). A corner, an arc or a wall across the corridor in view keeps all it says.
            False = without it (and the paper's update: ``bsslam experiment`` turns both
            off). On by default: with the invariant EKF the simulated long corridor's NEES
            falls from 8.0 to 5.2 over thirty seeds, the corridor loop stays in its band on
            54 % and 39 % of the steps (26 % and 16 % without), the rooms as without it
            (README, Consistency).
        second_order: each scan's update also weighs the ranges' second-order error, the
            Gaussian second-order filter's ½ tr(∇²h_i P ∇²h_j P) (m²): a full block added
            to R, shared by the beams through the state errors they share. Down a straight
            corridor the pose's needle-shaped prior times the walls' relative tilt gives the
            first-order update an along-corridor information that only the noise supports
            (docs/consistency.md, "Between the walls"); this term weighs it. Taken where the
            iterations linearise (the first corrected estimate), under the spread the scan
            leaves there (the first gain's posterior), along the estimator's own error (the
            invariant EKF's rotates every position, :meth:`Estimator.error_curvature`); each
            beam's Hessian on its own variables (the pose and its piece's control points) by
            central differences, 22 linearisations of the scan's beams for cubic splines.
            Off (the default): the first-order update. Down the benchmarks' 80 × 50 m
            corridor the pose NEES is 7.7 over ten seeds against 9.1, the double loops keep
            their band as without it (rounded-room 93 %, the corridor loop 16 %), at about
            twice the time of a simulated run (docs/consistency.md, "The ranges' second
            order").
        r_inflation: factor on the range variances (the paper's "inflated R" uses 3).
        gate_probability: χ² (1 dof) probability of the per-beam innovation gate.
        max_incidence_rad: beams hitting a wall more obliquely than this (angle between
            beam and wall normal) are dropped as grazing (rad). The range is strongly
            non-linear in the pose there; admitting beams up to 75° makes the filter
            optimistic within 20 steps in simulation.
        beam_stride: use every k-th beam of a segment in the update (1 = all).
        iterations: Gauss–Newton iterations of the iterated EKF update at most (1 = the
            paper's single linearisation).
        iteration_tolerance: the iterations stop once a Gauss–Newton step moves every pose
            component by less than this fraction of its posterior σ (0 = run them all).
    """

    sigma_range_m: float = 0.03
    sigma_model_m: float = 0.0025
    sigma_bearing_rad: float = 0.01
    sigma_shared_m: float = 0.0
    significant_bends_only: bool = True
    significant_wall_angles: bool = True
    second_order: bool = False
    r_inflation: float = 1.0
    gate_probability: float = 0.99
    max_incidence_rad: float = math.radians(45.0)
    beam_stride: int = 1
    iterations: int = 3
    iteration_tolerance: float = 0.1

    def __post_init__(self) -> None:
        _check(0 < self.sigma_range_m <= MAX_SIGMA_M, f"observation.sigma_range_m must be in (0, {MAX_SIGMA_M:g}] m")
        _check(0 <= self.sigma_model_m <= MAX_SIGMA_M, f"observation.sigma_model_m must be in [0, {MAX_SIGMA_M:g}] m")
        _check(0 <= self.sigma_shared_m <= MAX_SIGMA_M, f"observation.sigma_shared_m must be in [0, {MAX_SIGMA_M:g}] m")
        _check(0 <= self.sigma_bearing_rad <= MAX_BEARING_SIGMA_RAD,
               f"observation.sigma_bearing_rad must be in [0, {MAX_BEARING_SIGMA_RAD:g}] rad")
        _check(0 < self.r_inflation <= MAX_FACTOR, f"observation.r_inflation must be in (0, {MAX_FACTOR:g}]")
        _check(0 < self.gate_probability < 1, "observation.gate_probability must be in (0, 1)")
        _check(0 < self.max_incidence_rad < math.pi / 2, "observation.max_incidence_rad must be in (0, π/2)")
        _check(self.beam_stride >= 1, "observation.beam_stride must be ≥ 1")
        _check(1 <= self.iterations <= 100, "observation.iterations must be 1..100")
        _check(self.iteration_tolerance >= 0, "observation.iteration_tolerance must be ≥ 0")
        _check(isinstance(self.second_order, bool),
               f"observation.second_order must be true or false, got {self.second_order!r}")


@dataclass(frozen=True)
class AssociationConfig:
    """Matching observed splines to map splines (paper §III-B, Fig. 6).

    Attributes:
        control_point_gate_factor: the cheap gate δ_mincp as a multiple of the knot
            spacing ρ (the paper uses 1/2).
        match_distance_m: δ_match, the largest distance between corresponding end points (m).
        map_radius_m: only map splines whose bounding box comes this close to the robot
            are considered (m). Walls farther away are mapped again, as new splines, which
            fills a submap's state sooner, so the radius also sets how long submaps get in
            open spaces. Measured (ten perturbed runs and float32, median ATE; 2026-12-04):
            25 m (beyond which no 1° laser's segments reach) gives edmonton 0.396 m
            (0.414 at 12 m) and its worst run 0.560 m (0.966), but the campus 2.10 m
            (0.565), its submaps 124 instead of 196, and acapulco 0.310 m (0.293).
        uncertainty_sigmas: both distances grow by this many standard deviations of the
            predicted position of the observed spline's far end (pose uncertainty seen at
            that range), so association survives a poorly predicted turn; 0 = the paper's
            fixed thresholds.
        max_match_distance_m: cap on the grown δ_match (m).
    """

    control_point_gate_factor: float = 1.0
    match_distance_m: float = 0.25
    map_radius_m: float = 12.0
    uncertainty_sigmas: float = 3.0
    max_match_distance_m: float = 1.0

    def __post_init__(self) -> None:
        _check(self.control_point_gate_factor > 0, "association.control_point_gate_factor must be > 0")
        _check(self.match_distance_m > 0, "association.match_distance_m must be > 0")
        _check(self.map_radius_m > 0, "association.map_radius_m must be > 0")
        _check(self.uncertainty_sigmas >= 0, "association.uncertainty_sigmas must be ≥ 0")
        _check(self.max_match_distance_m >= self.match_distance_m,
               "association.max_match_distance_m must be ≥ match_distance_m")


@dataclass(frozen=True)
class MappingConfig:
    """Growing the map (paper §III-F).

    Attributes:
        extend: extend map splines at their ends (True) or add new splines instead.
        min_extension_m: the shortest unmatched stretch of an observed spline that extends a
            map spline or becomes a new one (m).
        max_extension_rms_m: an extension is kept only if the extended curve passes within
            this RMS distance of the new points (m); otherwise the stretch starts a new
            spline. The extension continues the old curve with C² continuity, so a short,
            sparse stretch inherits the noisy end curvature of the old fit and can bend away
            from the wall by centimetres; this check keeps such bends out of the map.
        extension_fit_probability: an extension is kept only if its new points' squared
            distances to the extended curve, in units of ``observation.sigma_range_m``, sum to
            no more than this quantile of χ² with (points − new control points) degrees of
            freedom: the extension must fit its points as well as range noise explains,
            as well as within ``max_extension_rms_m`` (which bounds it where the range σ
            is large for walls' model error). None: the RMS bound alone. 0.5 (the median):
            the two errors cost unequally. A good extension refused costs a new spline
            where the wall goes on; a biased one kept (a cubic continued across the
            junction of a straight wall and an arc, a few millimetres off over a few
            points, which the 99 % quantile lets through) is read back as the robot's
            place by every later scan. At 0.5 the simulated double loops with extension
            stay in their NEES band on 94 % of the steps in rounded-room and mixed (52 %
            and 91 % at 0.99); on the real logs the RMS bound is the tighter check and
            nothing changes (docs/consistency.md).
        fit_bias_sigmas: a new map spline is refitted with half the knot spacing (down to
            ``spline.min_knot_spacing_m``) while the finer fit differs from it, somewhere
            along the normal, by more than this many σ of that difference under range
            noise alone (dimensionless; None disables the check). A cubic at ρ = 1 m cannot
            follow a straight wall running into a 2 m arc: 8 mm of bias over a few points,
            invisible in the fit's RMS, while the map spline's σ there is < 1 mm; every run
            then drifts the same way when the robot sees that stretch again (rounded-room,
            no extension: mean NEES 5–8 at steps 7–9, 13–15, 21–23; with the check none of
            those steps exceeds 3.7). Under range noise alone the largest score along a 140-
            point wall is below 3.65 in 99% of draws, so 4 rarely refines a good fit.
        prune_after_scans: a map spline that no update has used within this many scans of
            its creation leaves the state (0, the default, keeps every spline). Pruning
            bounds the state in clutter (first 300 scans of intel-noisy: 1919 state
            dimensions without, 1123 with 2), but in long corridors it removes the walls seen
            far ahead, at grazing incidence, before the robot reaches them, and with them
            what closes the loops: ATE after the second pass with 2 / 0 on aces-noisy
            0.32 / 0.18 m, csail-rawodom 0.95 / 0.22 m, intel-noisy 0.11 / 0.08 m,
            intel-rawodom 0.11 / 0.07 m, at 1.3–1.6× the state size.
    """

    extend: bool = True
    min_extension_m: float = 0.5
    max_extension_rms_m: float = 0.015
    extension_fit_probability: float | None = 0.5
    fit_bias_sigmas: float | None = 4.0
    prune_after_scans: int = 0

    def __post_init__(self) -> None:
        _check(self.min_extension_m >= 0, "mapping.min_extension_m must be ≥ 0")
        _check(self.prune_after_scans >= 0, "mapping.prune_after_scans must be ≥ 0")
        _check(self.max_extension_rms_m > 0, "mapping.max_extension_rms_m must be > 0")
        _check(self.extension_fit_probability is None or 0 < self.extension_fit_probability < 1,
               "mapping.extension_fit_probability must be in (0, 1) or None")
        _check(self.fit_bias_sigmas is None or self.fit_bias_sigmas > 0,
               "mapping.fit_bias_sigmas must be > 0 or None")


Mode = Literal["slam", "localization"]

#: The joint Gaussian's filter: "ekf" the paper's, "oc-ekf" the observability-constrained
#: EKF (:mod:`bsslam.slam.oc_ekf`), "invariant" the invariant EKF
#: (:mod:`bsslam.slam.invariant_ekf`).
EstimatorName = Literal["ekf", "oc-ekf", "invariant"]
BackendName = Literal["submaps", "ekf"]
LoopOutliers = Literal["cauchy", "gnc"]


@dataclass(frozen=True)
class FrontendConfig:
    """Scan matching and laser odometry.

    enabled: run the front end in :func:`bsslam.pipeline.run_dataset` and give the filter
        scan-matched increments with their covariance instead of the raw odometry. On by
        default for real logs; the simulator's experiments turn it off (they test the
        paper's filter against the odometry model they simulate).
    update_distance_m, update_angle_rad: the filter processes a scan once the robot has
        moved this far (m) or turned this much (rad) since the last scan it processed
        (GMapping's linearUpdate/angularUpdate, whose defaults these are); the scans in
        between only feed the front end. 0 and 0 process every scan. The wheels' odometry
        measures that motion, not the scan matches, so that which scans the filter sees
        does not turn on the ranges' last digits (:mod:`bsslam.frontend.update_schedule`).

    Beams and points
        min_range_m: beams at or below this range are dropped (m); the same quantity and
            default as ``segmentation.min_range_m`` (set both together).
        max_range_m: beams at or beyond this range are dropped (m). Far points move a lot
            for a small rotation error and are sparse; 30 m keeps the ends of long corridors
            (CSAIL, ACES), which are what fixes the motion along them.
        full_range_when_sparse: a scan with fewer than ``min_points`` returns within
            ``max_range_m`` (counted one per ``scan_voxel_m`` cell) keeps every return up to
            the sensor's range instead, and so does its keyframe: in open ground (a square,
            a car park) the far buildings are all there is to match, and without them the
            front end falls back to the wheels. No scan of the six building logs is that
            sparse; 41 of the campus's 2008 are (in runs of up to 19 at its scans
            1041–1059), with a median of 137 returns out to the sensor's 80 m.
        scan_voxel_m: the current scan is thinned to one point per cell of this size (m) so
            that dense near walls do not outweigh sparse far ones.
        max_scan_points: at most this many (evenly chosen) thinned points go into the
            Gauss–Newton refinement.
        search_points: at most this many of them go into the correlative search (its cost
            is linear in it).

    Submap
        submap_keyframes: the reference is the union of the last this-many keyframes.
        submap_voxel_m: the submap is thinned to one point per cell of this size (m).
        submap_rebuild_every: the submap's likelihood fields and KD-tree are rebuilt from
            the last ``submap_keyframes`` keyframes every this many keyframes; in between,
            a new keyframe is added to them in place (so the submap holds up to
            ``submap_keyframes + submap_rebuild_every − 1`` keyframes). 1 rebuilds always.
        keyframe_distance_m, keyframe_angle_rad: a scan becomes a keyframe when it is this
            far (m) or this much turned (rad) from the last keyframe.
        normal_neighbours: points used for each reference point's local line fit (normal).

    Correlative search (coarse to fine, around the odometry guess)
        search_window_m: half-width of the translation search (m) in x and y. The worst
            odometry errors between scans on the real logs are ~0.46 m (CSAIL).
        search_window_rad: half-width of the rotation search (rad); worst seen ~24° (CSAIL).
        coarse_step_m, coarse_step_rad: grid of the first level; its likelihood field has
            cells of half the step.
        coarse_sigma_m: blur of the first level's likelihood field (m); about the step so
            that a pose between grid nodes still scores.
        fine_step_m, fine_step_rad, fine_sigma_m: the same for the second level, searched
            ±1 coarse step around the best coarse candidates; its field's cells are one
            fine step.
        coarse_candidates: how many distinct coarse maxima are refined at the fine level.
        search_prior_weight: penalty on the correlative score (a mean likelihood in
            [0, 1]) at the corner of the search window, quadratic in the distance from the
            guess, so that equal scores (a corridor) prefer the odometry guess.

    Refinement (robust point-to-line Gauss–Newton)
        icp_iterations: Gauss–Newton iterations at most.
        icp_max_distance_m: correspondences farther than this are ignored (m) (first
            iteration; it shrinks to ``icp_min_distance_m`` as the match converges).
        icp_min_distance_m: the final correspondence gate (m).
        huber_m: Huber threshold of the residual weights (m).
        inlier_distance_m: a point is an inlier of the final match when its point-to-line
            residual is below this (m) and its nearest reference point within the gate.

    Covariance
        range_sigma_m: stated σ of one point-to-line residual (m): range noise plus wall
            roughness and the reference's own noise; the larger of it and the σ estimated
            from the residuals is used. Not ``observation.sigma_range_m``, the filter's σ of
            a range against a map spline (see there).
        covariance_inflation: the Gauss–Newton covariance assumes independent residuals;
            neighbouring points of one real wall are not, so it is multiplied by this
            factor. Without it the covariance is consistent on the simulator (independent
            range noise: mean NEES ≈ 3, tests/frontend); with ×10 the median NEES of the
            increments against the real logs' references is ≈ 4–5 (χ²₃ median 2.4), and
            those references carry cm/degree errors of their own
            (benchmarks/bench_frontend.py); on the simulator it is then ~×10 conservative.
        min_sigma_xy_m, min_sigma_rad: floors added to the match covariance (m, rad).
        filter_translation_scale: the filter predicts with a trusted match's increment
            covariance whose translation variances are × this (dimensionless; the
            translation σ × its square root, correlations kept, the heading's variance
            untouched); the front end's own gates and fallbacks (odometry) are not
            scaled. Why the two parts differ: the filter's range updates come from the few
            beams its splines explain (16–19 in a step in the large halls, a quarter of the
            scan), whose errors are shared along a wall, while the match registers hundreds
            of points; with the match's translation at its stated covariance the spline
            updates pull it about more than they correct it. Its heading, on the other
            hand, drifts in correlated steps that only the map can take out: tightened as
            well, a missed turn at a submap's start is never corrected (ACES) and the
            covariance claims too much (CSAIL). 0.3 against 1 over seeds 0–29 of the
            perturbed logs: Acapulco −11 %, the campus −12 %, Edmonton and ACES −7 %,
            CSAIL +2 %, Intel level (docs/real_logs.md). 1: as stated.

    Odometry model (prior of the refinement and covariance of a fallback)
        odom_sigma_xy_m, odom_sigma_xy_per_m: σ of Δx, Δy = a + b·|Δ| (m, m/m).
        odom_sigma_rad, odom_sigma_rad_per_rad, odom_sigma_rad_per_m: σ of Δφ =
            a + b·|Δφ| + c·|Δ| (rad, rad/rad, rad/m). Wide: the real wheel odometry of the
            1 Hz Intel log is off by up to ~20° in one step. The same form as the filter's
            ``motion`` model but not its values (see :class:`MotionNoiseConfig` for why).
        odometry_learned_window: how well the odometry's translation actually agrees with
            the scan matches is measured over the last this-many well-constrained trusted
            matches (the median of the squared disagreement, forward and sideways, in σ of
            the model above); a degenerate match (see ``degenerate_ratio``) is refined with
            that σ instead of the model's, so that where the wheels are good a corridor's
            weak direction comes from them rather than from the scan's few features along
            it (:meth:`bsslam.frontend.LaserOdometry.odometry_scale`). 0: the model's σ.
        fallback_learned: true (default): a fallback's covariance (the raw odometry
            increment where no match could be trusted) is the model's with each σ (Δx,
            Δy, Δφ) scaled by the RMS disagreement of the same matches with the odometry,
            once 20 are in: what the wheels err by in a step (in heading 0.16–0.18 of the
            model's σ on the logs with synthetic drift, 0.30 on Intel's wheels, 0.64 on
            CSAIL's; with ``odometry_learned_window`` 0 nothing is learned and the model's
            is used); and the filter step holding it is first tried with the model's σ: where
            the walls then put the pose beyond the learned prediction's 99 % region, it
            predicts with the model's (:meth:`bsslam.mapper.Mapper._checked_by_walls`).
            false: the model's, wide enough for the worst wheels. Of the shared logs only
            the campus falls back often (about 80 of its 2008 scans; CSAIL and intel-noisy
            once in some runs): over forty perturbed runs its online covariance goes from
            cautious (median NEES 0.3) to calibrated (1.6), its worst run from 0.473 to
            0.382 m, and a run takes 2.6 × less time (docs/real_logs.md, "A fallback as
            wide as the wheels err").

    Trust
        min_points: fewer valid points in the scan or in the reference → fall back.
        min_inlier_fraction: a match with fewer inliers (fraction of the refined points)
            is rejected → fall back.
        degenerate_ratio: when the smallest eigenvalue of the translation information is
            below this fraction of the largest, the match is flagged degenerate (a
            corridor); its weak direction then comes from the odometry prior, with the σ
            learned from the matches (``odometry_learned_window``), blended towards the
            model's as the ratio goes up to twice this.
        odometry_gate: a match whose increment lies beyond this probability region of
            the odometry increment (χ²₃ with both covariances: the odometry model's and
            the match's; after fallbacks also their error, which the match undoes) is
            rejected → fall back, as the filter gates an observation against its
            prediction; 1 turns the gate off.
        odometry_gate_steps: a match the gate rejects is still trusted when, composed
            after the trusted matches of up to this many − 1 steps before it, it agrees
            with the odometry composed over the same steps: an odometry skewed in time
            books motion to the wrong one of two neighbouring increments. 1 gates each
            increment alone.
    """

    # beams and points
    enabled: bool = True
    update_distance_m: float = 1.0
    update_angle_rad: float = 0.5
    min_range_m: float = 0.05
    max_range_m: float = 30.0
    full_range_when_sparse: bool = True
    scan_voxel_m: float = 0.1
    max_scan_points: int = 400
    search_points: int = 150
    # submap
    submap_keyframes: int = 20
    submap_voxel_m: float = 0.05
    submap_rebuild_every: int = 5
    keyframe_distance_m: float = 0.3
    keyframe_angle_rad: float = math.radians(10.0)
    normal_neighbours: int = 7
    # correlative search
    search_window_m: float = 0.6
    search_window_rad: float = math.radians(30.0)
    coarse_step_m: float = 0.2
    coarse_step_rad: float = math.radians(2.0)
    coarse_sigma_m: float = 0.2
    fine_step_m: float = 0.05
    fine_step_rad: float = math.radians(0.5)
    fine_sigma_m: float = 0.07
    coarse_candidates: int = 4
    search_prior_weight: float = 0.05
    # refinement
    icp_iterations: int = 20
    icp_max_distance_m: float = 0.3
    icp_min_distance_m: float = 0.15
    huber_m: float = 0.03
    inlier_distance_m: float = 0.08
    # covariance
    range_sigma_m: float = 0.02
    covariance_inflation: float = 10.0
    min_sigma_xy_m: float = 0.005
    min_sigma_rad: float = math.radians(0.2)
    filter_translation_scale: float = 0.3
    # odometry model
    odom_sigma_xy_m: float = 0.05
    odom_sigma_xy_per_m: float = 0.2
    odom_sigma_rad: float = math.radians(3.0)
    odom_sigma_rad_per_rad: float = 0.2
    odom_sigma_rad_per_m: float = math.radians(5.0)
    # trust
    min_points: int = 30
    min_inlier_fraction: float = 0.25
    degenerate_ratio: float = 0.02
    odometry_gate: float = 0.99
    odometry_gate_steps: int = 2
    odometry_learned_window: int = 200
    fallback_learned: bool = True

    def __post_init__(self) -> None:
        positive = ("max_range_m", "scan_voxel_m", "submap_voxel_m", "search_window_m", "search_window_rad",
                    "coarse_step_m", "coarse_step_rad", "coarse_sigma_m", "fine_step_m", "fine_step_rad",
                    "fine_sigma_m", "icp_max_distance_m", "icp_min_distance_m", "huber_m",
                    "inlier_distance_m", "range_sigma_m", "covariance_inflation")
        for name in positive:
            _check(getattr(self, name) > 0, f"frontend.{name} must be > 0, got {getattr(self, name)!r}")
        nonneg = ("min_range_m", "keyframe_distance_m", "keyframe_angle_rad", "search_prior_weight",
                  "min_sigma_xy_m", "min_sigma_rad", "odom_sigma_xy_m", "odom_sigma_xy_per_m", "odom_sigma_rad",
                  "odom_sigma_rad_per_rad", "odom_sigma_rad_per_m", "degenerate_ratio",
                  "update_distance_m", "update_angle_rad")
        for name in nonneg:
            _check(getattr(self, name) >= 0, f"frontend.{name} must be ≥ 0, got {getattr(self, name)!r}")
        _check(self.max_range_m > self.min_range_m, "frontend.max_range_m must exceed min_range_m")
        _check(isinstance(self.fallback_learned, bool),
               f"frontend.fallback_learned must be true or false, got {self.fallback_learned!r}")
        _check(isinstance(self.full_range_when_sparse, bool),
               f"frontend.full_range_when_sparse must be true or false, got {self.full_range_when_sparse!r}")
        _check(self.odom_sigma_xy_m > 0 and self.odom_sigma_rad > 0,
               "frontend.odom_sigma_xy_m and odom_sigma_rad must be > 0 (the fallback covariance)")
        for name in ("max_scan_points", "search_points", "submap_keyframes", "submap_rebuild_every", "coarse_candidates",
                     "icp_iterations", "min_points"):
            _check(getattr(self, name) >= 1, f"frontend.{name} must be ≥ 1, got {getattr(self, name)!r}")
        _check(3 <= self.normal_neighbours <= 50, "frontend.normal_neighbours must be 3..50")
        self._check_ceilings()
        _check(self.icp_min_distance_m <= self.icp_max_distance_m,
               "frontend.icp_min_distance_m must be ≤ icp_max_distance_m")
        _check(0 <= self.min_inlier_fraction <= 1, "frontend.min_inlier_fraction must be in [0, 1]")
        _check(self.search_window_rad < math.pi, "frontend.search_window_rad must be < π")
        _check(self.fine_step_m <= self.coarse_step_m and self.fine_step_rad <= self.coarse_step_rad,
               "frontend fine steps must not exceed the coarse ones")

    def _check_ceilings(self) -> None:
        """Upper bounds: σ and factors that make no physical sense, and the sizes of the
        correlative search (grids of offsets × rotations, likelihood fields), which grow with
        the square of window / step: a 10 km window once asked for 596 GiB."""
        for name in ("range_sigma_m", "min_sigma_xy_m", "odom_sigma_xy_m"):
            _check(getattr(self, name) <= MAX_SIGMA_M, f"frontend.{name} must be ≤ {MAX_SIGMA_M:g} m")
        for name in ("min_sigma_rad", "odom_sigma_rad", "odom_sigma_rad_per_m"):
            _check(getattr(self, name) <= MAX_SIGMA_RAD, f"frontend.{name} must be ≤ 2π")
        for name in ("odom_sigma_xy_per_m", "odom_sigma_rad_per_rad"):
            _check(getattr(self, name) <= 10.0, f"frontend.{name} must be ≤ 10")
        _check(self.covariance_inflation <= MAX_FACTOR, f"frontend.covariance_inflation must be ≤ {MAX_FACTOR:g}")
        _check(0 < self.filter_translation_scale <= MAX_FACTOR,
               f"frontend.filter_translation_scale must be in (0, {MAX_FACTOR:g}], got {self.filter_translation_scale!r}")
        _check(self.degenerate_ratio <= 1, "frontend.degenerate_ratio must be ≤ 1")
        _check(0 < self.odometry_gate <= 1, "frontend.odometry_gate must be in (0, 1]")
        _check(isinstance(self.odometry_gate_steps, int) and 1 <= self.odometry_gate_steps <= 10,
               "frontend.odometry_gate_steps must be an integer in [1, 10]")
        _check(isinstance(self.odometry_learned_window, int) and 0 <= self.odometry_learned_window <= 100_000,
               "frontend.odometry_learned_window must be an integer in [0, 100000]")
        _check(self.max_range_m <= MAX_LASER_RANGE_M,
               f"frontend.max_range_m must be ≤ {MAX_LASER_RANGE_M:g} m (2D laser scanners reach ~80 m)")
        _check(self.search_window_m <= MAX_SEARCH_WINDOW_M,
               f"frontend.search_window_m must be ≤ {MAX_SEARCH_WINDOW_M:g} m (the correlative search's ceiling; the "
               f"worst odometry error between scans of the real logs is ~0.46 m), got {self.search_window_m!r}")
        _check(self.search_window_m / self.coarse_step_m <= MAX_STEPS_PER_WINDOW,
               f"frontend.search_window_m / coarse_step_m must be ≤ {MAX_STEPS_PER_WINDOW} (coarse offsets per side)")
        _check(self.search_window_rad / self.coarse_step_rad <= MAX_STEPS_PER_WINDOW,
               f"frontend.search_window_rad / coarse_step_rad must be ≤ {MAX_STEPS_PER_WINDOW}")
        _check(self.coarse_step_m / self.fine_step_m <= MAX_FINE_PER_COARSE
               and self.coarse_step_rad / self.fine_step_rad <= MAX_FINE_PER_COARSE,
               f"frontend.coarse_step_m / fine_step_m and coarse_step_rad / fine_step_rad must be "
               f"≤ {MAX_FINE_PER_COARSE} (fine offsets per coarse step)")
        for level, cell, sigma in (("coarse", self.coarse_step_m / 2, self.coarse_sigma_m),
                                   ("fine", self.fine_step_m, self.fine_sigma_m)):
            side = 2 * (self.max_range_m + 2 * self.search_window_m + 3 * sigma) / cell
            _check(side <= MAX_FIELD_CELLS,
                   f"frontend: the {level} likelihood field would be {side:.0f} cells wide (2·(max_range_m + "
                   f"2·search_window_m + 3·{level}_sigma_m) / cell); at most {MAX_FIELD_CELLS}: "
                   f"raise {level}_step_m or lower max_range_m")
            _check(sigma <= 10 * cell, f"frontend.{level}_sigma_m must be ≤ 10 cells of its field ({10 * cell:g} m)")


# ceilings of the front end's search (see FrontendConfig._check_ceilings)
MAX_LASER_RANGE_M = 100.0
#: the correlative search's window (m), a scan's or a loop closure's: its coarse level
#: scores (2·window / coarse step)² offsets per heading
MAX_SEARCH_WINDOW_M = 20.0
MAX_STEPS_PER_WINDOW = 90
MAX_FINE_PER_COARSE = 20
MAX_FIELD_CELLS = 8000     # per side: 64 M float32 cells, 256 MB
#: a loop-closure search's window (m): it runs on the default front end's coarse grid
MAX_LOOP_WINDOW_M = min(MAX_SEARCH_WINDOW_M, MAX_STEPS_PER_WINDOW * FrontendConfig.coarse_step_m)


@dataclass(frozen=True)
class GridConfig:
    """The occupancy grid a run writes (``grid.pgm``/``grid.yaml``, ROS ``map_server``):
    log-odds evidence from every scan at its final pose, the map splines drawn in as occupied.

    Attributes:
        resolution_m: cell size (m).
        margin_m: unknown border around everything drawn (m).
        min_range_m: beams at or below this range are invalid and ignored (m).
        no_return_clear_m: a "no return" beam (range inf or ≥ the scan's max_range) clears
            free space up to this distance (m); 0 ignores such beams. Nothing reflected
            within the sensor's range, but glass and black surfaces also return nothing,
            so only the near part is trusted.
        footprint_radius_m: cells within this distance of a robot pose are free whatever
            the beams said: the robot stood there (m). With a forward-looking laser no later
            scan looks back at the start, so its cell would otherwise stay unknown; 0 turns
            this off.
        log_odds_hit: log-odds added to the cell of a return (> 0; 0.85 is p = 0.7).
        log_odds_miss: log-odds added to a cell a beam passes through (< 0; −0.4 is p = 0.4).
            A cell takes at most one update per scan, and a return wins over a pass-through
            of the same scan (a wall cell grazed by a neighbouring beam stays a wall).
        log_odds_limit: log-odds are clamped to ±this after every update, so a cell can
            change its mind after a bounded number of contrary scans (> 0).
        occupied_thresh: a cell is occupied when p > this (probability, as map_server's).
        free_thresh: a cell is free when p < this (probability). Both go into grid.yaml;
            the image is trinary (0 occupied, 254 free, 205 unknown), which map_server reads
            back to the same classes only while free_thresh < 50/255 ≈ 0.19608 < occupied_thresh.
        max_cells: the largest grid (cells) a run may allocate; a larger extent (a wild
            range or pose) is an error naming this key, never a huge allocation. 8 bytes
            a cell while building: the default is at most 400 MB.
    """

    resolution_m: float = 0.05
    margin_m: float = 1.0
    min_range_m: float = 0.05
    no_return_clear_m: float = 5.0
    footprint_radius_m: float = 0.2
    log_odds_hit: float = 0.85
    log_odds_miss: float = -0.4
    log_odds_limit: float = 4.0
    occupied_thresh: float = 0.65
    free_thresh: float = 0.196
    max_cells: int = 50_000_000

    def __post_init__(self) -> None:
        _check(self.resolution_m > 0, "grid.resolution_m must be > 0")
        _check(self.margin_m >= 0, "grid.margin_m must be ≥ 0")
        _check(self.min_range_m >= 0, "grid.min_range_m must be ≥ 0")
        _check(0 <= self.no_return_clear_m < math.inf, "grid.no_return_clear_m must be ≥ 0 and finite")
        _check(0 <= self.footprint_radius_m < math.inf, "grid.footprint_radius_m must be ≥ 0 and finite")
        _check(self.log_odds_hit > 0, "grid.log_odds_hit must be > 0")
        _check(self.log_odds_miss < 0, "grid.log_odds_miss must be < 0")
        _check(self.log_odds_limit > 0, "grid.log_odds_limit must be > 0")
        _check(1 / 255 < self.free_thresh < 50 / 255 < self.occupied_thresh < 1,
               "grid.free_thresh and grid.occupied_thresh must satisfy 1/255 < free_thresh < 50/255 "
               "< occupied_thresh < 1 (the trinary image's grey values must read back as written)")
        _check(isinstance(self.max_cells, int) and self.max_cells >= 1, "grid.max_cells must be an integer ≥ 1")


@dataclass(frozen=True)
class SubmapConfig:
    """The submap backend (``backend: submaps``): the paper's filter runs inside a local
    submap of bounded size; full submaps are frozen and tied together by a pose graph
    (GTSAM iSAM2) with loop closures found by matching submap against submap.

    Attributes:
        max_state_size: a submap is full when its filter's state reaches this dimension
            (3 pose + 2 per control point). It bounds the per-scan cost (the covariance
            update is O(n²)) and the live covariance's memory (8 n² bytes).
        max_distance_m: … or when the robot has travelled this far in it (m): a submap
            is a local map, its drift small.
        carry_over_m: a new submap starts with the old one's splines that come within
            this distance of the robot (m), their covariance relative to it, instead of
            with one scan's splines; 0 starts every submap empty.
        seam_drift_m_per_m: the local filter drifts by about this much per metre
            travelled beyond what its covariance says (m/m): the constraint between a
            submap's base and the next one's gets (this × the distance travelled in the
            submap)² added to its x and y variance
            (:func:`~bsslam.submaps.backend.seam_covariance`); 0 takes the filter's
            covariance as it is. The default, 0.125 m over a submap's ~25 m, is about what
            the seams err by on Edmonton, Acapulco, ACES, Intel and CSAIL: 0.06–0.22 m
            (a run's median; ``benchmarks/seam_sources.py``, docs/real_logs.md).
        seam_drift_rad_per_m: … and (this × the distance)² to its heading variance (rad/m);
            the default, 0.72° over 25 m, is how far each submap turns against the one
            before it once the graph has placed them on Edmonton, Acapulco, ACES,
            intel-noisy and CSAIL (0.63–0.74° RMS, ``benchmarks/error_budget.py``; the
            seams against single reference poses, which err by a few tenths of a degree
            themselves: 0.75–1.7° RMS).
        drift_rate_sigma_rad_per_m: σ of a heading drift rate every seam shares (rad/m):
            an unknown of the pose graph, zero-mean a priori, that turns each seam by
            (rate × the distance travelled in its submap); the loop closures estimate it
            and it corrects the seams no loop closure reaches
            (:mod:`~bsslam.submaps.drift_factor`). 0 leaves it out.
        point_spacing_m: spacing of the points sampled on a frozen submap's splines for
            matching (m).
        loop_sigmas: a loop-closure search covers this many σ of the relative pose
            between the two submaps, as the pose graph's marginals give it.
        loop_min_window_m: … and at least this far in x and y (m), for drift larger than
            the filter admits;
        loop_max_window_m: … and at most this far (m), bounding the search's cost (which
            grows with the window's area: about 1 s per candidate at 12 m; at most
            ``MAX_LOOP_WINDOW_M``, 18 m). A window narrower than the drift cannot hold the true
            alignment, and then a copy of the structure within it (a facade, a row of
            trees) is what the search finds; a wider one also holds more rivals (turned
            ones among them) that the checks must tell from the truth. On the campus, ten
            perturbed runs and float32 each with every other default: 12 m (with ``gnc``)
            gives a median of 1.69 m and six runs of eleven within 0.63 m, 5 m (with
            ``cauchy``) 2.65 m and four; the other shared logs never need more than 5 m.
        loop_min_window_rad: the same bounds for the heading (rad).
        loop_max_window_rad:
        loop_max_candidates: old submaps matched against each newly frozen one, nearest
            first (bounds the time per submap).
        online_match_m: the growing submap is matched against the old ones it has not
            matched yet (as a frozen one is, up to ``loop_max_candidates`` of them) every
            time the robot has travelled this far in it (m), and the current base pose and
            its covariance are the graph's conditioned on the matches the graph vouches for
            (:meth:`~bsslam.submaps.pose_graph.PoseGraph.conditioned`). They do not enter
            the graph: the full submap's match replaces them when it is frozen. So the
            online pose is tied to the old map as soon as the robot is back in it, not a
            whole submap later; the final trajectory and map do not change. 0 (default):
            only frozen submaps are matched. At 5 m the Intel logs' online pose is about
            20 % closer to the reference, the other shared logs' within 6 %, for 8–36 % more
            time (docs/real_logs.md, "The growing submap matched").
        loop_sweep: at the end of a run, match each frozen submap again against up to
            ``loop_max_candidates`` older ones whose areas overlap it where the final graph
            puts them and that no loop closure ties to it yet, with the final graph's
            guesses and windows, and add the verified matches before the second pass
            (:meth:`~bsslam.submaps.SubmapSLAM.sweep_loops`). A newly frozen submap is
            matched once, against the graph as it then stood: a window as wide as the
            drift then, a guess later loop closures moved. Ten perturbed runs and float32
            of each shared log (2026-12-05, paired with the same runs without it): medians
            −4 % to +2 %, the worst runs of Acapulco 0.606 → 0.530 m, ACES 0.249 → 0.230,
            the campus 1.69 → 1.50; it costs about a tenth of a run (intel-rawodom 0.8 s,
            the campus 9 s). Every overlapping pair instead of four per submap gave
            intel-rawodom 0.099 m and Acapulco's worst run 0.435 m but the campus 0.412
            against 0.398 m, with four times the matches (ten perturbed runs each). The
            online estimate does not change.
        loop_min_inlier_fraction: a loop closure is accepted only if this fraction of
            the query submap's points that overlap the reference (see
            ``loop_overlap_distance_m``) lie on the reference's splines after alignment;
            each overlapping query curve is held to it too (the joint-compatibility vote).
            A near-symmetric building matched turned round scores ~0.86, the truth 1.0
            (simulation, tests/submaps).
        loop_min_overlap_m: … and the matched wall length is at least this (m).
        loop_max_ambiguity: … and no distinct alignment that the match's own covariance
            does not admit (beyond its 99 % region) scores more than this fraction of the
            best (repetitive structure matches in several places; an alternative along a
            corridor the covariance leaves free is the same answer, not a rival: the rival
            is the best alignment beyond that region), when the pose graph tells the two
            apart: the match lies within the 99 % region of the graph's relative pose and
            the rival beyond it.
        loop_max_ambiguity_alone: … and this fraction when the graph does not (it admits
            both, or neither: a match it did not expect), so that the walls alone must.
            Ten perturbed runs and float32 of every shared log (2026-12-05): the campus
            0.397 m (0.350–1.69; 0.498) against 0.419 (0.342–3.59; 1.13) with one bound of
            0.9 for all (seeds 10–19: every run within 0.49 m against two beyond 1 m), the
            buildings within 3 % of their medians; 0.8 for every match costs ACES and CSAIL
            12 % (README, Real logs; docs/real_logs.md).
        loop_slides: keep a match whose rival lies on a ridge of the same score from it (a
            slide along straight walls: every pose between them scores above the bound),
            its covariance widened along the ridge to at least the search window, instead
            of refusing it as ambiguous; the best alignment beyond the slide is then the
            rival, held to the same bound. Ten perturbed runs and float32 of every shared
            log (2026-12-07): Acapulco 4 % better run for run (spread 0.75 → 0.33), the
            campus 2 % (0.22 → 0.20), the others within 1 %; over more seeds the medians
            are level and Acapulco's worst run stays lower (0.26 m against 0.34 m over
            thirty) (docs/real_logs.md, "Loop closures along a wall"). False: every such
            match refused, as before.
        loop_covariance_inflation: the matched relative pose's covariance is inflated by
            this factor (its points are not independent).
        loop_inlier_distance_m: after alignment a query point is an inlier when its
            nearest reference point is this close (m).
        loop_overlap_distance_m: … and it counts as overlapping the reference (the
            denominator of the inlier fraction) when that point is this close (m): two
            submaps overlap only partly, the rest of the query says nothing.
        loop_min_information_ratio: a match is degenerate (a featureless corridor, one
            arc) when the smallest eigenvalue of its information, rotation scaled to metres
            at the submap's radius, is below this fraction of the largest. Above it the
            match is kept and its covariance carries the weak direction (large variance
            there): in the convention-centre logs the right matches had ratios of
            0.001–0.016, a straight corridor has ~1e-30.
        loop_distinct_m, loop_distinct_rad: alignments farther apart than this (m) or
            turned more than this (rad) are distinct for the ambiguity test.
        loop_search_points: at most this many (evenly chosen) query points go into the
            correlative search; ``loop_refine_points`` into the refinement.
        loop_refine_points:
        loop_support_submaps: 0 admits every verified match into the graph at once.
            N > 0 (default 5): verified matches vote on each other — two whose submaps are
            each within N submaps of the other's agree when the cycle they close through
            the submaps' odometry-like constraints is consistent (χ²(3) at 99 %), disagree
            when it is not; a consistent cycle agrees only when it can tell the match
            from the alignment it could be confused with: the runner-up its search found
            (its *rival*), or, without one, any alignment ``loop_distinct_m`` /
            ``loop_distinct_rad`` away; an inconsistent cycle always disagrees
            (:func:`~bsslam.submaps.loop_support.votes`). A match the graph expects (within the 99 % region
            of its relative pose, found in a search window that covered ``loop_sigmas`` σ
            of it: one clipped at ``loop_max_window_m`` saw only part of what the graph
            admits) enters unless more neighbours disagree than agree; any other, a
            surprising one, only once more agree than disagree, and is dropped
            (``unsupported``) when no later match can vote on it any more. Ten perturbed
            runs and float32 of every shared log (2026-12-04): the campus's median ATE
            0.414 m against 0.565 m with 0, its ten perturbed runs within 0.332–0.490 m
            against 0.398–6.03 m (a facade of submap 4 matched 9 m off in submap 55, which
            the graph took and bent the next matches to); every other log the same to the
            last digit. N = 3 gives the campus 0.429 m (0.385–1.43): in its seed 4 the
            copies 5.5 m off that followed the wrong match (0 → 60, 6 → 73–75, 3 → 193)
            entered, and with 5 they stay out (the campus's submaps are about 10 m long,
            the buildings' 25 m). Before cycles were judged against the
            rival (only against the fixed thresholds) 3 gave the campus 0.454 m and a worst
            run of 2.34 m (README, Limits; :mod:`bsslam.submaps.loop_support`).
        loop_max_wall_sigma_m: with a value > 0, a frozen submap's walls whose place in it
            is known to worse than this (m; the median σ of their control points) take no
            part in loop closure (they stay in the map); 0 (default) matches every wall.
            At 0.5 m (``loop_distinct_m``: such a wall cannot tell distinct alignments
            apart) Acapulco's worst of ten perturbed runs goes from 2.64 to 0.53 m and the
            campus's median from 3.9 to 0.9 m, but three campus runs of eleven and the
            as-logged one are lost (23–64 m) to matches turned by 58–149°, against none
            beyond 12.2 m without it, so it is off (README, Limits).
        loop_wall_covariance: a loop closure's covariance includes how well the matched
            walls' places are known in their own submaps (the local filters' drift when
            they saw them; :func:`~bsslam.submaps.loop_closure.matched_walls_covariance`),
            not only how well the walls align. Without it a match between two submaps
            each a few centimetres off inside carries a σ of 1 cm, and the graph bends its
            seams to it (the simulated double loop's final pose 0.11 m off at NEES 295 with
            ``gnc``). false: the alignment's covariance alone (the behaviour before
            2026-12-04).
        loop_outliers: how the pose graph guards against a wrong loop closure that passed
            the checks above (one that looks right locally but that the rest of the graph
            contradicts): ``gnc`` (default) classifies every loop closure afresh, by
            graduated non-convexity with a truncated-least-squares loss, whenever new ones
            break the classification, and sets the outliers aside; ``cauchy`` puts every
            loop closure behind a Cauchy kernel in iSAM2, which down-weights it smoothly
            but from wherever the graph stands, so a few wrong loop closures can hold a
            large graph in a local minimum (the Freiburg campus). GNC chooses whole groups
            of loop closures that agree with one another, so it needs honest covariances:
            before loop closures counted their walls' σ (``loop_wall_covariance``) it kept a
            consistent group 0.12 m off in the simulated double loop. With them, ten
            perturbed runs and float32 of every shared log: the same figures as ``cauchy``
            on the six building logs, the campus's median 1.69 against 2.65 m (README).
        robust_kernel_width: (``cauchy``) width of the Cauchy kernel in whitened units (σ):
            a loop closure this many σ from the graph's consensus is down-weighted by half.
        loop_inlier_probability: (``gnc``) a loop closure is an inlier when its whitened
            squared residual at the solution is within the χ²(3) quantile at this
            probability.
    """

    max_state_size: int = 400
    max_distance_m: float = 25.0
    carry_over_m: float = 10.0
    seam_drift_m_per_m: float = 0.005
    seam_drift_rad_per_m: float = 0.0005
    drift_rate_sigma_rad_per_m: float = 0.0
    point_spacing_m: float = 0.05
    loop_sigmas: float = 3.0
    loop_min_window_m: float = 2.0
    loop_max_window_m: float = 12.0
    loop_min_window_rad: float = math.radians(20.0)
    loop_max_window_rad: float = math.pi
    loop_max_candidates: int = 4
    online_match_m: float = 0.0
    loop_sweep: bool = True
    loop_min_inlier_fraction: float = 0.8
    loop_min_overlap_m: float = 8.0
    loop_max_ambiguity: float = 0.9
    loop_max_ambiguity_alone: float = 0.8
    loop_slides: bool = True
    loop_covariance_inflation: float = 10.0
    loop_inlier_distance_m: float = 0.1
    loop_overlap_distance_m: float = 1.0
    loop_min_information_ratio: float = 1e-4
    loop_distinct_m: float = 0.5
    loop_distinct_rad: float = math.radians(10.0)
    loop_search_points: int = 400
    loop_refine_points: int = 1500
    loop_support_submaps: int = 5
    loop_max_wall_sigma_m: float = 0.0
    loop_wall_covariance: bool = True
    loop_outliers: LoopOutliers = "gnc"
    robust_kernel_width: float = 3.0
    loop_inlier_probability: float = 0.99

    def __post_init__(self) -> None:
        _check(isinstance(self.max_state_size, int) and self.max_state_size >= 50,
               "submaps.max_state_size must be an integer ≥ 50")
        _check(self.max_distance_m > 0, "submaps.max_distance_m must be > 0")
        _check(0 <= self.carry_over_m <= 100.0, "submaps.carry_over_m must be in [0, 100] m")
        _check(0 <= self.seam_drift_m_per_m <= 1.0, "submaps.seam_drift_m_per_m must be in [0, 1] m/m")
        _check(0 <= self.seam_drift_rad_per_m <= 0.1, "submaps.seam_drift_rad_per_m must be in [0, 0.1] rad/m")
        _check(0 <= self.drift_rate_sigma_rad_per_m <= 0.1,
               "submaps.drift_rate_sigma_rad_per_m must be in [0, 0.1] rad/m")
        _check(0 < self.point_spacing_m <= 1.0, "submaps.point_spacing_m must be in (0, 1] m")
        _check(self.loop_sigmas > 0, "submaps.loop_sigmas must be > 0")
        # The window is the correlative search's, on the default front end's coarse grid
        # (loop_closure.matcher_config): bounded here, not at the first loop closure.
        _check(0 < self.loop_min_window_m <= self.loop_max_window_m <= MAX_LOOP_WINDOW_M,
               f"submaps.loop_min_window_m ≤ loop_max_window_m must be in (0, {MAX_LOOP_WINDOW_M:g}] m (the "
               f"correlative search's {MAX_STEPS_PER_WINDOW} coarse offsets of {FrontendConfig.coarse_step_m:g} m "
               f"per side)")
        _check(0 < self.loop_min_window_rad <= self.loop_max_window_rad <= math.pi,
               "submaps.loop_min_window_rad ≤ loop_max_window_rad must be in (0, π]")
        _check(isinstance(self.loop_max_candidates, int) and 0 <= self.loop_max_candidates <= 100,
               "submaps.loop_max_candidates must be an integer in [0, 100] (0: no loop closure)")
        _check(math.isfinite(self.online_match_m) and self.online_match_m >= 0,
               f"submaps.online_match_m must be finite and ≥ 0 m (0: off), got {self.online_match_m!r}")
        _check(isinstance(self.loop_sweep, bool), f"submaps.loop_sweep must be true or false, got {self.loop_sweep!r}")
        _check(0 < self.loop_min_inlier_fraction <= 1, "submaps.loop_min_inlier_fraction must be in (0, 1]")
        _check(self.loop_min_overlap_m >= 0, "submaps.loop_min_overlap_m must be ≥ 0")
        _check(0 < self.loop_max_ambiguity <= 1, "submaps.loop_max_ambiguity must be in (0, 1]")
        _check(0 < self.loop_max_ambiguity_alone <= self.loop_max_ambiguity,
               "submaps.loop_max_ambiguity_alone must be in (0, loop_max_ambiguity]")
        _check(isinstance(self.loop_slides, bool), f"submaps.loop_slides must be true or false, got {self.loop_slides!r}")
        _check(1 <= self.loop_covariance_inflation <= MAX_FACTOR,
               "submaps.loop_covariance_inflation must be in [1, 1e6]")
        _check(0 < self.loop_inlier_distance_m <= self.loop_overlap_distance_m <= 10.0,
               "submaps.loop_inlier_distance_m ≤ loop_overlap_distance_m must be in (0, 10] m")
        _check(0 <= self.loop_min_information_ratio <= 1, "submaps.loop_min_information_ratio must be in [0, 1]")
        _check(self.loop_distinct_m > 0 and 0 < self.loop_distinct_rad <= math.pi,
               "submaps.loop_distinct_m must be > 0 and loop_distinct_rad in (0, π]")
        for name in ("loop_search_points", "loop_refine_points"):
            _check(isinstance(getattr(self, name), int) and 30 <= getattr(self, name) <= 100_000,
                   f"submaps.{name} must be an integer in [30, 100000]")
        _check(isinstance(self.loop_support_submaps, int) and 0 <= self.loop_support_submaps <= 100,
               "submaps.loop_support_submaps must be an integer in [0, 100] (0: every verified match)")
        _check(0 <= self.loop_max_wall_sigma_m <= 100,
               "submaps.loop_max_wall_sigma_m must be in [0, 100] m (0: every wall)")
        _check(isinstance(self.loop_wall_covariance, bool),
               f"submaps.loop_wall_covariance must be true or false, got {self.loop_wall_covariance!r}")
        _check(self.loop_outliers in ("cauchy", "gnc"), "submaps.loop_outliers must be 'cauchy' or 'gnc'")
        _check(self.robust_kernel_width > 0, "submaps.robust_kernel_width must be > 0")
        _check(0 < self.loop_inlier_probability < 1, "submaps.loop_inlier_probability must be in (0, 1)")


@dataclass(frozen=True)
class SLAMConfig:
    """Everything the filter needs. ``mode`` is "slam" (full EKF-SLAM) or "localization"
    (localisation with map building: features fixed with zero uncertainty, paper §9).

    Attributes:
        initial_pose_sigma: σ of the initial pose (x m, y m, φ rad).
        relocalize: after the run, localise every scan again in the final map, held fixed
            (:func:`bsslam.pipeline.relocalize`), and report that trajectory. The online
            filter cannot move a pose once it is past, so the poses before a loop closure
            keep the drift the closure took out of the map; this pass puts them where the
            final map says they were. It reuses the first pass's front-end increments and
            fitted splines; on intel-rawodom it is 9.4 s of a 48 s run.
        input: the physical limits every scan and odometry pose is checked against where it
            enters (the log readers, :meth:`bsslam.Mapper.add`): beams per scan, plausible
            speed and turn rate, coordinates, laser offset (see
            :class:`~bsslam.input_limits.InputLimits`).
        backend: "submaps" (default): the filter runs in local submaps of bounded size tied
            together by a pose graph with loop closures (:mod:`bsslam.submaps`), so memory
            and time per scan stay bounded on any building; "ekf": the paper's single
            global EKF over every spline (the experiments, small rooms).
        submaps: the submap backend's parameters (:class:`SubmapConfig`).
        max_memory_mb: budget for the live estimator arrays (MB): the covariance and the
            frozen submaps. A run that would exceed it stops with a clear message and
            writes its results so far.
        estimator: "invariant" (default): the EKF in right-invariant error coordinates
            (Barrau and Bonnabel), where global translation and rotation are the same
            directions at every estimate, so no update can inform them, exactly (full SLAM
            only; localisation in a given map uses the EKF); "ekf": the paper's filter
            (its experiments use it); "oc-ekf": the observability-constrained EKF (Huang,
            Mourikis, Roumeliotis), whose linearisations keep those directions
            unobservable by first estimates. On the shared logs the invariant EKF keeps the
            heading's σ where the paper's EKF shrinks it seeing only new walls (CSAIL's
            first scans: 10.5° against 1.3° with the heading 13° off), which took the
            campus's online poses outside their 95 % region from 20 % to 6 % (README).
    """

    spline: SplineConfig = field(default_factory=SplineConfig)
    segmentation: SegmentationConfig = field(default_factory=SegmentationConfig)
    motion: MotionNoiseConfig = field(default_factory=MotionNoiseConfig)
    observation: ObservationConfig = field(default_factory=ObservationConfig)
    association: AssociationConfig = field(default_factory=AssociationConfig)
    mapping: MappingConfig = field(default_factory=MappingConfig)
    frontend: FrontendConfig = field(default_factory=FrontendConfig)
    grid: GridConfig = field(default_factory=GridConfig)
    input: InputLimits = field(default_factory=InputLimits)
    submaps: SubmapConfig = field(default_factory=SubmapConfig)
    backend: BackendName = "submaps"
    max_memory_mb: float = 1024.0
    mode: Mode = "slam"
    initial_pose_sigma: tuple[float, float, float] = (0.0, 0.0, 0.0)
    relocalize: bool = True
    estimator: EstimatorName = "invariant"

    def __post_init__(self) -> None:
        _check(self.mode in ("slam", "localization"), f"mode must be 'slam' or 'localization', got {self.mode!r}")
        _check(self.backend in ("submaps", "ekf"), f"backend must be 'submaps' or 'ekf', got {self.backend!r}")
        _check(1.0 <= self.max_memory_mb <= 1e7, "max_memory_mb must be in [1, 1e7] MB")
        _check(self.estimator in ("ekf", "oc-ekf", "invariant"),
               f"estimator must be 'ekf', 'oc-ekf' or 'invariant', got {self.estimator!r}")
        _check(isinstance(self.relocalize, bool), f"relocalize must be true or false, got {self.relocalize!r}")
        _check(len(self.initial_pose_sigma) == 3 and all(s >= 0 for s in self.initial_pose_sigma),
               "initial_pose_sigma must be three values ≥ 0")
        _check(max(self.initial_pose_sigma[:2]) <= 1000.0 and self.initial_pose_sigma[2] <= MAX_SIGMA_RAD,
               "initial_pose_sigma must be ≤ 1000 m (x, y) and ≤ 2π (φ)")

    def to_dict(self) -> dict[str, Any]:
        """Nested plain dict (YAML/JSON-ready)."""
        d = dataclasses.asdict(self)
        d["initial_pose_sigma"] = list(self.initial_pose_sigma)
        return d

    @classmethod
    def from_dict(cls, data: dict[str, Any] | None) -> "SLAMConfig":
        """Build from a nested dict; unknown keys are an error (no silent typos), every value
        is checked against its field's type (see the module docstring) and range.

        Raises:
            ConfigError: an unknown key, a section that is not a mapping, a value of the
                wrong type (naming ``section.key`` and the expected type) or out of range.
        """
        data = dict(data or {})
        sections = {f.name: f for f in dataclasses.fields(cls)}
        kwargs: dict[str, Any] = {}
        for key, value in data.items():
            if key not in sections:
                raise ConfigError(f"unknown configuration key {key!r}; known: {sorted(sections)}")
            sub = _SECTION_TYPES.get(key)
            if sub is not None:
                if not isinstance(value, dict):
                    raise ConfigError(f"configuration section {key!r} must be a mapping")
                known = {f.name for f in dataclasses.fields(sub)}
                unknown = set(value) - known
                if unknown:
                    raise ConfigError(f"unknown key(s) {sorted(unknown)} in section {key!r}; known: {sorted(known)}")
                kwargs[key] = sub(**_typed_fields(sub, value, f"{key}."))
            else:
                kwargs.update(_typed_fields(cls, {key: value}, ""))
        return cls(**kwargs)

    def replace(self, **sections: Any) -> "SLAMConfig":
        """A copy with whole sections or top-level fields replaced."""
        return dataclasses.replace(self, **sections)


_SECTION_TYPES = {
    "spline": SplineConfig,
    "segmentation": SegmentationConfig,
    "motion": MotionNoiseConfig,
    "observation": ObservationConfig,
    "association": AssociationConfig,
    "mapping": MappingConfig,
    "frontend": FrontendConfig,
    "grid": GridConfig,
    "input": InputLimits,
    "submaps": SubmapConfig,
}
