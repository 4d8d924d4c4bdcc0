"""Tracking: identification with an attitude prior (predicted stars, association, the tight
fit, motion smear) and its compiled kernels. May import: identify, detection, camera,
catalog, :mod:`adfusion.maths`.
"""
