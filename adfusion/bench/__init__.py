"""The benchmark harness: peer adapters (tetra3rs, cedar-solve), frame models, sweeps,
the campaign engine and the Renken §8 driver. The library never imports it; ``adfusion
bench …`` and ``benchmarks/`` run it."""
