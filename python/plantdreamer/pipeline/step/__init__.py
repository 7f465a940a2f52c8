"""The training step of a trainer's plants (docs/step.md): ``schedule`` (the order of one
step's work, as one batch or two halves in flight, the run-ahead and the stop rule),
``update`` (a plant's checks and Adam after the backward), ``plant`` (a plant of the
trainer) and ``options`` (the variants that keep the bits). The loop around the steps,
its checkpoints and stop signals are ``pipeline/trainer.py``'s."""
