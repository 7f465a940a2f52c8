"""The generation pipeline: point cloud -> initial Gaussians -> guided optimisation -> outputs."""

from plantdreamer.pipeline.config import GenerateConfig
from plantdreamer.pipeline.run import RunInterrupted, RunResult, generate

__all__ = ["GenerateConfig", "RunInterrupted", "RunResult", "generate"]
