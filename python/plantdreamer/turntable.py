"""Turntable files: an orbit's frames as an animated GIF and/or an H.264 MP4.

Light to import (the CLI reads TURNTABLE_FORMATS for its options); the encoders load on use.
The MP4 uses the ffmpeg binary that the imageio-ffmpeg wheel ships.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import numpy as np

TURNTABLE_FORMATS = ("gif", "mp4", "both", "none")
TURNTABLE_FPS = 12.5  # 80 ms a frame
TURNTABLE_FRAMES = 40  # frames picked from the orbit renders
# One encoder thread and no version strings in the file: the same frames give the same bytes.
MP4_DETERMINISTIC = ("-threads", "1", "-fflags", "+bitexact", "-flags:v", "+bitexact")


def suffixes(fmt: str) -> tuple[str, ...]:
    """The file suffixes a turntable format writes: ``"both"`` -> ``("gif", "mp4")``."""
    return {"gif": ("gif",), "mp4": ("mp4",), "both": ("gif", "mp4"), "none": ()}[fmt]


def write_gif(path: Path, frames: list[np.ndarray]) -> None:
    """A looping GIF of uint8 [H, W, 3] frames."""
    import imageio.v3 as iio
    import numpy as np

    duration_ms = round(1000 / TURNTABLE_FPS)
    iio.imwrite(path, np.stack(frames), extension=".gif", duration=duration_ms, loop=0)


def write_mp4(path: Path, frames: list[np.ndarray]) -> None:
    """An H.264 MP4 (yuv420p, plays everywhere) of uint8 [H, W, 3] frames.

    ``-f mp4`` because the temporary file of an atomic write has another suffix.
    """
    import imageio_ffmpeg
    import numpy as np

    h, w = frames[0].shape[:2]
    pad = ((0, h % 2), (0, w % 2), (0, 0))  # yuv420p needs even sides: repeat the edge
    writer = imageio_ffmpeg.write_frames(
        str(path),
        (w + w % 2, h + h % 2),
        fps=TURNTABLE_FPS,
        codec="libx264",
        quality=8,
        macro_block_size=1,
        ffmpeg_log_level="error",
        output_params=[*MP4_DETERMINISTIC, "-movflags", "+faststart", "-f", "mp4"],
    )
    writer.send(None)
    for frame in frames:
        writer.send(np.ascontiguousarray(np.pad(frame, pad, mode="edge")))
    writer.close()
