# `arbiterd simulate`: the control code and the simulated world in lockstep virtual time.
