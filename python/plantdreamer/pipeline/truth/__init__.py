"""The ground-truth wing: each view's class, instance and depth maps through the rasterizer
(``ground_truth``), the label channels (``label_channels``), specks (``label_pieces``) and
the view files of a plant folder (``dataset_export``).
"""
