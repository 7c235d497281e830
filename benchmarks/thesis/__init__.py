"""Scripts that reproduce the seeds' tables and figures, each printing ours beside the seed's.

Cloth (*thesis* ch. 7): Table 7.1 (:mod:`.table71`), Fig. 7.3 (:mod:`.fig73`), Table 7.2
(:mod:`.table72`), the geometry oracle and feature probes (:mod:`.geometry_oracle`,
:mod:`.feature_probe`). Tissue: Tables 3.1/3.2 and Fig. 3.7 (:mod:`.tissue_tables`), the PSO
benchmark (:mod:`.pso_benchmark`), Table 4.1 (:mod:`.table41`, :mod:`.ukf_experiments`), the
paper's Table 1 (:mod:`.paper_table1`, :mod:`.monocular_benchmark`); their Hydra entry is
:mod:`.tissue_jobs`.
"""
