"""A sign map from a survey: every sign's pose in one map frame, from images that see signs together.

Each observation is one sign seen in one image: the pose T_cam_sign (X_cam = R·X_sign + t) with its
6x6 covariance over [rotation vector of R, t] (`pipeline.pose`). A pose graph (GTSAM) holds one Pose3
per sign (T_map_sign) and one per image (T_map_cam) and, per observation, a BetweenFactorPose3 from
the image to the sign measuring T_cam_sign = T_map_cam⁻¹·T_map_sign. The anchor sign (the map frame
is its frame) or the signs of a known map fix the frame with priors. Levenberg-Marquardt solves it
under a Huber kernel, so that a bad detection (a flipped planar pose, a wrong sign) pulls little;
an observation whose whitened residual is then beyond CHI2_REJECT, at the survey's own scale of
the covariances (`_covariance_scale`), is rejected, the graph is solved again without the rejected
ones and without the kernel, and GTSAM's Marginals give every sign's covariance. Each sign's photos
share part of their error (SHARED_SHARE): the observations measure where the photos see the sign,
tied to where it is by that shared error, which no number of photos averages out.

Covariance conventions. GTSAM's Pose3 tangent is ξ = [ω, v] (rotation first) and perturbs on the
right, T = T̂·Exp(ξ): R = R̂·Exp(ω), t = t̂ + R̂·v to first order. A measured pose's covariance is
over [δr, δt], δr the change of R's rotation vector r: R̂·Exp(ω) = Exp(r + δr) gives
ω = J_r(r)·δr (J_r the SO(3) right Jacobian, J_l(r)ᵀ), and v = R̂ᵀ·δt (`gtsam_covariance`). The map
file's covariance is ROS-ordered [δp, δθ] with the rotation about the map's axes on the left,
R = Exp(δθ)·R̂: R̂·Exp(ω) = Exp(R̂ω)·R̂ gives δθ = R̂·ω, and δp = R̂·v (`ros_covariance` and
its inverse `gtsam_from_ros`).
"""

from __future__ import annotations

import math
from collections import Counter, defaultdict
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from typing import Protocol

import gtsam
import numpy as np

from .pose import Pose, euler_zyx_deg
from .pose_filter import FALLBACK_SIGMA, left_jacobian, log_so3
from .sign_map import DEFAULT_FRAME, MappedSign, SignMap

# Huber's threshold on an observation's whitened residual norm: the 95 % point of a 6-dof chi
# distribution (sqrt(12.59)), so that consistent observations keep their full weight.
HUBER_K = math.sqrt(12.592)
# A whitened squared residual beyond this, after the robust solve, is an inconsistent observation:
# the 99.9 % point of chi-square with 6 dof, which a consistent one passes once in a thousand.
CHI2_REJECT = 22.458
# The median of chi-square with 6 dof: an observation's whitened squared residual, were its covariance exact.
CHI2_MEDIAN = 5.348
# What every photo of one sign shares of its pose's error (its edges pulled the same way by the wall
# beside them in every view, which no number of photos averages out), as a share of the 1σ of its
# median observation: on bench/map.py's surveys at 1280x960 (36 signs), a sign's median error over
# its photos, less what their number leaves of their scatter, is 0.14-0.19 of that 1σ in rotation
# and 0.37 along its normal (signs seen nearer than they are).
SHARED_SHARE = 0.3
# Fewer degrees of freedom than this leave the survey's own scale of the covariances unmeasured (1 is
# kept); the scale is kept above MIN_SCALE, so that a survey of exact poses keeps a solvable graph.
MIN_DOF_FOR_SCALE = 30
MIN_SCALE = 0.01
# σ of the priors that fix the anchor, and the known signs given without covariance (m and rad):
# tight enough to fix them, loose enough to keep the information matrix well conditioned.
FIXED_SIGMA = 1e-6
# A flight's frames close in time see a sign with nearly the same errors, which the pose graph would
# count as independent: one frame in this many is taken, besides every frame that links two signs.
FLIGHT_STEP = 10


class MapBuildError(ValueError):
    """A survey from which no map can be built; the message says why and what to do."""


class DisconnectedSurvey(MapBuildError):
    """The survey's signs fall into groups that no image links; `groups` (sorted sign ids each) are
    those that no anchor or known sign fixes, `fixed_groups` those that one does."""

    def __init__(self, message: str, groups: list[list[str]], fixed_groups: list[list[str]]) -> None:
        super().__init__(message)
        self.groups, self.fixed_groups = groups, fixed_groups


