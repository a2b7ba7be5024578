"""Images as data URIs, so the page carries them inline (no files next to it)."""

from __future__ import annotations

import base64
from pathlib import Path

import cv2
import numpy as np


def image_uri(rgb: np.ndarray, fmt_: str = "png", quality: int = 88) -> str:
    """An RGB(A) or grey uint8 image as a data URI."""
    img = np.asarray(rgb)
    if img.ndim == 3 and img.shape[2] == 3:
        img = cv2.cvtColor(img, cv2.COLOR_RGB2BGR)
    elif img.ndim == 3 and img.shape[2] == 4:
        img = cv2.cvtColor(img, cv2.COLOR_RGBA2BGRA)
    if fmt_ == "jpg":
        if img.ndim == 3 and img.shape[2] == 4:
            img = img[:, :, :3]
        ok, buf = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, quality])
        mime = "image/jpeg"
    else:
        ok, buf = cv2.imencode(".png", img, [cv2.IMWRITE_PNG_COMPRESSION, 9])
        mime = "image/png"
    if not ok:
        raise ValueError("image encoding failed")
    return f"data:{mime};base64,{base64.b64encode(buf.tobytes()).decode()}"


def gif_uri(frames: list[np.ndarray], seconds_per_frame: float = 0.6) -> str:
    """RGB uint8 images of one size as an endlessly looping animated GIF data URI."""
    import io

    from PIL import Image

    images = [Image.fromarray(np.asarray(f)).convert("P", palette=Image.ADAPTIVE) for f in frames]
    buf = io.BytesIO()
    images[0].save(
        buf,
        format="GIF",
        save_all=True,
        append_images=images[1:],
        duration=int(1000 * seconds_per_frame),
        loop=0,
    )
    return f"data:image/gif;base64,{base64.b64encode(buf.getvalue()).decode()}"


def file_image_uri(
    path: Path | None, max_width: int = 1100, fmt_: str = "png", quality: int = 88
) -> str | None:
    """An image file, downscaled to max_width, as a data URI; None when absent or unreadable."""
    if path is None or not Path(path).is_file():
        return None
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        return None
    if img.dtype != np.uint8:
        img = cv2.normalize(img, None, 0, 255, cv2.NORM_MINMAX).astype(np.uint8)
    if img.shape[1] > max_width:
        h = round(img.shape[0] * max_width / img.shape[1])
        img = cv2.resize(img, (max_width, h), interpolation=cv2.INTER_AREA)
    if img.ndim == 3 and img.shape[2] == 3:
        img = cv2.cvtColor(img, cv2.COLOR_BGR2RGB)
    elif img.ndim == 3 and img.shape[2] == 4:
        img = cv2.cvtColor(img, cv2.COLOR_BGRA2RGBA)
    return image_uri(img, fmt_, quality)


def video_uri(path: Path) -> str:
    return f"data:video/mp4;base64,{base64.b64encode(Path(path).read_bytes()).decode()}"
