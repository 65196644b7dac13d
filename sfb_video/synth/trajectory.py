"""The continuous 3D motion of a synthetic object over a clip, and its per-frame ground truth.

Convention:
    Clip time t is in frame intervals: frame k's exposure covers t in [k, k + e], e the
    exposure fraction, and exposure time tau in [0, 1] maps to t = k + tau * e.
    Position x(t) = p0 + v t + a t^2 / 2 (camera space, object sizes), and after a bounce at
    t_b the same from x(t_b) with the velocity's y reversed and scaled by
    ``BOUNCE_RESTITUTION``; or, for a swing, a circle parallel to the image plane; rotation
    R(t) = exp(t w) @ R_init with w an axis-angle per frame interval. Frame k's ground truth is
    then x0 = x(k), dx = x(k + e) - x(k), R0 = R(k), omega = e * w, which matches
    ``geometry.rotation.exposure_rotations``: R(k + tau e) = exp(tau omega) @ R0.
    Quaternions are WXYZ with w >= 0. Everything here is float64 numpy.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from sfb_video.errors import SfbError
from sfb_video.geometry.camera import PinholeCamera
from sfb_video.synth.spec import ClipSpec

BOUNCE_RESTITUTION = 0.8
"""The share of its vertical speed a bouncing object keeps."""


def axis_angle_to_quaternion(omega: np.ndarray) -> np.ndarray:
    """(*, 3) axis-angle vectors -> (*, 4) WXYZ unit quaternions (exact at angle 0)."""
    angle = np.linalg.norm(omega, axis=-1, keepdims=True)
    # sin(a/2)/a tends to 1/2; the series keeps full precision for tiny angles.
    small = angle < 1e-6
    scale = np.where(small, 0.5 - angle**2 / 48, np.sin(angle / 2) / np.where(small, 1.0, angle))
    return np.concatenate((np.cos(angle / 2), omega * scale), -1)


def quaternion_multiply(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product a * b of (*, 4) WXYZ quaternions (the rotation b, then a)."""
    aw, ax, ay, az = np.moveaxis(a, -1, 0)
    bw, bx, by, bz = np.moveaxis(b, -1, 0)
    return np.stack(
        (
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ),
        -1,
    )


def quaternion_to_matrix(q: np.ndarray) -> np.ndarray:
    """(*, 4) WXYZ quaternions (normalised here) -> (*, 3, 3) rotation matrices."""
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = np.moveaxis(q, -1, 0)
    return np.stack(
        (
            np.stack((1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)), -1),
            np.stack((2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)), -1),
            np.stack((2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)), -1),
        ),
        -2,
    )


def _canonical(q: np.ndarray) -> np.ndarray:
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    return np.where(q[..., :1] < 0, -q, q)


@dataclass(frozen=True)
class FrameMotion:
    """Ground-truth motion during one exposure (the fitter's parameters for that frame).

    Attributes:
        x0: (3,) camera-space centre at the start of the exposure (object sizes).
        dx: (3,) x(end) - x(start) over the exposure.
        quaternion: (4,) WXYZ rotation R0 at the start of the exposure, w >= 0.
        rotation: (3, 3) the matrix of ``quaternion``.
        omega: (3,) axis-angle of the rotation made during the exposure (radians).
    """

    x0: np.ndarray
    dx: np.ndarray
    quaternion: np.ndarray
    rotation: np.ndarray
    omega: np.ndarray


