# One table: each registered driver's emulator, started on a MotorPair, and the options reaching it.
from __future__ import annotations

import time
import uuid
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from drivers.rosarduino import ticks_to_rad_s
from sim.motor_model import MotorPair, PairWiring, WheelMotor

LOOPBACK = "127.0.0.1"
#: Seconds the emulated Arduino's bootloader ignores input after the port opens.
ARDUINO_BOOT_S = 0.01


@dataclass(frozen=True)
class Emulated:
    """A running emulator, how to stop it, and the ``[driver.<name>]`` options reaching it.

    ``options`` go on top of the driver's configured section (they win). ``resolution_rad_s``
    is the smallest wheel-speed step the wire can carry (0 = continuous); ``in_process_only``
    says no other process can reach the emulator (a python-can virtual bus).
    """

    emulator: Any
    options: dict[str, Any]
    stop: Callable[[], None]
    resolution_rad_s: float = 0.0
    in_process_only: bool = False


# what starts an emulator: the wheels, a private directory, the driver's complete section
Starter = Callable[[MotorPair, Path, Mapping[str, Any]], Emulated]


@dataclass(frozen=True)
class EmulatorWiring:
    """How one driver meets its emulator: the agreed encoder resolution and the starter."""

    #: encoder counts (quadrature edges) per wheel revolution of the emulated wheels
    counts_per_rev: int
    starter: Starter

    def start(self, motors: MotorPair, workdir: Path, options: Mapping[str, Any],
              miswire: Sequence[str] = ()) -> Emulated:
        """Mount the wheels as the driver's complete section ``options`` expects them (its
        ``*_motor_inverted`` / ``*_encoder_inverted`` keys), play the ``miswire`` faults on
        top, and start the emulator on them."""
        motors.wiring = mounted(options, miswire)
        return self.starter(motors, workdir, options)

    def motors(self, *, max_speed_rad_s: float = 40.0, time_constant_s: float = 0.05,
               clock: Callable[[], float] | None = time.monotonic) -> MotorPair:
        """A MotorPair with this driver's encoder resolution (``clock=None``: the world steps
        it)."""
        def wheel() -> WheelMotor:
            return WheelMotor(max_speed_rad_s=max_speed_rad_s, time_constant_s=time_constant_s,
                              counts_per_rev=self.counts_per_rev)

        return MotorPair(wheel(), wheel(), clock=clock)


def mounted(options: Mapping[str, Any], miswire: Sequence[str] = ()) -> PairWiring:
    """The wheels' wiring for a driver section (a driver without direction keys: as is)."""
    def flags(kind: str) -> tuple[bool, bool]:
        return (bool(options.get(f"left_{kind}_inverted", False)),
                bool(options.get(f"right_{kind}_inverted", False)))

    return PairWiring.build(flags("motor"), flags("encoder"), miswire)


# -- one starter per driver --------------------------------------------------------------


def _start_mock(motors: MotorPair, workdir: Path, options: Mapping[str, Any]) -> Emulated:
    """No wire: whoever runs the mock driver connects its ``listeners`` to the motors."""
    return Emulated(None, {}, lambda: None)


def _start_serial(motors: MotorPair, workdir: Path, options: Mapping[str, Any]) -> Emulated:
    """An Arduino running ROSArduinoBridge on a pty with a stable link."""
    from sim.arduino_emulator import ArduinoEmulator

    board = ArduinoEmulator(workdir / "arduino", motors, pid_rate=options["pid_rate"],
                            boot_s=ARDUINO_BOOT_S, auto_stop_s=options["auto_stop_s"]).start()
    counts = motors.left.counts_per_rev
    reach = {"port": str(board.link), "counts_per_rev": counts, "reset_wait_s": 0.05,
             "poll_rate": 50.0}
    return Emulated(board, reach, board.stop, ticks_to_rad_s(1, counts, options["pid_rate"]))


def _start_pigpio(motors: MotorPair, workdir: Path, options: Mapping[str, Any]) -> Emulated:
    """pigpiod on a loopback port, L298N bridges (EN = PWM) and encoders on its pins."""
    from sim.pigpiod_emulator import PigpiodEmulator, pigpio_driver_wiring

    reach = {"host": LOOPBACK, "encoders": True,
             "max_wheel_speed": motors.left.max_speed_rad_s,
             "encoder_counts_per_rev": motors.left.counts_per_rev}
    pigpiod = PigpiodEmulator(pigpio_driver_wiring({**options, **reach}), motors,
                              host=LOOPBACK, port=0).start()
    return Emulated(pigpiod, {**reach, "port": pigpiod.port}, pigpiod.close)