@dataclass(frozen=True, eq=False)
class Observation:
    """Sign `sign_id` seen in image `image` (any id of the image: its file, a flight's frame):
    X_cam = R·X_sign + t (R (3, 3), t (3,) metres), `covariance` (6, 6) over [rotation vector of R
    (rad), t (m)] or None (FALLBACK_SIGMA is assumed)."""

    image: str
    sign_id: str
    R: np.ndarray
    t: np.ndarray
    covariance: np.ndarray | None = None


@dataclass(frozen=True)
class Rejected:
    """An observation left out as inconsistent: its whitened squared residual `chi2` after the robust solve."""

    observation: Observation
    chi2: float


@dataclass(frozen=True)
class SignReport:
    """How the survey saw one sign: `images` that saw it (after rejection), `seen_with` the other
    signs in those images and in how many, `fixed` "anchor" or "known" (None: estimated), the
    1-sigma along the worst direction of its position (mm) and rotation (degrees)."""

    sign_id: str
    images: int
    seen_with: dict[str, int]
    fixed: str | None
    sigma_position_mm: float
    sigma_rotation_deg: float
    rejected: int = 0

    def lines(self) -> list[str]:
        """The report as lines of text (the map file's comments under the sign)."""
        how = (f"fixed ({self.fixed})" if self.fixed is not None
               else f"1-sigma {self.sigma_position_mm:.1f} mm, {self.sigma_rotation_deg:.3f} deg")
        with_ = ", ".join(f"{s} ({n})" for s, n in sorted(self.seen_with.items())) or "no other sign"
        lines = [f"{how}; seen in {self.images} image(s), with {with_}"]
        if self.rejected:
            lines.append(f"{self.rejected} observation(s) rejected as inconsistent")
        return lines


@dataclass(frozen=True, eq=False)
class MapBuild:
    """A built map: the `sign_map`, a `reports` entry per sign, the `rejected` observations, each
    image's camera pose in the map frame (`cameras`: image -> (R, position), X_map = R·X_cam +
    position) and the signs no map could hold (`unmapped`: id -> why)."""

    sign_map: SignMap
    reports: dict[str, SignReport]
    rejected: list[Rejected]
    cameras: dict[str, tuple[np.ndarray, np.ndarray]]
    unmapped: dict[str, str] = field(default_factory=dict)

    def comments(self) -> dict[str, Iterable[str]]:
        """Per sign id, the report's lines, for `save_sign_map(..., comments=...)`."""
        return {sign_id: report.lines() for sign_id, report in self.reports.items()}


class SeenSign(Protocol):
    """A sign found in an image: a `Recognition`, a tracker's `SignObservation`."""

    @property
    def label(self) -> str | None: ...

    @property
    def pose(self) -> Pose | None: ...


def observations_of(image: str, found: Iterable[SeenSign]) -> list[Observation]:
    """The observations in image `image` of the signs `found` in it that have a pose."""
    return [Observation(image, sign.label, sign.pose.R, sign.pose.t, sign.pose.covariance)
            for sign in found if sign.label is not None and sign.pose is not None]


def takes_frame(index: int, signs: int, step: int = FLIGHT_STEP) -> bool:
    """Whether frame `index` of a flight, on which `signs` signs are confirmed, gives its observations
    to a map: one frame in `step`, and every frame with two or more (the links between signs, which a
    flight past a wall gives a few frames of)."""
    return signs >= 2 or index % step == 0


def right_jacobian(r: np.ndarray) -> np.ndarray:
    """(3, 3) SO(3) right Jacobian at rotation vector r: Exp(r + δ) ≈ Exp(r)·Exp(J_r(r)·δ)."""
    return left_jacobian(r).T


def gtsam_covariance(R: np.ndarray, covariance: np.ndarray) -> np.ndarray:
    """(6, 6) covariance of a pose (R, t) over [rotation vector of R, t] carried into GTSAM's Pose3
    tangent [ω, v], right perturbation (see the module's docstring)."""
    A = np.zeros((6, 6))
    A[:3, :3] = right_jacobian(log_so3(R))
    A[3:, 3:] = R.T
    return A @ covariance @ A.T


def _ros_jacobian(R: np.ndarray) -> np.ndarray:
    """(6, 6) B with [δp, δθ] (ROS order, left perturbation about the map axes) = B·[ω, v] (GTSAM's)."""
    B = np.zeros((6, 6))
    B[:3, 3:] = R
    B[3:, :3] = R
    return B