@dataclass(frozen=True)
class Trajectory:
    """Continuous motion over the clip (see the module docstring for the convention).

    Attributes:
        position0: (3,) x(0); velocity: (3,) per frame interval; acceleration: (3,) per
            frame interval squared.
        quaternion0: (4,) WXYZ R_init = R(0); angular_velocity: (3,) w, axis-angle per frame.
        exposure_fraction: e, the open-shutter fraction of each frame interval.
        bounce_time: t_b of a bounce (see the module docstring), or None.
        swing: a circular swing instead of the free path, or None: (6,) the circle's centre
            (3,), radius, angular rate (radians per frame interval) and phase at t = 0; the
            circle lies parallel to the image plane, x(t) = c + r (cos(rate t + phase),
            sin(rate t + phase), 0).
    """

    position0: np.ndarray
    velocity: np.ndarray
    acceleration: np.ndarray
    quaternion0: np.ndarray
    angular_velocity: np.ndarray
    exposure_fraction: float
    bounce_time: float | None = None
    swing: np.ndarray | None = None

    def positions(self, t: np.ndarray) -> np.ndarray:
        """(T,) clip times -> (T, 3) centres."""
        t = np.asarray(t, dtype=np.float64)[:, None]
        if self.swing is not None:
            centre, radius, rate, phase = self.swing[:3], self.swing[3], self.swing[4], self.swing[5]
            angle = rate * t[:, 0] + phase
            return centre + radius * np.stack((np.cos(angle), np.sin(angle), np.zeros_like(angle)), -1)
        free = self.position0 + self.velocity * t + 0.5 * self.acceleration * t**2
        if self.bounce_time is None:
            return free
        tb = self.bounce_time
        at = self.position0 + self.velocity * tb + 0.5 * self.acceleration * tb**2
        v = self.velocity + self.acceleration * tb
        v = v * np.array([1.0, -BOUNCE_RESTITUTION, 1.0])
        s = t - tb
        return np.where(t > tb, at + v * s + 0.5 * self.acceleration * s**2, free)

    def quaternions(self, t: np.ndarray) -> np.ndarray:
        """(T,) clip times -> (T, 4) WXYZ rotations R(t), w >= 0."""
        t = np.asarray(t, dtype=np.float64)[:, None]
        turn = axis_angle_to_quaternion(t * self.angular_velocity)
        return _canonical(quaternion_multiply(turn, np.broadcast_to(self.quaternion0, turn.shape)))

    def rotations(self, t: np.ndarray) -> np.ndarray:
        """(T,) clip times -> (T, 3, 3) rotation matrices R(t)."""
        return quaternion_to_matrix(self.quaternions(t))

    def exposure_times(self, frame: int, taus: np.ndarray) -> np.ndarray:
        """Clip times k + tau * e of exposure times ``taus`` (T,) in frame ``frame``."""
        return frame + np.asarray(taus, dtype=np.float64) * self.exposure_fraction

    def frame_motion(self, frame: int) -> FrameMotion:
        """The ground-truth motion of exposure ``frame``."""
        start, end = self.positions(self.exposure_times(frame, np.array([0.0, 1.0])))
        quat = self.quaternions(np.array([float(frame)]))[0]
        return FrameMotion(
            x0=start,
            dx=end - start,
            quaternion=quat,
            rotation=quaternion_to_matrix(quat),
            omega=self.angular_velocity * self.exposure_fraction,
        )


def _random_unit(rng: np.random.Generator, dim: int) -> np.ndarray:
    # A normalised Gaussian is uniform on the sphere (a unit quaternion: uniform on SO(3)).
    x = rng.normal(size=dim)
    return x / np.linalg.norm(x)


