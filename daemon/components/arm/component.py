# The "arm" component: poses and joint targets over HTTP and rosbridge, servo moves, /joint_states.
from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from aiohttp import web

from base.config import Config
from daemon.bus import BusKey
from daemon.component import BaseComponent, ComponentSpec, DaemonContext, DeviceUse, Plugs, Route
from daemon.components.arm.controller import ArmController, ArmRefused
from daemon.components.arm.kinematics import forward
from daemon.components.arm.settings import ArmSettings
from daemon.health import Health
from daemon.messages.convert import header
from daemon.messages.definitions import FLOAT64, JOINT_STATE, STRING
from daemon.telemetry import COMMAND, CommandEvent
from daemon.topics import Inbound, Refusal, Topic, TopicIn, TopicOut
from daemon.web import ApiError, json_response, read_json_object
from drivers.devices import DeviceError, create_device
from drivers.servo_array import ServoArray
from sim.objects import Tool

log = logging.getLogger("arbiterd.arm")

#: the gripper's two fingers as /joint_states names them (each finger travels the opening)
FINGERS = ("left_finger_joint", "right_finger_joint")
#: the seed's command topics: one per pitching joint, then the fingers
JOINT_TOPICS = ("/arm_joint1_cmd", "/arm_joint2_cmd", "/arm_joint3_cmd")
FINGER_TOPICS = ("/left_finger_cmd", "/right_finger_cmd")


@dataclass(frozen=True, slots=True)
class JointStates:
    """The arm's joints at one instant (wall-clock stamp, s), for /joint_states."""

    stamp: float
    name: list[str]
    position: list[float]
    velocity: list[float]


JOINT_STATES: BusKey[JointStates] = BusKey("arm_joint_states")
#: reconnecting the servos after a fault or a failed start: first and longest wait, s
RETRY_MIN_S, RETRY_MAX_S = 1.0, 10.0


def joint_state_msg(states: JointStates) -> dict[str, Any]:
    return {"header": header(states.stamp, "base_link"), "name": states.name,
            "position": states.position, "velocity": states.velocity, "effort": []}


#: reads the pulse width (µs, 0 = off) an output carries: the simulator's emulator
PulseReader = Callable[[int], float]


