"""Attitude control of a VSCMG spacecraft, pure math (no I/O): the geometric SO(3) controller and eigenaxis
slews (:mod:`.attitude`), Schaub–Junkins VSCMG steering (:mod:`.steering`), and the motor loops that turn
its rates into gimbal/rotor setpoints, with the servo model of the drives (:mod:`.motor_loops`)."""
