"""The host side of vscmg-hil.

Pure math (no I/O): :mod:`hil.so3`, :mod:`hil.estimation`, :mod:`hil.vscmg`, :mod:`hil.control` (the
world's models that step the spacecraft and simulate its phone are the far side's: :mod:`firmware_sim.world`).
Around it: :mod:`hil.scenario` (what a run simulates), :mod:`hil.timing` (clocks, scheduler),
:mod:`hil.threads` (a background thread's error, raised by its owner), :mod:`hil.files` (files read within
bounds), :mod:`hil.link` (board client, transports, phone sources), :mod:`hil.runtime` (the host's loop and
its run directory), and the tools: :mod:`hil.logs`, :mod:`hil.calibration`, :mod:`hil.montecarlo`,
:mod:`hil.plots`, :mod:`hil.cli`. docs/architecture.md draws the layers.
"""
