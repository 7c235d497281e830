"""Applications on top of the whole stack: the main job (demo) and material cloning.

They simulate, render and (cloning) classify, so they stand above ``datasets`` and ``models``;
no library package imports them (an import-linter contract in CI).
"""