class ArmComponent(BaseComponent):
    """Runs :class:`ArmController` at ``update_rate`` on the event loop and serves it:
    ``GET``/``POST /api/arm``, the seed's command topics, ``/arm/pose`` and ``/joint_states``.
    Under ``run --sim`` the joint states are what the emulated servos' pulses mean."""

    name = "arm"
    core = False

    def __init__(self, settings: ArmSettings, make_servo: Callable[[], ServoArray],
                 plugs: Plugs, *, readback: PulseReader | None = None) -> None:
        self.settings = settings
        self.make_servo = make_servo
        self.servo = servo = make_servo()
        self.robot = plugs.robot
        self.bus = plugs.bus
        self.clock = self.robot.clock
        self.readback = readback
        self.arm = ArmController(settings, servo, self.clock(), self._estop)
        self._task: asyncio.Task[None] | None = None
        self._next_publish = 0.0
        #: why the servos are not connected (None: they are)
        self.unreachable: str | None = None
        self._retry_at = 0.0
        self._retry_s = RETRY_MIN_S
        plugs.subscribe(COMMAND, self._on_command_event)

    def _estop(self) -> str | None:
        robot = self.robot
        return (robot.estop_reason or "latched") if robot.estop_engaged else None

    def _on_command_event(self, event: CommandEvent) -> None:
        """An e-stop freezes the arm at once, not only at the next servo update."""
        if event.kind == "estop" and self.arm.frozen_by is None:
            self.arm.frozen_by = self._estop() or event.source
            self.arm.motion.freeze(self.clock())

    # -- lifecycle ---------------------------------------------------------------------------

    async def start(self) -> None:
        """Connect the servos and send the home pose; a board that does not answer is logged,
        makes health ``error`` and is tried again with back-off (the daemon runs on)."""
        if await self._connect():
            await self.arm.step(self.clock())
        self._task = asyncio.create_task(self._run(), name="arm")

    async def _connect(self) -> bool:
        try:
            await self.servo.open()
        except DeviceError as exc:
            if self.unreachable != str(exc):
                log.error("arm: %s (trying again every %g..%g s)", exc, RETRY_MIN_S,
                          RETRY_MAX_S)
            self.unreachable = str(exc)
            self._retry_at = self.clock() + self._retry_s
            self._retry_s = min(2 * self._retry_s, RETRY_MAX_S)
            return False
        if self.unreachable is not None:
            log.info("arm: servos connected; the arm waits for a command")
        self.unreachable, self._retry_s = None, RETRY_MIN_S
        return True

    async def _recover(self, now: float) -> None:
        """After a fault or a failed connect: a fresh device, opened again with back-off; the
        arm then holds still (frozen where it was) until it is told to move."""
        if now < self._retry_at:
            return
        if self.arm.fault is not None:
            await self.servo.close()
            self.servo = self.arm.servo = self.make_servo()
            self.unreachable = self.arm.fault
            self.arm.fault, self.arm.written = None, None
        elif self.servo.is_open:
            return
        elif self.servo.fault is not None or self.unreachable is not None:
            self.servo = self.arm.servo = self.make_servo()
        await self._connect()

    async def _run(self) -> None:
        period = 1.0 / self.settings.update_rate
        deadline = self.clock()
        while True:
            now = self.clock()
            try:
                await self._update(now)
            except Exception as exc:  # a bug must not end the loop with the arm unwatched
                log.exception("arm update failed")
                self.arm.fail(f"update failed: {exc!r}", now)
            deadline = max(deadline + period, self.clock())
            await asyncio.sleep(deadline - self.clock())

    async def _update(self, now: float) -> None:
        if self.arm.fault is not None or not self.servo.is_open:
            await self._recover(now)
        else:
            await self.arm.step(now)
        self._publish(now)

    async def stop(self) -> None:
        if self._task is not None:
            self._task.cancel()
            await asyncio.gather(self._task, return_exceptions=True)
        try:
            done = await self.arm.park_or_relax(self.clock, asyncio.sleep)
            log.info("arm at shutdown: %s", done)
        except DeviceError as exc:
            log.error("arm at shutdown: %s", exc)
        finally:
            await self.servo.close()

    def health(self) -> Health:
        device = self.servo.health()
        status = "error" if self.arm.fault or device["status"] != "ok" else "ok"
        fault = self.arm.fault or device.get("fault") or self.unreachable
        values = {"backend": self.settings.backend, "fault": fault, "writes": self.arm.writes,
                  "frozen_by_estop": self.arm.frozen_by}
        if status == "error":
            return Health("error", str(fault or f"servo {device['status']}"), values)
        return Health("ok", str(fault or ""), values)

    # -- reports -----------------------------------------------------------------------------

    def measured(self) -> dict[str, float | None] | None:
        """What the emulated servos' pulses mean (``run --sim``), else None."""
        if self.readback is None:
            return None
        out: dict[str, float | None] = {}
        for name, output in self.servo.outputs.items():
            pulse = self.readback(output)
            out[name] = self.servo.calibrations[name].position(pulse) if pulse > 0 else None
        return out

    def joint_states(self, now: float) -> JointStates:
        """Where the joints are: what the emulated servos' pulses mean under ``--sim`` (the
        commanded position for a relaxed servo), else the commanded position; each finger
        travels the gripper's opening."""
        here, velocity = self.arm.motion.position(now), self.arm.motion.velocity(now)
        for joint, value in (self.measured() or {}).items():
            if value is not None:
                here[joint] = value
        *pitch, gripper = self.arm.joints
        return JointStates(time.time(), [*pitch, *FINGERS],
                           [here[j] for j in pitch] + [here[gripper]] * 2,
                           [velocity[j] for j in pitch] + [velocity[gripper]] * 2)

    def _publish(self, now: float) -> None:
        if now >= self._next_publish:
            self._next_publish = now + 1.0 / self.settings.publish_rate
            self.bus.publish(JOINT_STATES, self.joint_states(now))

    def state(self) -> dict[str, Any]:
        return self.arm.state(self.clock(), self.measured())

    def tool(self) -> Tool:
        """Where the tool point is (base_link) and the gripper's opening, from what the
        servos were told (the emulated pulses' meaning under ``--sim``): the simulator's
        objects are grasped and carried by it."""
        return tool_at(self.arm.joints, self.joint_positions())

    def joint_positions(self) -> dict[str, float]:
        here = self.arm.written or self.arm.motion.position(self.clock())
        measured = self.measured() or {}
        return {j: here[j] if measured.get(j) is None else float(measured[j] or 0.0)
                for j in self.arm.joints}

    # -- HTTP --------------------------------------------------------------------------------

    def routes(self) -> Sequence[Route]:
        return (Route("GET", "/api/arm", self.get_arm, "read"),
                Route("POST", "/api/arm", self.post_arm, "drive"))

    async def get_arm(self, request: web.Request) -> web.Response:
        return json_response(self.state())

    async def post_arm(self, request: web.Request) -> web.Response:
        body = await read_json_object(request, 4096)
        try:
            duration = self._apply_request(body)
        except ArmRefused as exc:
            raise ApiError(exc.status, f"arm refused: {exc.reason}") from None
        return json_response({**self.state(), "duration_s": round(duration, 3)})

    def _apply_request(self, body: dict[str, Any]) -> float:
        unknown = sorted(set(body) - {"pose", "joints", "gripper_m"})
        if unknown:
            raise ArmRefused(422, f"{unknown[0]}: unknown field (pose, joints, gripper_m)")
        now = self.clock()
        if "pose" in body:
            if len(body) > 1:
                raise ArmRefused(422, "give a pose, or joints and gripper_m, not both")
            if not isinstance(body["pose"], str):
                raise ArmRefused(422, f"pose: expected a name, got {body['pose']!r}")
            return self.arm.go_to_pose(body["pose"], now)
        joints = body.get("joints", {})
        if not isinstance(joints, dict):
            raise ArmRefused(422, f"joints: expected an object, got {joints!r}")
        goals = dict(joints)
        if "gripper_m" in body:
            goals[self.arm.joints[3]] = body["gripper_m"]
        if not goals:
            raise ArmRefused(422, "nothing to do: give a pose, joints or gripper_m")
        return self.arm.command(goals, now)

    # -- topics ------------------------------------------------------------------------------

    def topics(self) -> Sequence[Topic]:
        joint_in = [TopicIn(topic, FLOAT64, self._joint_handler(joint), "drive")
                    for topic, joint in zip(JOINT_TOPICS, self.arm.joints, strict=False)]
        finger_in = [TopicIn(topic, FLOAT64, self._joint_handler(self.arm.joints[3]), "drive")
                     for topic in FINGER_TOPICS]
        return (*joint_in, *finger_in,
                TopicIn("/arm/pose", STRING, self.on_pose_message, "drive"),
                TopicOut("/joint_states", JOINT_STATE, JOINT_STATES, joint_state_msg,
                         f"{self.settings.publish_rate:g} Hz"))

    def _joint_handler(self, joint: str) -> Callable[[Inbound], Any]:
        async def on_message(message: Inbound) -> Refusal | None:
            try:
                self.arm.command({joint: message.msg["data"]}, self.clock())
            except ArmRefused as exc:
                return Refusal(exc.reason, repeats=True)
            return None

        return on_message

    async def on_pose_message(self, message: Inbound) -> Refusal | None:
        try:
            self.arm.go_to_pose(str(message.msg["data"]), self.clock())
        except ArmRefused as exc:
            return Refusal(exc.reason)
        return None


