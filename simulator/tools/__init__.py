"""Command-line tools of the cloth and tissue experiments.

Cloth: Table 7.1, the Fig. 7.3 sensitivity study, mesh-sequence export. Tissue: Tables
3.1/3.2 and Fig. 3.7, Table 4.1, the paper's Table 1, with their Hydra entry
:mod:`simulator.tools.tissue`.
"""