def _start_l298n(motors: MotorPair, workdir: Path, options: Mapping[str, Any]) -> Emulated:
    """gpiozero's PiGPIOFactory against the emulated pigpiod, L298N bridges on its pins."""
    from sim.pigpiod_emulator import PigpiodEmulator, l298n_driver_wiring

    reach = {"pin_factory": "pigpio", "pigpio_host": LOOPBACK, "encoders": True,
             "max_wheel_speed": motors.left.max_speed_rad_s,
             # gpiozero's RotaryEncoder counts one step per 4-edge quadrature cycle
             "encoder_counts_per_rev": motors.left.counts_per_rev // 4}
    pigpiod = PigpiodEmulator(l298n_driver_wiring({**options, **reach}), motors,
                              host=LOOPBACK, port=0).start()
    return Emulated(pigpiod, {**reach, "pigpio_port": pigpiod.port}, pigpiod.close)


def _start_odrive(motors: MotorPair, workdir: Path, options: Mapping[str, Any]) -> Emulated:
    """An ODrive (two axes) on a python-can virtual channel of its own."""
    from sim.odrive_emulator import ODriveEmulator

    channel = f"arbiterd-{workdir.name}-{uuid.uuid4().hex[:8]}"
    # the axes' directions are the MotorPair's wiring (mounted from the section)
    odrive = ODriveEmulator("virtual", channel, motors=motors, directions=(1, 1),
                            node_ids=(options["left_node_id"], options["right_node_id"]),
                            gear_ratio=options["gear_ratio"],
                            watchdog_timeout_s=options["watchdog_timeout_s"]).start()
    return Emulated(odrive, {"interface": "virtual", "channel": channel}, odrive.stop,
                    in_process_only=True)


#: driver name => its emulator wiring; one row per name in ``drivers.DRIVERS``. Encoder
#: edges are generated one by one for pigpio and l298n, so their resolution stays modest; the
#: serial one is fine enough that ``m L R``'s ticks per frame round off little.
EMULATORS: dict[str, EmulatorWiring] = {
    "mock": EmulatorWiring(1440, _start_mock),
    "l298n": EmulatorWiring(200, _start_l298n),
    "pigpio": EmulatorWiring(200, _start_pigpio),
    "serial": EmulatorWiring(4096, _start_serial),
    "odrive_can": EmulatorWiring(8192, _start_odrive),
}


# -- devices other than the wheel pair ------------------------------------------------------

#: what starts a device's emulator: a private directory and the device's options
DeviceStarter = Callable[[Path, Mapping[str, Any]], Emulated]


def _start_pigpio_servo(workdir: Path, options: Mapping[str, Any]) -> Emulated:
    """pigpiod on a loopback port with nothing on its motor pins: the servos' pulses are its
    pins' state (``bank.pins[gpio].servo_us``)."""
    from sim.pigpiod_emulator import PigpiodEmulator, Wiring

    pigpiod = PigpiodEmulator(Wiring(), host=LOOPBACK, port=0).start()
    return Emulated(pigpiod, {"host": LOOPBACK, "port": pigpiod.port}, pigpiod.close)


def _start_pca9685_servo(workdir: Path, options: Mapping[str, Any]) -> Emulated:
    """A PCA9685 board on an emulated I2C bus (a loopback port) at the section's address: its
    channels' pulse widths are ``servo_pulse_us(channel)``."""
    from sim.pca9685_emulator import Pca9685Emulator

    board = Pca9685Emulator(options.get("address", 0x40), host=LOOPBACK).start()
    return Emulated(board, {"bus": board.bus}, board.close)


def _start_mock_servo(workdir: Path, options: Mapping[str, Any]) -> Emulated:
    """No wire: the mock servos record their pulses themselves."""
    return Emulated(None, {}, lambda: None)


def _ina_starter(kind: str) -> DeviceStarter:
    def start(workdir: Path, options: Mapping[str, Any]) -> Emulated:
        """An INA2xx breakout on an emulated I2C bus (a loopback port) at the section's
        address and with its shunt, measuring a battery model (``use_battery``: the
        world's pack under ``run --sim``)."""
        from sim.ina2xx_emulator import InaEmulator

        board = InaEmulator(kind, options.get("address", 0x40),
                            shunt_ohms=options.get("shunt_ohms", 0.1), host=LOOPBACK).start()
        return Emulated(board, {"bus": board.bus}, board.close)

    return start


def _start_odrive_battery(workdir: Path, options: Mapping[str, Any]) -> Emulated:
    """An ODrive of its own on a python-can virtual channel answering Get_Bus_Voltage_Current
    with a battery model (``use_battery``: the world's pack under ``run --sim``)."""
    from sim.odrive_emulator import ODriveEmulator

    node = int(options.get("node_id", 0))
    channel = f"arbiterd-battery-{workdir.name}-{uuid.uuid4().hex[:8]}"
    odrive = ODriveEmulator("virtual", channel, node_ids=(node, (node + 1) % 64)).start()
    return Emulated(odrive, {"interface": "virtual", "channel": channel}, odrive.stop,
                    in_process_only=True)


#: device name => the starter of its emulator; one row per name in ``drivers.device_registry``
DEVICE_EMULATORS: dict[str, DeviceStarter] = {
    "pigpio_servo": _start_pigpio_servo,
    "pca9685_servo": _start_pca9685_servo,
    "mock_servo": _start_mock_servo,
    "ina219": _ina_starter("ina219"),
    "ina226": _ina_starter("ina226"),
    "odrive_battery": _start_odrive_battery,
}
