"""Star catalogues (Hipparcos, BSC5), their source files, photometry, declination bands and
sky coverage, the on-disk cache, and the pattern indexes (pairs, triangles). May import:
:mod:`adfusion.maths`, :mod:`adfusion.plain`.
"""
