"""Host side of calibration: bench CSVs, fitting maps to them, calibration files, plots, test vectors.

The maps themselves (and their binary form) live in the sans-IO ``protocol.calibration``; this package
reads and writes files and does the numerics that need numpy/scipy. Modules: ``bench`` (bench CSVs),
``generate`` (seeded synthetic bench data), ``fit`` (least-squares monotone fits and validation),
``files`` (the TOML calibration file format), ``plot`` (data against fit), ``vectors`` (test vectors
for other implementations of the binary format), ``textfiles`` (typed-error reads, atomic writes).

Through a board (``hil calibrate esc | sweep | unit``, docs/calibration.md §9): ``benchlink`` (the tools'
hold on a connected board: time, telemetry, modes, guards, settling), ``esc`` (teaching ESCs their
endpoints), ``sweep`` (pulse sweeps into bench CSVs), ``verify`` (tracking error through the uploaded
maps), ``cycle`` (sweep → fit → upload → read back → verify → save, in one go).
"""
