"""Reading the files a user hands the project within bounds of what they are (lines, members, documents,
nesting): one module, :mod:`hil.files.bounded`, below every package that reads a file — the scenario and
dispersion TOML, calibration files, phone logs, run directories."""
