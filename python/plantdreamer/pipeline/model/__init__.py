"""The model wing: the trainable Gaussians (``gaussian_model``) and their renders (``render``),
the training cameras (``sampler``), the source and the initial Gaussians (``source``,
``init``), density control and culling (``density``, ``density_ops``, ``culling``).
"""
