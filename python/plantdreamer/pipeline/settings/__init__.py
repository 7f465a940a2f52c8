"""The settings wing: every setting of a run (``config``: ``GenerateConfig`` and its sections'
owners), the presets, the training section (``train_config``), what plants trained together
share (``group_settings``), the values decided once (``runtime``) and ``--print-config``
(``resolved``). No torch at import.
"""
