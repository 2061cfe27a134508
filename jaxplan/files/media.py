"""Encoding animation frames as GIF or MP4 files, written atomically
(:mod:`jaxplan.files.durable`).

    write_gif(frames, path, frame_ms) -> path          Pillow, one shared palette
    write_mp4(frames, size, path, frame_ms) -> path    ffmpeg (H.264, yuv420p)
    ffmpeg_available() -> bool                         ffmpeg on PATH

``frames`` is an iterable of (H, W, 4) uint8 RGBA arrays, all of one size; ``size`` is
(W, H) in pixels.  The frames are drawn by :mod:`jaxplan.plots`.
"""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import numpy as np

from jaxplan.files.durable import atomic_write

__all__ = ["write_gif", "write_mp4", "ffmpeg_available"]


def ffmpeg_available() -> bool:
    """Whether ffmpeg is on PATH (:func:`write_mp4` needs it)."""
    return shutil.which("ffmpeg") is not None


def write_gif(frames, path: Path, frame_ms: int) -> Path:
    """A looping GIF, ``frame_ms`` ms per frame (GIF delays are multiples of 10 ms); one
    palette of 255 colours from the first frame (it shows every colour: paths, goals,
    bodies), no dithering."""
    from PIL import Image

    rgb = [Image.fromarray(np.ascontiguousarray(fr[..., :3])) for fr in frames]
    first = rgb[0].quantize(colors=255, method=Image.Quantize.MEDIANCUT,
                            dither=Image.Dither.NONE)
    pal = [first] + [fr.quantize(palette=first, dither=Image.Dither.NONE) for fr in rgb[1:]]
    return atomic_write(path, lambda tmp: pal[0].save(
        tmp, format="GIF", save_all=True, append_images=pal[1:], duration=frame_ms, loop=0))


def write_mp4(frames, size, path: Path, frame_ms: int) -> Path:
    """Pipe raw RGBA frames to ffmpeg (H.264, yuv420p; the frame size padded to even)."""
    w, h = size

    def encode(tmp):
        cmd = ["ffmpeg", "-y", "-loglevel", "error", "-f", "rawvideo", "-pix_fmt", "rgba",
               "-s", f"{w}x{h}", "-r", f"{1000.0 / frame_ms:g}", "-i", "-",
               "-vf", "pad=ceil(iw/2)*2:ceil(ih/2)*2", "-c:v", "libx264", "-pix_fmt", "yuv420p",
               "-movflags", "+faststart", tmp]
        with subprocess.Popen(cmd, stdin=subprocess.PIPE, stderr=subprocess.PIPE) as proc:
            try:
                for fr in frames:
                    proc.stdin.write(np.ascontiguousarray(fr).tobytes())
            except BrokenPipeError:
                pass
            proc.stdin.close()
            err = proc.stderr.read().decode(errors="replace").strip()
            rc = proc.wait()
        if rc != 0:
            raise RuntimeError(f"ffmpeg failed writing {path} (exit {rc}): {err[-500:]}")

    # ffmpeg picks the container by the file name's suffix
    return atomic_write(path, encode, suffix=".tmp.mp4")
