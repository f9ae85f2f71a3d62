"""Time for every loop: injected clocks (wall, lockstep) (:mod:`.clock`) and the absolute-deadline
scheduler with lateness statistics (:mod:`.scheduler`)."""
