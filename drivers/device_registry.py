# The device table: name -> (module, class) of hardware other than the wheel pair. Pure data.
from __future__ import annotations

# device name => (module, class name); the module is imported only when a component uses it.
# Each name has an emulator row in sim/wiring.py DEVICE_EMULATORS.
DEVICES: dict[str, tuple[str, str]] = {
    "pigpio_servo": ("drivers.pigpio_servo", "PigpioServos"),
    "pca9685_servo": ("drivers.pca9685_servo", "Pca9685Servos"),
    "mock_servo": ("drivers.mock_servo", "MockServos"),
    "ina219": ("drivers.ina2xx", "Ina219Monitor"),
    "ina226": ("drivers.ina2xx", "Ina226Monitor"),
    "odrive_battery": ("drivers.odrive_battery", "ODriveBattery"),
    "picamera2_camera": ("drivers.picamera2_camera", "Picamera2Camera"),
    "v4l2_camera": ("drivers.v4l2_camera", "V4l2Camera"),
}