def ros_covariance(R: np.ndarray, covariance: np.ndarray) -> np.ndarray:
    """(6, 6) map-file covariance (ROS order, left perturbation) of a sign whose GTSAM covariance at
    rotation R (sign to map) is `covariance`."""
    B = _ros_jacobian(R)
    return B @ covariance @ B.T


def gtsam_from_ros(R: np.ndarray, covariance: np.ndarray) -> np.ndarray:
    """The inverse of `ros_covariance`: a map file's covariance in GTSAM's tangent at R."""
    B = _ros_jacobian(R)  # orthogonal: its inverse is its transpose
    return B.T @ covariance @ B


def sign_groups(observations: Iterable[Observation]) -> list[list[str]]:
    """The signs in groups that images link (union-find: two signs in one image are one group), each
    sorted, the groups in order of their first sign's first observation."""
    parent: dict[str, str] = {}

    def root(s: str) -> str:
        while parent[s] != s:
            parent[s] = parent[parent[s]]
            s = parent[s]
        return s

    by_image: dict[str, list[str]] = defaultdict(list)
    order: list[str] = []
    for o in observations:
        if o.sign_id not in parent:
            parent[o.sign_id] = o.sign_id
            order.append(o.sign_id)
        by_image[o.image].append(o.sign_id)
    for signs in by_image.values():
        for other in signs[1:]:
            parent[root(other)] = root(signs[0])
    groups: dict[str, list[str]] = {}
    for s in order:
        groups.setdefault(root(s), []).append(s)
    return [sorted(g) for g in groups.values()]


def _pose3(R: np.ndarray, t: np.ndarray) -> gtsam.Pose3:
    return gtsam.Pose3(gtsam.Rot3(np.asarray(R, dtype=np.float64)), np.asarray(t, dtype=np.float64))


def _noise(covariance: np.ndarray) -> gtsam.noiseModel.Gaussian:
    # A hair of diagonal keeps a covariance that rounding left singular invertible.
    c = 0.5 * (covariance + covariance.T)
    return gtsam.noiseModel.Gaussian.Covariance(c + np.eye(6) * 1e-18)


def _measurement_covariance(o: Observation) -> np.ndarray:
    if o.covariance is None or not np.all(np.isfinite(o.covariance)):
        rot, pos = FALLBACK_SIGMA
        return np.diag([rot**2] * 3 + [pos**2] * 3)
    return gtsam_covariance(o.R, o.covariance)


