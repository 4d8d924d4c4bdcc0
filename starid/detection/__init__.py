"""Star detection: a frame's background, threshold, blobs and centroids, and centroiding in
windows around predicted stars (tracking's detection). May import: :mod:`adfusion.maths`,
:mod:`adfusion.starid.camera.model`, :mod:`adfusion.starid.jit_cache`; never identification.
"""
