"""Sim-to-real gap diagnosis: where the gap lies, which unmodelled effect causes it.

The package sits above ``simulator``, ``render``, ``datasets`` and ``models`` and imports
from them; nothing imports it. Entry points: ``python -m sim2real.diagnose`` (one real set
against one trained run) and ``python -m sim2real.study.seal`` (a pseudo-real set whose effect
is withheld, for checking the diagnosis blind).
"""
