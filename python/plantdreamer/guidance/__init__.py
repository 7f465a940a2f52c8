"""Diffusion guidance: score distillation (SDS) with Stable Diffusion + depth ControlNet + LoRA.

Light to import: the diffusers / transformers models load only when a guidance is built.
"""