def _median_covariance(covariances: list[np.ndarray]) -> np.ndarray:
    """Of (6, 6) covariances, the one of median rotation variance (trace of its rotation block)."""
    return sorted(covariances, key=lambda c: float(np.trace(c[:3, :3])))[len(covariances) // 2]


class _Graph:
    """The survey's keys, priors and measurements, from which graphs are made (robust or not, over
    a subset of the observations). Each sign has two poses: where it is (`sign_key`, the map's) and
    where its photos see it (`seen_key`), tied by the error they all share (SHARED_SHARE of the 1σ
    of its median observation); the observations measure the second. `scale` multiplies every
    observation's covariance."""

    def __init__(self, observations: Sequence[Observation], fixed: dict[str, tuple[gtsam.Pose3, np.ndarray]],
                 scale: float = 1.0) -> None:
        self.observations = observations
        self.fixed = fixed  # sign id: (pose, GTSAM covariance)
        signs = list(dict.fromkeys([*fixed, *(o.sign_id for o in observations)]))
        images = list(dict.fromkeys(o.image for o in observations))
        self.sign_key = {s: gtsam.symbol("s", i) for i, s in enumerate(signs)}
        self.seen_key = {s: gtsam.symbol("a", i) for i, s in enumerate(signs)}
        self.image_key = {im: gtsam.symbol("c", i) for i, im in enumerate(images)}
        self.measured = [_pose3(o.R, o.t) for o in observations]
        covariances = [_measurement_covariance(o) for o in observations]
        self.noise = [_noise(c * scale) for c in covariances]
        by_sign: dict[str, list[np.ndarray]] = defaultdict(list)
        for o, c in zip(observations, covariances):
            by_sign[o.sign_id].append(c)
        self.shared = {s: _noise(SHARED_SHARE**2 * _median_covariance(c)) for s, c in by_sign.items()}

    def factor(self, i: int, robust: bool) -> gtsam.BetweenFactorPose3:
        o = self.observations[i]
        noise = self.noise[i]
        if robust:
            noise = gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Huber.Create(HUBER_K), noise)
        return gtsam.BetweenFactorPose3(self.image_key[o.image], self.seen_key[o.sign_id], self.measured[i], noise)

    def graph(self, kept: Sequence[int], robust: bool) -> gtsam.NonlinearFactorGraph:
        graph = gtsam.NonlinearFactorGraph()
        for sign_id, (pose, covariance) in self.fixed.items():
            graph.add(gtsam.PriorFactorPose3(self.sign_key[sign_id], pose, _noise(covariance)))
        for sign_id in dict.fromkeys(self.observations[i].sign_id for i in kept):
            graph.add(gtsam.BetweenFactorPose3(self.sign_key[sign_id], self.seen_key[sign_id], gtsam.Pose3(),
                                               self.shared[sign_id]))
        for i in kept:
            graph.add(self.factor(i, robust))
        return graph

    def dof(self, kept: Sequence[int]) -> int:
        """The degrees of freedom of the graph over the `kept` observations: 6 per observation and
        prior, less 6 per image and sign placed (the shared ties add as many as they place)."""
        images = {self.observations[i].image for i in kept}
        signs = {self.observations[i].sign_id for i in kept} | set(self.fixed)
        return 6 * (len(kept) + len(self.fixed) - len(images) - len(signs))

    def initial(self, kept: Sequence[int]) -> gtsam.Values:
        """Every sign and image reached from the fixed signs, each through its most certain
        observation (smallest rotation variance) from what is already placed."""
        signs = {s: pose for s, (pose, _) in self.fixed.items()}
        images: dict[str, gtsam.Pose3] = {}
        weight = {i: float(np.trace(self.noise[i].covariance()[:3, :3])) for i in kept}
        grew = True
        while grew:
            best_image = self._most_certain(kept, weight, lambda o: o.sign_id in signs and o.image not in images,
                                            lambda o: o.image)
            for image, i in best_image.items():
                images[image] = signs[self.observations[i].sign_id].compose(self.measured[i].inverse())
            best_sign = self._most_certain(kept, weight, lambda o: o.image in images and o.sign_id not in signs,
                                           lambda o: o.sign_id)
            for sign_id, i in best_sign.items():
                signs[sign_id] = images[self.observations[i].image].compose(self.measured[i])
            grew = bool(best_image or best_sign)
        values = gtsam.Values()
        for s, pose in signs.items():
            values.insert(self.sign_key[s], pose)
        for s in {self.observations[i].sign_id for i in kept} & set(signs):
            values.insert(self.seen_key[s], signs[s])
        for image, pose in images.items():
            values.insert(self.image_key[image], pose)
        return values


    def _most_certain(self, kept: Sequence[int], weight: dict[int, float], placing: Callable[[Observation], bool],
                      placed: Callable[[Observation], str]) -> dict[str, int]:
        """Per image or sign `placed(o)`, the observation of smallest `weight` among the `kept` ones that are `placing`."""
        best: dict[str, int] = {}
        for i in kept:
            o = self.observations[i]
            if placing(o) and (placed(o) not in best or weight[i] < weight[best[placed(o)]]):
                best[placed(o)] = i
        return best


def _optimize(graph: gtsam.NonlinearFactorGraph, initial: gtsam.Values) -> gtsam.Values:
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(100)
    params.setRelativeErrorTol(1e-10)
    params.setAbsoluteErrorTol(1e-12)
    return gtsam.LevenbergMarquardtOptimizer(graph, initial, params).optimize()


def _fixed_signs(seen: list[str], anchor: str | None, known: SignMap | None) -> dict[str, tuple[gtsam.Pose3, np.ndarray, str]]:
    tight = np.eye(6) * FIXED_SIGMA**2
    if known is not None:
        return {s.sign_id: (_pose3(s.R, s.position_m),
                            tight if s.covariance is None else gtsam_from_ros(s.R, s.covariance), "known")
                for s in known.signs.values()}
    if anchor is None:
        anchor = seen[0]
    elif anchor not in seen:
        raise MapBuildError(f"the anchor {anchor!r} is not among the signs the survey saw: {', '.join(sorted(seen))}")
    return {anchor: (gtsam.Pose3(), tight, "anchor")}


