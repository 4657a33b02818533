# The arm in `run --sim`: HTTP and rosbridge drive the emulated servos; refusals; a dead board.
from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import aiohttp
import pytest

import sim.wiring
from base.config import ConfigError
from daemon.components.arm.kinematics import forward
from daemon.components.arm.settings import SEED_POSES
from daemon.config import load_config
from daemon.probe import probe_arm, safe_stop_arm
from drivers import pca9685_protocol as chip
from drivers.devices import Actuator, DeviceError, create_device
from sim.pca9685_emulator import Pca9685Emulator
from sim.wiring import DEVICE_EMULATORS, Emulated
from tests.support.in_process_daemon import in_process_daemon
from tests.support.rosbridge import connect
from tests.support.wait import eventually

#: fast joints, so that a move takes a few servo updates (0.1 rad/s..1 rad in 0.1 s)
FAST = "max_speed = [10.0, 10.0, 10.0, 0.35]\n"
#: one pulse step (a PCA9685 count at 50 Hz, 4.9 µs, of 2000 µs) in each joint's units: rad
#: over the π of a pitching joint, m over the gripper's 0.035 (pigpio's 1 µs is finer)
STEP = chip.step_us(chip.frequency_of(121)) / 2000
TOLERANCE = (STEP * math.pi,) * 3 + (STEP * 0.035,)


def arm_toml(backend: str, extra: str = "") -> str:
    return f'[arm]\nenabled = true\nbackend = "{backend}"\n' + extra


async def get_arm(http: aiohttp.ClientSession, url: str) -> dict[str, Any]:
    async with http.get(f"{url}/api/arm") as answer:
        assert answer.status == 200
        body: dict[str, Any] = await answer.json()
        return body


async def post_arm(http: aiohttp.ClientSession, url: str, body: Any) -> tuple[int, Any]:
    async with http.post(f"{url}/api/arm", json=body) as answer:
        return answer.status, await answer.json()


@pytest.mark.parametrize("backend", ["pca9685", "pigpio"])
async def test_a_pose_over_http_moves_the_emulated_servos(tmp_path: Path, backend: str) -> None:
    async with in_process_daemon(tmp_path, arm_toml(backend, FAST)) as robot, \
            aiohttp.ClientSession() as http:
        assert robot.daemon.health()["components"]["arm"]["status"] == "ok"
        status, body = await post_arm(http, robot.http_url, {"pose": "pregrasp"})
        assert status == 200 and body["target_pose"] == "pregrasp"

        pose = SEED_POSES["pregrasp"]

        async def at_pose() -> dict[str, Any] | None:  # the servos' pulses mean the pose
            state = await get_arm(http, robot.http_url)
            measured = [joint["measured"] for joint in state["joints"].values()]
            return state if state["pose"] == "pregrasp" and all(
                m is not None and abs(m - v) <= tol
                for m, v, tol in zip(measured, pose, TOLERANCE, strict=True)) else None

        state = await eventually(at_pose, "the emulated servos at pregrasp")
        tip = forward(*pose[:3])
        assert (state["end_effector"]["x"], state["end_effector"]["z"]) == \
            pytest.approx((tip.x, tip.z), abs=1e-4)
        status, body = await post_arm(http, robot.http_url,
                                      {"joints": {"arm_joint1": 0.2}, "gripper_m": 0.01})
        assert status == 200 and body["target_pose"] is None
        assert body["joints"]["arm_joint1"]["target"] == 0.2


async def test_bad_requests_are_refused_and_the_daemon_runs_on(tmp_path: Path) -> None:
    async with in_process_daemon(tmp_path, arm_toml("pca9685", FAST)) as robot, \
            aiohttp.ClientSession() as http:
        url = robot.http_url
        status, body = await post_arm(http, url, {"pose": "wave"})
        assert status == 404 and "no pose named 'wave'; poses: home, pregrasp" in body["error"]
        status, body = await post_arm(http, url, {"joints": {"arm_joint3": 1.7}})
        assert status == 422 and "arm_joint3 = 1.7 is outside its limits" in body["error"]
        status, body = await post_arm(http, url, {"gripper_m": "wide"})
        assert status == 422 and "gripper: expected a finite number" in body["error"]
        status, body = await post_arm(http, url, {"pose": "home", "joints": {}})
        assert status == 422
        status, body = await post_arm(http, url, {"speed": 1})
        assert status == 422 and "speed: unknown field" in body["error"]
        async with http.post(f"{url}/api/arm", data=b'{"gripper_m": NaN}',
                             headers={"Content-Type": "application/json"}) as answer:
            assert answer.status == 400  # not JSON
        assert robot.daemon.health()["components"]["arm"]["status"] == "ok"
        assert (await get_arm(http, url))["pose"] == "home"


