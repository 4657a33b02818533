# Differential-drive physics: wheel motors move a round robot, which stops at obstacles.
from __future__ import annotations

import math
from dataclasses import dataclass

from sim.motor_model import MotorPair, WheelMotor
from sim.noise import Noise, NoiseConfig
from sim.world import Circle, Pose, Segment, World

#: Gap (m) left between the footprint and an obstacle when the robot is stopped by it.
CONTACT_GAP = 1e-6
#: The contact sweep only looks at primitives found within this margin (m) of the footprint,
#: refreshed whenever the robot may have moved farther than the margin from where they were.
NEARBY_MARGIN = 0.25


@dataclass(frozen=True)
class RobotGeometry:
    """Wheel radius and separation (m) and the radius of the robot's round footprint (m)."""

    wheel_radius: float = 0.05
    wheel_separation: float = 0.30
    footprint_radius: float = 0.2

    def __post_init__(self) -> None:
        for name in ("wheel_radius", "wheel_separation", "footprint_radius"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be > 0, got {getattr(self, name)}")


@dataclass
class BodyState:
    """The true pose and velocity of the robot, and its contact state."""

    x: float = 0.0
    y: float = 0.0
    theta: float = 0.0
    v: float = 0.0
    w: float = 0.0
    travelled: float = 0.0  # translation of the last step (m), >= 0
    in_contact: bool = False
    collisions: int = 0


class DiffDrivePhysics:
    """Moves the robot from its wheel motors, one fixed step at a time.

    The motors (a :class:`MotorPair` with ``clock=None``) are advanced here, so whatever an
    emulator commands on the same object drives the robot. Each wheel's travel, less
    ``wheel_slip``, moves the body along an arc; the translation is swept against the world
    grown by the footprint radius, so the robot stops at the first contact at any speed (no
    tunnelling). Entering contact counts one collision. Encoder noise is added to the motors'
    positions (what the emulated encoders report) and never to the true motion.
    ``wheel_sign`` is -1 when the emulated hardware turns the wheels backwards to drive
    forwards.
    """

    def __init__(self, world: World, motors: MotorPair, geometry: RobotGeometry,
                 noise: Noise | None = None, *, wheel_sign: int = 1) -> None:
        if wheel_sign not in (1, -1):
            raise ValueError(f"wheel_sign must be 1 or -1, got {wheel_sign}")
        self.world = world
        self.motors = motors
        self.geometry = geometry
        self.noise = noise or Noise(NoiseConfig(enabled=False))
        self.wheel_sign = wheel_sign
        self.state = BodyState()
        self._offsets = [0.0, 0.0]  # encoder error currently applied to each motor (rad)
        self._written = (0.0, 0.0)  # motor positions as this class last left them
        self._free = 0.0  # distance the centre can still move without any contact check
        self._nearby: tuple[tuple[Circle, ...], tuple[Segment, ...]] = ((), ())
        self._nearby_at = (math.inf, math.inf)
        self.place(world.start)

    def place(self, pose: Pose) -> None:
        """Teleport the robot (at rest, no contact, no collisions counted); refuses a pose
        that puts the footprint on an obstacle or a wall."""
        clearance = self.world.clearance(pose.x, pose.y) - self.geometry.footprint_radius
        if not all(math.isfinite(v) for v in (pose.x, pose.y, pose.theta)):
            raise ValueError(f"pose must be finite, got {pose}")
        if clearance <= 0:
            raise ValueError(f"pose ({pose.x:.3f}, {pose.y:.3f}) puts the robot's footprint "
                             f"on an obstacle or wall")
        self.state = BodyState(pose.x, pose.y, _wrap(pose.theta))
        self._free = clearance
        self._nearby_at = (math.inf, math.inf)

    def step(self, dt: float) -> None:
        """Advance the motors and the body by ``dt`` seconds."""
        left_rad, right_rad = self._advance_motors(dt)
        keep = (1.0 - self.noise.config.slip) * self.geometry.wheel_radius * self.wheel_sign
        left, right = left_rad * keep, right_rad * keep
        self._move((left + right) / 2.0, (right - left) / self.geometry.wheel_separation, dt)

    def _advance_motors(self, dt: float) -> tuple[float, float]:
        """Advance both motors; returns each wheel's true rotation (rad) during the step."""
        pair = self.motors
        with pair.lock:
            before = (pair.left.position_rad, pair.right.position_rad)
            if before != self._written:  # someone re-zeroed the encoders: no error applied
                self._offsets = [0.0, 0.0]
            pair.advance(dt)
            turned = (pair.left.position_rad - before[0], pair.right.position_rad - before[1])
            if self.noise.odom_on:
                self._apply_encoder_noise(turned)
            self._written = (pair.left.position_rad, pair.right.position_rad)
        return turned

    def _apply_encoder_noise(self, turned: tuple[float, float]) -> None:
        draws = self.noise.encoder_offsets()
        for index, motor in enumerate((self.motors.left, self.motors.right)):
            if turned[index] == 0.0:
                continue  # a still wheel keeps its reading
            fresh = draws[index] / self.geometry.wheel_radius
            _shift(motor, fresh - self._offsets[index])
            self._offsets[index] = fresh

    def _move(self, ds: float, dtheta: float, dt: float) -> None:
        state = self.state
        # exact arc: the chord is ds·sin(dθ/2)/(dθ/2), along the mid heading
        half = dtheta / 2.0
        chord = ds if dtheta == 0.0 else ds * math.sin(half) / half
        heading = state.theta + dtheta / 2.0
        dx, dy = chord * math.cos(heading), chord * math.sin(heading)
        length = abs(chord)
        allowed = self._allowed_distance(dx, dy, length)
        fraction = 1.0 if allowed >= length else allowed / length
        state.x += dx * fraction
        state.y += dy * fraction
        state.theta = _wrap(state.theta + dtheta)
        state.travelled = length * fraction
        state.v = ds * fraction / dt if dt > 0 else 0.0
        state.w = dtheta / dt if dt > 0 else 0.0

    def _allowed_distance(self, dx: float, dy: float, length: float) -> float:
        """How far the centre may move along (dx, dy); updates contact and collisions."""
        state = self.state
        if length == 0.0:
            return 0.0
        if length <= self._free:
            self._free -= length
            state.in_contact = False
            return length
        if not state.in_contact:  # in contact the clearance is ~0: go straight to the sweep
            self._free = self.world.clearance(state.x, state.y) - self.geometry.footprint_radius
            if length <= self._free:
                self._free -= length
                state.in_contact = False
                return length
        self._free = 0.0
        hit = self._sweep(dx / length, dy / length, length)
        if hit > length:
            state.in_contact = False
            return length
        if not state.in_contact:
            state.collisions += 1
        state.in_contact = True
        return max(0.0, hit - CONTACT_GAP)

    def _sweep(self, ux: float, uy: float, length: float) -> float:
        """First contact along the unit vector, checking only the primitives close enough."""
        x, y, radius = self.state.x, self.state.y, self.geometry.footprint_radius
        moved = math.hypot(x - self._nearby_at[0], y - self._nearby_at[1])
        if moved + length > NEARBY_MARGIN:
            if length > NEARBY_MARGIN:
                return first_contact(self.world, x, y, ux, uy, radius)
            self._nearby = self.world.nearby(x, y, radius + 2 * NEARBY_MARGIN)
            self._nearby_at = (x, y)
        circles, segments = self._nearby
        return _first_contact(circles, segments, x, y, ux, uy, radius)


def make_motors(max_speed_rad_s: float = 40.0, time_constant_s: float = 0.05) -> MotorPair:
    """A wheel pair stepped by the world (``clock=None``) for emulators and physics to share."""
    return MotorPair(WheelMotor(max_speed_rad_s=max_speed_rad_s, time_constant_s=time_constant_s),
                     WheelMotor(max_speed_rad_s=max_speed_rad_s, time_constant_s=time_constant_s),
                     clock=None)


def _shift(motor: WheelMotor, delta_rad: float) -> None:
    motor.position_rad += delta_rad


def _wrap(angle: float) -> float:
    return math.atan2(math.sin(angle), math.cos(angle))


# -- swept footprint against the world -------------------------------------------------------

def first_contact(world: World, x: float, y: float, ux: float, uy: float,
                  radius: float) -> float:
    """Distance the centre of a disc of ``radius`` at (x, y) can travel along the unit
    vector (ux, uy) before touching a wall or obstacle; ``inf`` when it never does.

    A disc already touching something is blocked (0) only when moving into it.
    """
    return _first_contact(world.circles, world.segments, x, y, ux, uy, radius)


def _first_contact(circles: tuple[Circle, ...], segments: tuple[Segment, ...], x: float,
                   y: float, ux: float, uy: float, radius: float) -> float:
    best = math.inf
    for circle in circles:
        best = min(best, _disc_hits_circle(x, y, ux, uy, radius, circle))
    for segment in segments:
        best = min(best, _disc_hits_segment(x, y, ux, uy, radius, segment))
    return best


def _ray_circle(x: float, y: float, ux: float, uy: float, cx: float, cy: float,
                r: float) -> float:
    """Distance along the ray to the circle (cx, cy, r) from outside or on it; inf if none."""
    fx, fy = cx - x, cy - y
    along = fx * ux + fy * uy
    offset = fx * fx + fy * fy - r * r
    if offset <= 0:  # touching or inside: blocked only when heading inwards
        return 0.0 if along > 0 else math.inf
    disc = along * along - offset
    if disc < 0 or along <= 0:
        return math.inf
    return along - math.sqrt(disc)


def _disc_hits_circle(x: float, y: float, ux: float, uy: float, radius: float,
                      circle: Circle) -> float:
    return _ray_circle(x, y, ux, uy, circle.x, circle.y, circle.r + radius)


def _disc_hits_segment(x: float, y: float, ux: float, uy: float, radius: float,
                       seg: Segment) -> float:
    """The ray against the capsule of ``radius`` around the segment."""
    ex, ey = seg.x2 - seg.x1, seg.y2 - seg.y1
    length = math.hypot(ex, ey)
    nx, ny = -ey / length, ex / length
    best = min(_ray_circle(x, y, ux, uy, seg.x1, seg.y1, radius),
               _ray_circle(x, y, ux, uy, seg.x2, seg.y2, radius))
    side = (x - seg.x1) * nx + (y - seg.y1) * ny
    u = ((x - seg.x1) * ex + (y - seg.y1) * ey) / (length * length)
    if abs(side) <= radius and 0 <= u <= 1:  # touching the flat side
        toward = -(ux * nx + uy * ny) * math.copysign(1.0, side)
        return 0.0 if toward > 0 else best
    sign = math.copysign(1.0, side)  # only the face towards the centre can be hit first
    ox, oy = seg.x1 + sign * radius * nx, seg.y1 + sign * radius * ny
    return min(best, _ray_segment(x, y, ux, uy, ox, oy, ex, ey))


def _ray_segment(x: float, y: float, ux: float, uy: float, ax: float, ay: float,
                 ex: float, ey: float) -> float:
    """Distance along the ray to the segment a + s·e (0 <= s <= 1); inf if it misses."""
    denom = ux * ey - uy * ex
    if denom == 0:
        return math.inf
    fx, fy = ax - x, ay - y
    t = (fx * ey - fy * ex) / denom
    s = (fx * uy - fy * ux) / denom
    return t if t >= 0 and 0 <= s <= 1 else math.inf
