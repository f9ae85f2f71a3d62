"""Attitude estimation, pure math (no I/O): sensor sample types (:mod:`.sensors`), the multi-rate merge
that holds the last sample of slower sensors (:mod:`.multirate`), the paper's Butterworth pre-filter and
the magnetic gate (:mod:`.prefilter`), the paper's variational estimator — its parameters and constants
(:mod:`.params`), its step (:mod:`.variational`), the estimator object (:mod:`.estimator`) — and the
attitude filter around it (:mod:`.filter`, its step :mod:`.chain`), inertial reference directions and the
geomagnetic field model (:mod:`.inertial`), and error metrics against ground truth (:mod:`.metrics`).
The steps are compiled kernels (:mod:`hil.jit`); :mod:`.reference` holds their numpy references."""