def _check_groups(groups: list[list[str]], fixed: Iterable[str], known: bool) -> None:
    """DisconnectedSurvey unless every group of signs holds a fixed one (`known`: signs of a known map)."""
    fixed = set(fixed)
    loose = [g for g in groups if not fixed & set(g)]
    if not loose:
        return
    held = [g for g in groups if fixed & set(g)]
    named = "; ".join("{" + ", ".join(g) + "}" for g in groups)
    if len(groups) == 1:
        message = (f"none of the known signs ({', '.join(sorted(fixed))}) was seen: the survey's signs "
                   f"({', '.join(groups[0])}) need one of them to be placed in the map")
    else:
        message = (f"the survey's signs form {len(groups)} groups that no image links: {named}; take photos "
                   "that see a sign of one group beside a sign of another")
        if known and held:
            message += f" (or give a known pose for a sign of {'; '.join('{' + ', '.join(g) + '}' for g in loose)})"
    raise DisconnectedSurvey(message, loose, held)


def build_map(observations: Sequence[Observation], *, anchor: str | None = None, known: SignMap | None = None,
              frame: str | None = None) -> MapBuild:
    """The map of the signs in `observations`, in the frame of `anchor` (default: the first sign
    observed; T_map_anchor = identity) or, with `known`, in the frame of the known map whose signs
    are held at their poses (their covariance, else FIXED_SIGMA). `frame`: the map's frame id
    (default the known map's, else "map").

    Raises MapBuildError: no observation; an anchor not observed; DisconnectedSurvey when images
    do not link every sign to a fixed one (naming the groups). Signs all of whose observations are
    rejected are left out of the map and named in `unmapped`; known signs not observed are in the
    map as given."""
    # One observation of a sign per image: a second one of the same sign is a look-alike or a double search.
    unique: dict[tuple[str, str], Observation] = {}
    for o in observations:
        unique.setdefault((o.image, o.sign_id), o)
    obs = list(unique.values())
    if not obs:
        raise MapBuildError("no sign was seen in the survey")
    seen = list(dict.fromkeys(o.sign_id for o in obs))
    fixed = _fixed_signs(seen, anchor, known)
    _check_groups(sign_groups(obs), fixed, known is not None)
    problem = _Graph(obs, {s: (pose, cov) for s, (pose, cov, _) in fixed.items()})
    every = list(range(len(obs)))
    robust = _optimize(problem.graph(every, robust=True), problem.initial(every))
    # A pose fit's covariance is made for one photo: its corner floor stands for errors the photos of a
    # sign share, so the residuals of most observations are well within it and an outlier hides among
    # them. Which observations are inconsistent is judged at the survey's own scale of the covariances;
    # the map's covariance keeps the fits' covariances (errors shared along a chain of photos, not only
    # per sign, outgrow the scaled ones).
    scaled = _Graph(obs, problem.fixed, _covariance_scale(problem, robust, every))
    robust = _optimize(scaled.graph(every, robust=True), robust)
    chi2 = [2.0 * scaled.factor(i, robust=False).error(robust) for i in every]
    rejected = [i for i in every if chi2[i] > CHI2_REJECT]
    kept = [i for i in every if chi2[i] <= CHI2_REJECT]
    kept_obs = [obs[i] for i in kept]
    # Rejection may leave a sign without observations, or a group cut off from every fixed sign.
    unmapped: dict[str, str] = {}
    fixed_ids = set(fixed)
    for group in sign_groups(kept_obs):
        if not fixed_ids & set(group):
            unmapped.update({s: "its observations link it to no fixed sign once the inconsistent ones are rejected"
                             for s in group})
    for s in seen:
        if s not in fixed_ids and all(o.sign_id != s for o in kept_obs):
            unmapped[s] = "every observation of it was rejected as inconsistent"
    kept = [i for i in kept if obs[i].sign_id not in unmapped]
    graph = problem.graph(kept, robust=False)
    result = _optimize(graph, _subset(robust, problem, kept))
    marginals = gtsam.Marginals(graph, result)
    return _assemble(problem, [obs[i] for i in kept], [Rejected(obs[i], chi2[i]) for i in rejected],
                     fixed, result, marginals, unmapped, frame or (known.frame if known is not None else DEFAULT_FRAME))


