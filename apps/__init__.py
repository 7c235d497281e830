"""Applications on top of the whole stack: the main job, material cloning, garment recovery.

They simulate, render and (cloning) classify, so they stand above ``datasets`` and ``models``;
no library package imports them (an import-linter contract in CI). :mod:`apps.garment` recovers
a garment from one image on :mod:`simulator.garment`.
"""
