"""Calibration wing: inverse methods on the batched solver core.

PSO (:mod:`.pso`), the multi-region objective (:mod:`.multiregion`), the UKF (:mod:`.ukf`) and
its body problems (:mod:`.ukf_body`); every candidate parameter set is a batch row.
"""