async def test_the_estop_freezes_the_arm_and_refuses_it(tmp_path: Path) -> None:
    slow = "max_speed = [0.5, 0.5, 0.5, 0.02]\n"
    async with in_process_daemon(tmp_path, arm_toml("mock", slow)) as robot, \
            aiohttp.ClientSession() as http:
        url = robot.http_url
        await post_arm(http, url, {"pose": "carry"})
        await eventually(lambda: robot.component("arm").arm.writes > 3, "the arm moving")
        async with http.post(f"{url}/api/estop", json={"engaged": True}) as answer:
            assert answer.status == 200
        state = await get_arm(http, url)
        assert not state["moving"] and state["frozen_by_estop"]
        held = {name: joint["target"] for name, joint in state["joints"].items()}
        assert held != {name: 0.0 for name in held}
        status, body = await post_arm(http, url, {"pose": "home"})
        assert status == 409 and "e-stop engaged" in body["error"]
        arm = robot.component("arm").arm
        await eventually(lambda: arm.written == arm.motion.goal, "the frozen position written")
        writes, steps = arm.writes, arm.steps
        await eventually(lambda: arm.steps >= steps + 5, "five more servo updates")
        assert arm.writes == writes  # nothing more sent: the servos hold


async def test_joint_states_follow_the_topics(tmp_path: Path) -> None:
    async with in_process_daemon(tmp_path, arm_toml("pca9685", FAST)) as robot, \
            connect(robot.ws_url) as client:
        await client.send(op="subscribe", topic="/joint_states")
        await client.send(op="advertise", topic="/arm/pose", type="std_msgs/msg/String")
        await client.send(op="publish", topic="/arm/pose", msg={"data": "carry"})

        def converged(pose: tuple[float, ...]) -> Any:
            def check(m: dict[str, Any]) -> bool:
                if m.get("op") != "publish" or m.get("topic") != "/joint_states":
                    return False
                msg = m["msg"]
                want = [*pose[:3], pose[3], pose[3]]
                return all(abs(a - b) <= tol for a, b, tol in
                           zip(msg["position"], want, (*TOLERANCE, TOLERANCE[3]), strict=True))
            return check

        message = await client.expect(converged(SEED_POSES["carry"]), what="carry")
        assert message["msg"]["name"] == ["arm_joint1", "arm_joint2", "arm_joint3",
                                          "left_finger_joint", "right_finger_joint"]
        client.received.clear()
        await client.send(op="advertise", topic="/arm_joint2_cmd", type="std_msgs/msg/Float64")
        await client.send(op="publish", topic="/arm_joint2_cmd", msg={"data": -0.5})
        await client.send(op="advertise", topic="/left_finger_cmd",
                          type="std_msgs/msg/Float64")
        await client.send(op="publish", topic="/left_finger_cmd", msg={"data": 0.02})
        carry = SEED_POSES["carry"]
        await client.expect(converged((carry[0], -0.5, carry[2], 0.02)), what="the topics")
        client.received.clear()
        await client.send(op="publish", topic="/arm_joint2_cmd", msg={"data": 3.0})
        refusal = await client.op("status", level="error")
        assert "arm_joint2 = 3.0 is outside its limits" in refusal["msg"]


def test_a_channel_used_twice_is_a_configuration_error(tmp_path: Path) -> None:
    path = tmp_path / "arbiterd.toml"
    path.write_text(arm_toml("pca9685", "channels = [0, 1, 1, 3]\n"))
    with pytest.raises(ConfigError, match=r"\[arm\] channels: a channel is used twice"):
        load_config(path, sim=True)


@pytest.mark.parametrize(("extra", "problem"), [
    ('poses = [["wave", 0.1, 0.2]]\n', r"\[arm\] poses: .*expected \[name, joint1"),
    ('poses = [["wave", 0.1, 0.2, 0.3, nan]]\n', r"\[arm\] poses: .*finite"),
    ('backend = "servo9000"\n', r"\[arm\] backend: must be one of"),
    ("max_speed = [1.0, 1.0, 0.0, 0.1]\n", r"\[arm\] max_speed: item 2: must be > 0"),
    ('joints = ["a", "b", "a", "g"]\n', r"\[arm\] joints: a name is used twice"),
    ("offsets_us = [0, 0, 400, 0]\n", r"\[arm\] joint arm_joint3: pulses with the offset "
                                        r"\(900..2900 µs\) leave 500..2500 µs"),
    ("lower = [-1.0, -1.0, -1.0]\n", r"\[arm\] lower: expected a list of 4 items"),
])
def test_bad_arm_keys_name_the_key(tmp_path: Path, extra: str, problem: str) -> None:
    path = tmp_path / "arbiterd.toml"
    path.write_text(arm_toml("mock").replace('backend = "mock"\n', "") + extra)
    with pytest.raises(ConfigError, match=problem):
        load_config(path, sim=True)


