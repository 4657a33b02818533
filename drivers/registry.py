# The motor driver table: name -> (module, class). Pure data, so sim/ and config can read it.
from __future__ import annotations

# driver name => (module, class name); the module is imported only when that driver is chosen.
# The names are also the choices of `[driver] type` and `[sim] driver`.
DRIVERS: dict[str, tuple[str, str]] = {
    "mock": ("drivers.mock", "MockDriver"),
    "l298n": ("drivers.l298n", "L298NDriver"),
    "pigpio": ("drivers.pigpio_pwm", "PigpioDriver"),
    "serial": ("drivers.arduino_serial", "SerialBridgeDriver"),
    "odrive_can": ("drivers.odrive_can", "ODriveCanDriver"),
}


def registered_name(module: str, class_name: str) -> str | None:
    """The name ``module.class_name`` is registered under, or ``None``."""
    for name, entry in DRIVERS.items():
        if entry == (module, class_name):
            return name
    return None