def tool_at(joints: Sequence[str], positions: Mapping[str, float]) -> Tool:
    """The tool point (forward kinematics) and the gripper's opening at ``positions``."""
    j1, j2, j3, gripper = joints
    tip = forward(positions[j1], positions[j2], positions[j3])
    return Tool(tip.x, 0.0, positions[gripper])


def build_servo(config: Config) -> ServoArray:
    """The [arm] section's servo device (built, not opened)."""
    settings = config.get(ArmSettings)
    servo = create_device(settings.device, config["arm"], section="arm")
    assert isinstance(servo, ServoArray)
    return servo


def create(ctx: DaemonContext) -> ArmComponent | None:
    settings = ctx.settings(ArmSettings)
    if not settings.enabled:
        return None
    problems = settings.pose_problems()
    if problems:
        raise ValueError(problems[0])
    config = ctx.config
    component = ArmComponent(settings, lambda: build_servo(config), ctx.plugs)
    if ctx.sim is not None:
        emulator = ctx.sim.device_emulators.get("arm")
        component.readback = emulator.servo_pulse_us if emulator is not None \
            else lambda output: component_pulse(component, output)
        ctx.sim.world.arm_tool = component.tool  # the world's objects follow the gripper
    return component


def component_pulse(component: ArmComponent, output: int) -> float:
    """The mock servos' own record of an output's pulse (they have no emulator)."""
    reader: PulseReader | None = getattr(component.servo, "servo_pulse_us", None)
    return reader(output) if reader is not None else 0.0


def devices(config: Config) -> list[DeviceUse]:
    settings = config.get(ArmSettings)
    return [DeviceUse(settings.device, "arm")] if settings.enabled else []


COMPONENT = ComponentSpec("arm", create, ArmSettings, devices)
