"""The bottom layer every room imports: Hamilton scalar-first quaternions, rotation
matrices, RA/Dec/roll (:mod:`adfusion.maths.rotations`) and Wahba's problem with its
covariance (:mod:`adfusion.maths.attitude`). Imports nothing of ours.
"""
