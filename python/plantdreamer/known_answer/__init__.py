"""Known-answer check of SDS: tiny models trained on a plant's true views (see docs/known_answer.md)."""
