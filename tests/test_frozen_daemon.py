# A frozen daemon (SIGSTOP) with its device in another process: the device's own deadman stops it.
from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

from daemon.bench.frozen import measure

SPEED = 0.5  # m/s
FROZEN_S = 1.5
#: what the wheels may still roll after the deadman fires: the motor's decay (0.05 s time
#: constant) and the time between the daemon's last write and the SIGSTOP, with room to spare
SLACK_S = 0.5
DEADMEN = {"pigpio": {"deadman_s": 0.3}, "serial": {"auto_stop_s": 0.5}}


def test_the_device_deadman_stops_the_wheels_of_a_frozen_daemon() -> None:
    """pigpiod keeps its PWM and the Arduino its last speed while the daemon cannot run (the
    bench's --no-deadman row shows the wheels going on); the pigpiod script and the firmware's
    auto-stop end it. Both drivers run at once, each against its own device."""
    with ThreadPoolExecutor(len(DEADMEN)) as pool:
        rolls = dict(zip(DEADMEN, pool.map(lambda d: measure(d, FROZEN_S, DEADMEN[d], SPEED),
                                           DEADMEN), strict=True))
    for driver, roll in rolls.items():
        limit = next(iter(DEADMEN[driver].values())) + SLACK_S
        assert roll.still_after_s is not None, roll  # stopped while the daemon was frozen
        assert 0.0 < roll.rolled_m < SPEED * limit, roll  # it was moving, and not for long
