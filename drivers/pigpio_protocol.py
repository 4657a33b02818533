# pigpio socket interface values both the driver and the pigpiod emulator use (pure, no I/O).
from __future__ import annotations

#: GPIO => hardware PWM channel (12/18 share channel 0, 13/19 channel 1).
HARDWARE_PWM_CHANNEL = {12: 0, 18: 0, 13: 1, 19: 1}
#: Full-scale duty of the HP (hardware_PWM) command.
HARDWARE_DUTY_FULL = 1_000_000
#: What HWVER answers on a Raspberry Pi 4B (the revision code).
PI4B_REVISION = 0xC03111

# MODES: pin modes; PUD: pull-up/down
MODE_INPUT, MODE_OUTPUT = 0, 1
PUD_OFF, PUD_DOWN, PUD_UP = 0, 1, 2
# callbacks: which edges, and the level a watchdog timeout reports
RISING_EDGE, FALLING_EDGE, EITHER_EDGE = 0, 1, 2
PI_TIMEOUT_LEVEL = 2
