"""The host side of vscmg-hil.

Pure math (no I/O): :mod:`hil.so3` and the estimator, dynamics, control and steering modules.
Around it the runtime: sensor sources, loops, transports, the board client, logs, reports and the CLI.
"""
