"""The Python module's overhead per frame against the Rust example, side by side in one run:
the same first N frames of the shared cube video, the same start pose, the in-process core.

Each side decodes the frames beforehand and times only the tracker's calls (push_frame and
poll): the Rust example (host-vision/examples/track_video.rs, `--decode-first`) prints its
mean; here the same calls are timed. The rounds alternate, so that the machine's load falls on both.

    python python/bench_overhead.py [--frames N] [--rounds R] --example PATH

Build both the same way: `cargo build --release -p host-vision --example track_video` and
`pip install ./python` (release), or the test command's profile for both.
"""

import argparse
import pathlib
import statistics
import subprocess
import time

import numpy as np

import vitracker as vt

CUBE = pathlib.Path(__file__).resolve().parents[2] / "shared/data/visp-cube"


def decode(count):
    """The first `count` grey frames, as the command line decodes them."""
    out = subprocess.run(
        ["ffmpeg", "-hide_banner", "-nostdin", "-loglevel", "error", "-copyts", "-i",
         str(CUBE / "cube_video.mp4"), "-map", "0:v:0", "-vf", "format=gray", "-fps_mode",
         "passthrough", "-frames:v", str(count), "-f", "rawvideo", "-pix_fmt", "gray",
         "pipe:1"], check=True, capture_output=True).stdout
    return np.frombuffer(out, np.uint8).reshape(-1, 480, 640)


def rust_ms(example, count):
    """The Rust example's mean time per frame [ms] and its tracked line."""
    files = [str(CUBE / f) for f in
             ("cube_video.mp4", "camera.json", "model/cube.obj", "frame0_pose.json")]
    out = subprocess.run([example, "--frames", str(count), "--decode-first", *files], check=True,
                         capture_output=True, text=True).stdout.splitlines()
    timing = next(line for line in out if line.startswith("# tracker time per frame"))
    tracked = next(line for line in out if line.startswith("# tracked"))
    return float(timing.split(":")[1].split()[0]), tracked


def python_ms(frames, colour):
    """The module's mean time per frame [ms] (push_frame + poll), and its figures."""
    camera = vt.Camera.from_json(CUBE / "camera.json")
    tracker = vt.Tracker(vt.Model(CUBE / "model/cube.obj"), camera,
                         start_pose=CUBE / "frame0_pose.json", rate_hz=30.0)
    busy = 0.0
    for i, frame in enumerate(frames):
        image = np.repeat(frame[:, :, None], 3, axis=2) if colour else frame
        start = time.perf_counter()
        tracker.push_frame(i / 30.0, image)
        tracker.poll()
        busy += time.perf_counter() - start
    return busy * 1e3 / len(frames), tracker.finish()


def conversion_ms(colour, calls=200):
    """What Python adds to a call, measured alone: a frame one row taller than the camera's is
    read and converted in full, then refused by the tracker before any work [ms per call]."""
    camera = vt.Camera.from_json(CUBE / "camera.json")
    tracker = vt.Tracker(vt.Model(CUBE / "model/cube.obj"), camera,
                         start_pose=CUBE / "frame0_pose.json", rate_hz=30.0)
    shape = (481, 640, 3) if colour else (481, 640)
    frame = np.random.default_rng(0).integers(0, 256, shape, dtype=np.uint8)
    start = time.perf_counter()
    for i in range(calls):
        try:
            tracker.push_frame(i / 30.0, frame)
        except ValueError:
            pass
    spent = time.perf_counter() - start
    tracker.finish()
    return spent * 1e3 / calls


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=300)
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--example", required=True, help="the track_video example's program")
    args = parser.parse_args()
    frames = decode(args.frames)
    rows = []
    for r in range(args.rounds):
        rust, tracked = rust_ms(args.example, args.frames)
        grey, figures = python_ms(frames, colour=False)
        colour, _ = python_ms(frames, colour=True)
        rows.append((rust, grey, colour))
        print(f"round {r + 1}: Rust {rust:.2f} ms, Python grey {grey:.2f} ms, "
              f"Python BGR {colour:.2f} ms per frame ({tracked[2:]}; Python {figures})")
    rust, grey, colour = (statistics.median(c) for c in zip(*rows))
    print(f"\nmedian of {args.rounds} rounds, {len(frames)} frames each:")
    print(f"  Rust example        {rust:7.2f} ms per frame")
    print(f"  Python, grey frames {grey:7.2f} ms  ({100 * (grey / rust - 1):+.1f} %)")
    print(f"  Python, BGR frames  {colour:7.2f} ms  ({100 * (colour / rust - 1):+.1f} %)")
    for name, colour in (("grey", False), ("BGR", True)):
        alone = conversion_ms(colour)
        print(f"  what Python adds to a call, alone ({name} 640x480): {alone:.3f} ms, "
              f"{100 * alone / rust:.2f} % of the Rust frame")


if __name__ == "__main__":
    main()
