"""The run's state wing: everything a run needs to continue (``run_state``), its checkpoints
(``checkpoint``), the group's noise state (``group_noise``) and what a run writes
(``run_outputs``).
"""
