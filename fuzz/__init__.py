"""Fuzzing of the frame decoder, the CSV/NPZ readers and the certificate loader.

``python -m fuzz`` (see :mod:`fuzz.run`); the targets and their contracts are in
:mod:`fuzz.targets`, the hypothesis strategies in :mod:`fuzz.strategies`.
"""
