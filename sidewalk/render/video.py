"""An episode's frames written as a video: a looping GIF (Pillow) or an H.264 MP4 (ffmpeg)."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import numpy as np

FORMATS = (".gif", ".mp4")
HOLD_S = 1.0  # the last frame stays this long, so the outcome can be seen before the GIF loops


def paletted(frames: list[np.ndarray]):
    """The frames as Pillow "P" images sharing one exact palette (renders use a handful of flat colours)."""
    from PIL import Image

    stack = np.stack(frames).astype(np.uint32)
    key = (stack[..., 0] << 16) | (stack[..., 1] << 8) | stack[..., 2]
    colours, index = np.unique(key, return_inverse=True)
    if len(colours) > 256:  # not a flat render: let Pillow pick 256 colours
        return [Image.fromarray(frame).quantize(256) for frame in frames]
    palette = np.stack([colours >> 16, (colours >> 8) & 255, colours & 255], -1).astype(np.uint8)
    images = []
    for frame_index in index.reshape(key.shape).astype(np.uint8):
        image = Image.fromarray(frame_index, mode="P")
        image.putpalette(palette.reshape(-1).tolist())
        images.append(image)
    return images


def write_video(frames: list[np.ndarray], out: Path, fps: float) -> None:
    """Write ``frames`` (RGB uint8 arrays of one size) as a looping GIF (Pillow) or an H.264 MP4 (ffmpeg)."""
    out.parent.mkdir(parents=True, exist_ok=True)
    frames = frames + [frames[-1]] * round(HOLD_S * fps)
    if out.suffix == ".gif":
        from PIL import Image

        images = [Image.fromarray(frame) for frame in frames]
        images[0].save(out, save_all=True, append_images=images[1:], duration=round(1000 / fps), loop=0)
        return
    height, width, _ = frames[0].shape
    command = [
        shutil.which("ffmpeg"),
        "-y",
        "-loglevel",
        "error",
        "-f",
        "rawvideo",
        "-pix_fmt",
        "rgb24",
        "-s",
        f"{width}x{height}",
        "-r",
        f"{fps}",
        "-i",
        "-",
        "-vf",
        "pad=ceil(iw/2)*2:ceil(ih/2)*2",  # H.264 in yuv420p needs even sides
        "-pix_fmt",
        "yuv420p",
        "-vcodec",
        "libx264",
        str(out),
    ]
    result = subprocess.run(
        command, input=b"".join(frame.tobytes() for frame in frames), capture_output=True, check=False
    )
    if result.returncode != 0:
        raise RuntimeError(
            f"ffmpeg failed ({result.returncode}): {result.stderr.decode(errors='replace').strip()}"
        )
