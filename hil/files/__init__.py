"""Reading the files a user hands the project within bounds of what they are (lines, members, documents,
nesting): one module, :mod:`hil.files.bounded`, below every package that reads a file — the scenario and
dispersion TOML, calibration files, phone logs, run directories. Writing results: where they go
(:mod:`hil.files.output`: directories made or a ConfigError naming them; a refused write an OutputError naming
the file) and how a growing log is appended to (:mod:`hil.files.appending`: whole lines, never a torn one,
also when the disk fills)."""
