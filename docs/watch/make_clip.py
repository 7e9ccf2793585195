"""The pictures of docs/watch.md and the README's clip, from a video ``--video`` wrote.

    python docs/watch/make_clip.py VIDEO.mp4 [--png PATH --frame K] [--gif PATH --every N --width W]

``--png``: the video's frame K (from 0), as decoded. ``--gif``: every N-th frame, scaled to
W pixels wide, at the video's frame rate over N, looping. Read with imageio (the
``[video]`` extra), the GIF written with Pillow.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import cv2
import imageio.v3 as iio


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("video", type=Path)
    parser.add_argument("--png", type=Path, default=None, help="write frame K here")
    parser.add_argument("--frame", type=int, default=20, help="the frame of --png (from 0)")
    parser.add_argument("--gif", type=Path, default=None, help="write the clip here")
    parser.add_argument("--every", type=int, default=2, help="keep every N-th frame in the GIF")
    parser.add_argument("--width", type=int, default=480, help="the GIF's width in pixels")
    args = parser.parse_args()
    fps = float(iio.immeta(args.video).get("fps", 50.0))
    frames = iio.imread(args.video, index=None)  # (T, H, W, 3): a short clip fits in memory
    if args.png is not None:
        iio.imwrite(args.png, frames[args.frame])
    if args.gif is not None:
        height = round(frames.shape[1] * args.width / frames.shape[2])
        small = [
            cv2.resize(f, (args.width, height), interpolation=cv2.INTER_AREA)
            for f in frames[:: args.every]
        ]
        iio.imwrite(args.gif, small, duration=1000 * args.every / fps, loop=0, plugin="pillow")


if __name__ == "__main__":
    main()
