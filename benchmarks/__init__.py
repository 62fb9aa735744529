"""pointrig's benchmarks, run from the repository root as ``python -m benchmarks.NAME``
(see ``benchmarks/BENCHMARKS.md``)."""
