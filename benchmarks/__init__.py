"""Benchmarks, run as modules from the repository root: ``python -m benchmarks.codec``,
``benchmarks.emulator``, ``benchmarks.link``, ``benchmarks.throughput`` (``make bench`` runs
all four). Each prints a table beside the machine it ran on and writes JSON to
``benchmarks/results/``; shared helpers are in :mod:`benchmarks._common`.

A package so that the scripts import ``benchmarks._common`` and the tests' reference models
(``tests.support.reference``) by their full names, with no ``sys.path`` changes.
"""
