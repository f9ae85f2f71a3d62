"""Attitude estimation, pure math (no I/O): sensor sample types (:mod:`.sensors`), the multi-rate merge
that holds the last sample of slower sensors (:mod:`.multirate`), the paper's Butterworth pre-filter and
the magnetic gate (:mod:`.prefilter`), the paper's variational estimator — its parameters and constants
(:mod:`.params`), its step (:mod:`.variational`), the estimator object (:mod:`.estimator`) — and the
attitude filter around it (:mod:`.filter`, its step :mod:`.chain`), inertial reference directions and the
geomagnetic field model (:mod:`.inertial`), and error metrics against ground truth (:mod:`.metrics`).
The steps are compiled kernels (:mod:`hil.jit`; their parameter packing and flag bits in :mod:`.slots`);
:mod:`.reference` holds their numpy references. What the host calls is the :class:`.interface.Estimator`
protocol; estimators are chosen by name (:mod:`.registry`): the attitude filter (:mod:`.variational_kind`,
the default) or VQF (:mod:`.vqf_adapter`), or one a package registers."""