def test_configured_poses_extend_and_override_the_seed_ones(tmp_path: Path) -> None:
    from daemon.components.arm.settings import ArmSettings

    path = tmp_path / "arbiterd.toml"
    path.write_text(arm_toml("mock", 'poses = [["wave", 0.5, -0.5, 0.5, 0.0], '
                                     '["home", 0.0, 0.2, 0.0, 0.0]]\n'))
    poses = load_config(path, sim=True).get(ArmSettings).named_poses()
    assert poses["wave"]["arm_joint2"] == -0.5 and poses["home"]["arm_joint2"] == 0.2
    assert poses["pregrasp"]["arm_joint1"] == 1.043


async def test_a_board_that_does_not_answer_degrades_health_only(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    def silent_board(workdir: Path, options: Any) -> Emulated:
        board = Pca9685Emulator(host="127.0.0.1").start()
        board.answering = False
        return Emulated(board, {"bus": board.bus}, board.close)

    import daemon.components.arm.component

    monkeypatch.setitem(sim.wiring.DEVICE_EMULATORS, "pca9685_servo", silent_board)
    monkeypatch.setattr(daemon.components.arm.component, "RETRY_MIN_S", 0.05)
    async with in_process_daemon(tmp_path, arm_toml("pca9685")) as robot, \
            aiohttp.ClientSession() as http:
        health = robot.daemon.health()
        assert health["components"]["arm"]["status"] == "error"
        assert "no answer from the PCA9685 at 0x40" in str(health["components"]["arm"])
        status, body = await post_arm(http, robot.http_url, {"pose": "carry"})
        assert status == 503 and "not connected" in body["error"]
        async with http.get(f"{robot.http_url}/api/status") as answer:
            assert answer.status == 200  # the daemon runs on
        board: Pca9685Emulator = robot.ctx.sim.device_emulators["arm"]
        board.answering = True  # connected at last: the servos are sent home
        # the channels are written one after another: wait for the last of them
        await eventually(lambda: all(board.servo_pulse_us(c) > 0 for c in range(4)),
                         "pulses on all four channels")
        assert [board.servo_pulse_us(c) for c in range(4)] == pytest.approx(
            [1500, 1500, 1500, 500], abs=chip.step_us(50.0))


async def test_pca9685_register_semantics(tmp_path: Path) -> None:
    emulated = DEVICE_EMULATORS["pca9685_servo"](tmp_path, {})
    board: Pca9685Emulator = emulated.emulator
    try:
        board.chip.registers[chip.MODE1] = 0  # awake: PRESCALE must not take a write
        board.chip.write(chip.PRESCALE, (5,))
        assert board.chip.prescale_refused == 1
        assert board.chip.registers[chip.PRESCALE] == chip.PRESCALE_RESET
        servo = create_device("pca9685_servo", {**emulated.options, "channels": [4]},
                              section="arm")
        assert isinstance(servo, Actuator)
        await servo.open()
        assert board.chip.prescale_refused == 1  # the driver wrote it asleep
        assert board.chip.registers[chip.PRESCALE] == 121
        assert board.chip.frequency_hz == pytest.approx(50.0, rel=0.01)
        assert not board.chip.asleep and board.chip.registers[chip.MODE1] & chip.AI
        await servo.write({"joint1": 0.0})
        assert board.servo_pulse_us(4) == pytest.approx(1500, abs=chip.step_us(50.0))
        await servo.relax()
        assert board.servo_pulse_us(4) == 0.0
        await servo.close()
    finally:
        emulated.stop()


async def test_an_absent_board_is_a_clear_device_error(tmp_path: Path) -> None:
    emulated = DEVICE_EMULATORS["pca9685_servo"](tmp_path, {})
    try:
        servo = create_device("pca9685_servo", {**emulated.options, "address": 0x41},
                              section="arm")
        with pytest.raises(DeviceError, match=r"\[arm\] no answer from the PCA9685 at 0x41 "
                                              r"on emulated:127.0.0.1:\d+"):
            await servo.open()
    finally:
        emulated.stop()


@pytest.mark.parametrize(("on_stop", "pulse"), [("relax", 0.0), ("home", 1500.0)])
async def test_safe_stop_puts_the_servos_in_their_shutdown_state(
        tmp_path: Path, on_stop: str, pulse: float) -> None:
    emulated = DEVICE_EMULATORS["pca9685_servo"](tmp_path, {})
    try:
        path = tmp_path / "arbiterd.toml"
        path.write_text(arm_toml("pca9685", f'on_stop = "{on_stop}"\nbus = '
                                            f'"{emulated.options["bus"]}"\n'))
        config = load_config(path)
        assert await safe_stop_arm(config) == ("relaxed" if on_stop == "relax" else "home")
        for channel in range(3):
            assert emulated.emulator.servo_pulse_us(channel) == pytest.approx(
                pulse, abs=chip.step_us(50.0))
    finally:
        emulated.stop()


async def test_check_probes_the_board_without_touching_it(tmp_path: Path) -> None:
    emulated = DEVICE_EMULATORS["pca9685_servo"](tmp_path, {})
    board: Pca9685Emulator = emulated.emulator
    try:
        path = tmp_path / "arbiterd.toml"
        path.write_text(arm_toml("pca9685", f'bus = "{board.bus}"\n'))
        writes = board.chip.writes
        assert await probe_arm(load_config(path)) == []
        assert board.chip.writes == writes and board.chip.asleep  # read only
        board.answering = False
        assert await probe_arm(load_config(path)) == [
            f"[arm] no answer from the PCA9685 at 0x40 on {board.bus} (Remote I/O error): "
            "check its wiring and address"]
    finally:
        emulated.stop()


def test_a_pose_outside_the_limits_names_the_pose_and_joint(tmp_path: Path) -> None:
    from daemon.components.arm.settings import ArmSettings

    path = tmp_path / "arbiterd.toml"
    path.write_text(arm_toml("mock", 'poses = [["reach", 0.0, 0.0, 0.0, 0.05]]\n'))
    assert load_config(path, sim=True).get(ArmSettings).pose_problems() == [
        "poses: reach: gripper = 0.05 is outside 0.0..0.035"]


async def test_a_board_lost_while_moving_freezes_the_arm_until_it_answers_again(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import daemon.components.arm.component

    monkeypatch.setattr(daemon.components.arm.component, "RETRY_MIN_S", 0.05)
    slow = "max_speed = [0.5, 0.5, 0.5, 0.02]\n"
    async with in_process_daemon(tmp_path, arm_toml("pca9685", slow)) as robot, \
            aiohttp.ClientSession() as http:
        component = robot.component("arm")
        board: Pca9685Emulator = robot.ctx.sim.device_emulators["arm"]
        await post_arm(http, robot.http_url, {"pose": "carry"})
        await eventually(lambda: component.arm.writes > 3, "the arm moving")
        board.answering = False
        health = await eventually(
            lambda: (h := component.health().to_json())["status"] == "error" and h, "the fault")
        assert "no answer from the PCA9685" in health["fault"]
        state = await get_arm(http, robot.http_url)
        assert not state["moving"] and state["pose"] is None  # frozen part way
        status, _ = await post_arm(http, robot.http_url, {"pose": "home"})
        assert status == 503
        board.answering = True
        await eventually(lambda: component.health().status == "ok", "the board back")
        await eventually(lambda: component.arm.written is not None, "the held position sent")
        after = (await get_arm(http, robot.http_url))["joints"]
        for name, joint in state["joints"].items():  # it holds where it froze
            assert after[name]["target"] == joint["target"] == joint["position"]
        status, _ = await post_arm(http, robot.http_url, {"pose": "home"})
        assert status == 200


async def test_the_daemons_shutdown_parks_the_arm_at_home_when_configured(
        tmp_path: Path) -> None:
    toml = arm_toml("pca9685", FAST + 'on_stop = "home"\n')
    async with in_process_daemon(tmp_path, toml) as robot, aiohttp.ClientSession() as http:
        board: Pca9685Emulator = robot.ctx.sim.device_emulators["arm"]
        await post_arm(http, robot.http_url, {"pose": "carry"})
        await eventually(lambda: robot.component("arm").state()["pose"] == "carry",
                         "the arm at carry")
    # the daemon has stopped: the board (its registers outlive the emulator) holds home
    assert [board.servo_pulse_us(c) for c in range(4)] == pytest.approx(
        [1500, 1500, 1500, 500], abs=chip.step_us(50.0))


@pytest.mark.parametrize(("problem", "says"), [
    (FileNotFoundError(2, "No such file or directory"), r"no such bus: enable I2C"),
    (ModuleNotFoundError("No module named 'smbus2'"), r"smbus2 is not installed"),
])
async def test_a_missing_bus_or_library_says_what_to_do(
        monkeypatch: pytest.MonkeyPatch, problem: Exception, says: str) -> None:
    import drivers.pca9685_servo

    def fails(bus: str, timeout_s: float) -> None:
        raise problem

    monkeypatch.setattr(drivers.pca9685_servo, "open_i2c", fails)
    servo = create_device("pca9685_servo", {"bus": "/dev/i2c-1"}, section="arm")
    with pytest.raises(DeviceError, match=rf"\[arm\] PCA9685 at 0x40 on /dev/i2c-1: {says}"):
        await servo.open()
