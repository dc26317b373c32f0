"""Shared fixtures: the repository's shared data, the Rust programs the tests compare with,
and a small textured model made on the spot (for the tests that need no recorded data)."""

import os
import pathlib
import shutil

import numpy as np
import pytest

ROOT = pathlib.Path(__file__).resolve().parents[2]
DATA = ROOT.parent / "shared" / "data"
CUBE = DATA / "visp-cube"


def program(variable: str, what: str) -> pathlib.Path:
    """A Rust program named by an environment variable (`cargo xtask test` sets it)."""
    path = os.environ.get(variable)
    if not path or not pathlib.Path(path).is_file():
        pytest.skip(f"{variable} is not set to {what} (cargo xtask test builds and sets it)")
    return pathlib.Path(path)


@pytest.fixture(scope="session")
def cube() -> pathlib.Path:
    """The shared cube video's folder."""
    if not (CUBE / "cube_video.mp4").is_file():
        pytest.skip(f"{CUBE} is absent: the shared data is not on this machine")
    if shutil.which("ffmpeg") is None:
        pytest.skip("ffmpeg is not installed (cargo xtask setup installs it)")
    return CUBE


@pytest.fixture(scope="session")
def cache(tmp_path_factory) -> pathlib.Path:
    """The cold start's database cache: the Rust locate tests' (the cube's is built there
    already), else one of this session's own."""
    given = os.environ.get("VITRACKER_LOCATE_CACHE")
    return pathlib.Path(given) if given else tmp_path_factory.mktemp("locate-cache")


@pytest.fixture(scope="session")
def board_model(tmp_path_factory) -> pathlib.Path:
    """A textured 0.2 m square board (OBJ + MTL + PNG), seen from 0.5 m by `board_camera`."""
    import cv2

    d = tmp_path_factory.mktemp("board")
    rng = np.random.default_rng(1)
    texture = cv2.resize(rng.integers(0, 256, (32, 32), dtype=np.uint8), (256, 256),
                         interpolation=cv2.INTER_NEAREST)
    cv2.imwrite(str(d / "board.png"), texture)
    (d / "board.mtl").write_text("newmtl board\nKd 1 1 1\nmap_Kd board.png\n")
    (d / "board.obj").write_text(
        "mtllib board.mtl\n"
        "v -0.1 -0.1 0\nv 0.1 -0.1 0\nv 0.1 0.1 0\nv -0.1 0.1 0\n"
        "vt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\n"
        "usemtl board\nf 1/1 2/2 3/3\nf 1/1 3/3 4/4\n"
    )
    return d / "board.obj"


BOARD_START = np.array(
    [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.5], [0.0, 0.0, 0.0, 1.0]]
)
"""The board's start pose: 0.5 m in front of the camera, facing it."""
