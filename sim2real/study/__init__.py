"""The diagnosis's validation study, apart from what a user runs to diagnose footage.

Sealed pseudo-real sets with a withheld answer (:mod:`.seal`, out-of-library effects made as a
camera makes them in :mod:`.open_set`), blind validation rounds (:mod:`.validate`), stored
diagnoses decided again under other rules (:mod:`.rescore`) and the gap test's power with more
simulations (:mod:`.power`). The diagnosis itself never imports this package (an import-linter
contract in CI).
"""
