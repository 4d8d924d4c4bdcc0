"""Bleif (2004) DLR-TUBSAT: the MusterPr reference-star matcher and its pattern catalogue, the
operator-in-the-loop session, star angles (RA, DE, AZ), and the bridge into the solver's
verification. May import: identify, camera, catalog, :mod:`adfusion.maths`.
"""
