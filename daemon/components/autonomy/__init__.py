# Autonomous behaviours: a low-priority command source (wander).
