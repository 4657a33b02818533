# Navigation in lockstep: the apartment with the navigation component, as the tests drive it.
from __future__ import annotations

import contextlib
from collections.abc import AsyncIterator

from daemon.components.navigation.component import NavigationComponent
from daemon.config import load_config
from daemon.lockstep.runner import Lockstep


@contextlib.asynccontextmanager
async def apartment_lockstep(seed: int = 3) -> AsyncIterator[Lockstep]:
    """The apartment world in lockstep with [navigation] on, its first revolutions taken."""
    config = load_config(None, sim=True, env={})
    config.update("sim", {"world_file": "apartment", "seed": seed})
    lockstep = Lockstep(config, navigation=True)
    await lockstep.begin()
    await lockstep.advance(0.3)
    try:
        yield lockstep
    finally:
        await lockstep.finish()


def nav_of(lockstep: Lockstep) -> NavigationComponent:
    assert lockstep.navigation is not None
    return lockstep.navigation
