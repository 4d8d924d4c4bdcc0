"""Lost-in-space identification (Renken's n-star patterns, Not-Modus, the combinations), the
verification of a candidate and its false-match probability, the final refit, the
:class:`Solution` types, and their compiled kernels. May import: camera, catalog,
:mod:`adfusion.maths`, :mod:`adfusion.starid.jit_cache`.
"""
