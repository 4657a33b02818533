# The built-in world files (sim.world.builtin_worlds); a package so that they ship.
