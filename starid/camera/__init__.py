"""Camera models (pixels ⇄ unit vectors), camera files, the camera fit to matched stars, FITS
WCS, and which catalogue stars a camera sees. May import: :mod:`adfusion.maths`,
:mod:`adfusion.starid.jit_cache`.
"""
