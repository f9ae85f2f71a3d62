"""Attitude estimation, pure math (no I/O): sensor sample types (:mod:`.sensors`), the multi-rate merge
that holds the last sample of slower sensors (:mod:`.multirate`), the paper's Butterworth pre-filter and
the magnetic gate (:mod:`.prefilter`), the paper's variational estimator and the attitude filter around it
(:mod:`.estimator`), inertial reference directions and the geomagnetic field model (:mod:`.inertial`), and
error metrics against ground truth (:mod:`.metrics`)."""
