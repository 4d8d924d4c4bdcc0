"""Yee (1999) triad identification and plate-constant pointing, and its bridge into the
solver's verification. May import: identify, camera, catalog, :mod:`adfusion.maths`.
"""