def _covariance_scale(problem: _Graph, values: gtsam.Values, kept: Sequence[int]) -> float:
    """The factor to the observations' covariances that makes the median of their whitened squared
    residuals at `values` what chi-square gives for their redundancy (dof per observation of 6), at
    least MIN_SCALE; 1 when the graph has fewer than MIN_DOF_FOR_SCALE dof."""
    dof = problem.dof(kept)
    if dof < MIN_DOF_FOR_SCALE:
        return 1.0
    chi2 = [2.0 * problem.factor(i, robust=False).error(values) for i in kept]
    return max(MIN_SCALE, float(np.median(chi2)) / (CHI2_MEDIAN * dof / (6 * len(kept))))


def _subset(values: gtsam.Values, problem: _Graph, kept: Sequence[int]) -> gtsam.Values:
    """`values` of the fixed signs and of the signs and images the `kept` observations hold."""
    out = gtsam.Values()
    keys = {problem.sign_key[s] for s in problem.fixed}
    for i in kept:
        o = problem.observations[i]
        keys |= {problem.sign_key[o.sign_id], problem.seen_key[o.sign_id], problem.image_key[o.image]}
    for key in keys:
        out.insert(key, values.atPose3(key))
    return out


def _assemble(problem: _Graph, kept: list[Observation], rejected: list[Rejected],
              fixed: dict[str, tuple[gtsam.Pose3, np.ndarray, str]], result: gtsam.Values, marginals: gtsam.Marginals,
              unmapped: dict[str, str], frame: str) -> MapBuild:
    by_image: dict[str, list[str]] = defaultdict(list)
    for o in kept:
        by_image[o.image].append(o.sign_id)
    rejected_count = Counter(r.observation.sign_id for r in rejected)
    signs: dict[str, MappedSign] = {}
    reports: dict[str, SignReport] = {}
    for sign_id, key in problem.sign_key.items():
        if sign_id in unmapped:
            continue
        pose = result.atPose3(key)
        R, position = pose.rotation().matrix(), np.asarray(pose.translation(), dtype=np.float64)
        covariance = ros_covariance(R, marginals.marginalCovariance(key))
        covariance = 0.5 * (covariance + covariance.T)
        signs[sign_id] = sign = MappedSign(sign_id=sign_id, R=R, position_m=position, covariance=covariance)
        sigma_position_m, sigma_rotation_rad = sign.worst_sigma() or (0.0, 0.0)
        images = [im for im, s in by_image.items() if sign_id in s]
        seen_with = Counter(other for im in images for other in by_image[im] if other != sign_id)
        reports[sign_id] = SignReport(
            sign_id=sign_id, images=len(images), seen_with=dict(seen_with),
            fixed=fixed[sign_id][2] if sign_id in fixed else None,
            sigma_position_mm=1e3 * sigma_position_m, sigma_rotation_deg=math.degrees(sigma_rotation_rad),
            rejected=rejected_count[sign_id])
    cameras = {}
    for image in by_image:
        pose = result.atPose3(problem.image_key[image])
        cameras[image] = (pose.rotation().matrix(), np.asarray(pose.translation(), dtype=np.float64))
    return MapBuild(SignMap(signs=signs, frame=frame), reports, rejected, cameras, unmapped)


def format_report(build: MapBuild) -> str:
    """The build as text: a line per sign (position, yaw/pitch/roll, 1-sigma, images, companions),
    then the rejected observations and the signs left out."""
    lines = [f"{'sign':<24} {'position_m':<28} {'yaw, pitch, roll deg':<26} {'1-sigma':<20} images  seen with"]
    for sign_id, sign in build.sign_map.signs.items():
        report = build.reports[sign_id]
        x, y, z = sign.position_m
        yaw, pitch, roll = euler_zyx_deg(sign.R)
        sigma = (report.fixed if report.fixed is not None
                 else f"{report.sigma_position_mm:.1f} mm {report.sigma_rotation_deg:.3f}°")
        with_ = ", ".join(f"{s} ({n})" for s, n in sorted(report.seen_with.items())) or "-"
        lines.append(f"{sign_id:<24} {f'{x:+.3f} {y:+.3f} {z:+.3f}':<28} "
                     f"{f'{yaw:+.2f} {pitch:+.2f} {roll:+.2f}':<26} {sigma:<20} {report.images:>6}  {with_}")
    if build.rejected:
        lines.append(f"rejected as inconsistent ({len(build.rejected)}, chi-square over {CHI2_REJECT:g}):")
        lines += [f"  {r.observation.image}: {r.observation.sign_id} (chi-square {r.chi2:.1f})" for r in build.rejected]
    lines += [f"not mapped: {s}: {why}" for s, why in build.unmapped.items()]
    return "\n".join(lines)