def sample_trajectory(
    rng: np.random.Generator, spec: ClipSpec, vertices: np.ndarray, camera: PinholeCamera
) -> Trajectory:
    """Draw a trajectory that keeps the whole mesh in view and in front in visible frames.

    Size, speed, direction, depth change, spin and start pose are drawn from the spec's
    ranges; the mid-span image position is drawn from where the path's approximate image
    extent fits, and every vertex at ``spec.sub_exposures + 1`` times spanning each visible
    exposure is then checked exactly. Draws that do not fit are redrawn, so a long clip gets
    the small and slow end of the size and speed ranges: the ranges bound the draw, they are
    not its distribution.

    Args:
        vertices: (V, 3) unit-scale mesh vertices centred at 0.
    """
    radius = float(np.linalg.norm(vertices, axis=-1).max())
    diameter, e, f = 2 * radius, spec.exposure_fraction, camera.fy
    present = spec.present_frames
    t_start, t_end = present[0], present[-1] + e
    t_mid, span = (t_start + t_end) / 2, t_end - t_start
    # The exposure's ends are included: renders come as close to them as their count allows.
    taus = np.linspace(0.0, 1.0, spec.sub_exposures + 1)
    times = np.concatenate([k + taus * e for k in present])
    for _ in range(spec.max_tries):
        size_px = rng.uniform(*spec.size_px_range)
        z_mid = f * diameter / size_px
        speed = rng.uniform(*spec.speed_range) * diameter / e
        heading = rng.uniform(0, 2 * math.pi)
        if spec.bounce_time is not None:
            # Down the image towards the floor, steeply enough for the bounce to show.
            side = rng.choice([-1.0, 1.0])
            heading = math.pi / 2 + side * rng.uniform(math.radians(30), math.radians(55))
        vz = rng.uniform(-1, 1) * spec.max_depth_change * z_mid / span
        velocity = np.array([speed * math.cos(heading), speed * math.sin(heading), vz])
        acceleration = np.array([0.0, spec.gravity, 0.0])
        axis = _random_unit(rng, 3)
        angle = math.radians(rng.uniform(*spec.rotation_deg_range))
        spin = axis * angle / e
        quat0 = _canonical(_random_unit(rng, 4))
        u_mid, v_mid = rng.uniform(0, 1, 2)  # where in the feasible box; drawn every try
        z_near = z_mid - abs(vz) * span / 2
        if z_near - radius < spec.min_depth:
            continue
        half = span / 2
        px_per_unit = f / z_near
        reach = radius * px_per_unit + spec.margin_px
        if spec.swing_period is not None:
            swing = _swing(rng, spec, speed, z_mid, reach, camera)
            still = np.zeros(3)
            swung = None if swing is None else Trajectory(still, still, still, quat0, spin, e, swing=swing)
            if swung is not None and _fits(swung, spec, vertices, camera, times, diameter):
                return swung
            continue
        half_u = abs(velocity[0]) * half * px_per_unit + reach
        half_v = (abs(velocity[1]) * half + 0.5 * abs(spec.gravity) * half**2) * px_per_unit + reach
        room_u, room_v = camera.width - 1 - 2 * half_u, camera.height - 1 - 2 * half_v
        if room_u < 0 or room_v < 0:
            continue
        uv = np.array([half_u + u_mid * room_u, half_v + v_mid * room_v])
        mid = np.array([(uv[0] - camera.cx) / camera.fx * z_mid, (uv[1] - camera.cy) / camera.fy * z_mid, z_mid])
        position0 = mid - velocity * t_mid - 0.5 * acceleration * t_mid**2
        traj = Trajectory(position0, velocity, acceleration, quat0, spin, e, spec.bounce_time)
        if _fits(traj, spec, vertices, camera, times, diameter):
            return traj
    raise SfbError(
        f"no trajectory in {spec.max_tries} tries keeps the {spec.shape} in view for "
        f"{len(present)} frames: lower speed_range or size_px_range, or use fewer frames"
    )


def _swing(
    rng: np.random.Generator,
    spec: ClipSpec,
    speed: float,
    depth: float,
    reach: float,
    camera: PinholeCamera,
) -> np.ndarray | None:
    """:attr:`Trajectory.swing` of a circle of ``spec.swing_period`` frames a turn at ``speed``
    and ``depth``, centred where it fits in view (None where it cannot)."""
    rate = 2 * math.pi / float(spec.swing_period) * rng.choice([-1.0, 1.0])
    radius = speed / abs(rate)
    half = radius * camera.fy / depth + reach
    room_u, room_v = camera.width - 1 - 2 * half, camera.height - 1 - 2 * half
    if room_u < 0 or room_v < 0:
        return None
    u, v = half + rng.uniform() * room_u, half + rng.uniform() * room_v
    centre = np.array([(u - camera.cx) / camera.fx * depth, (v - camera.cy) / camera.fy * depth, depth])
    return np.array([*centre, radius, rate, rng.uniform(0, 2 * math.pi)])


def _fits(
    traj: Trajectory, spec: ClipSpec, vertices: np.ndarray, camera: PinholeCamera, times: np.ndarray, diameter: float
) -> bool:
    """True when every vertex is in view and in front at ``times`` and every streak is long."""
    pts = np.einsum("tij,vj->tvi", traj.rotations(times), vertices) + traj.positions(times)[:, None]
    z = pts[..., 2]
    if z.min() < spec.min_depth:
        return False
    u = camera.fx * pts[..., 0] / z + camera.cx
    v = camera.fy * pts[..., 1] / z + camera.cy
    lo = spec.margin_px
    if u.min() < lo or v.min() < lo or u.max() > camera.width - 1 - lo or v.max() > camera.height - 1 - lo:
        return False
    for k in spec.present_frames:
        ends = traj.positions(traj.exposure_times(k, np.array([0.0, 1.0])))
        img = ends[:, :2] / ends[:, 2:] * np.array([camera.fx, camera.fy])
        streak = float(np.linalg.norm(img[1] - img[0]))
        size_px = camera.fy * diameter / float(ends[:, 2].min())  # the larger image of the two
        if streak < spec.min_streak * size_px:
            return False
    return True
