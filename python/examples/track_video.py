"""Tracks the shared cube video (or a camera: `track_video.py 0`) and writes the frames with
the model's edges drawn at each pose (green: tracked, red: not) to tracked.mp4.

    python python/examples/track_video.py [VIDEO|CAMERA_INDEX] [OUT.mp4]
"""
import pathlib
import sys

import cv2
import numpy as np
import vitracker as vt

data = pathlib.Path(__file__).resolve().parents[3] / "shared/data/visp-cube"
source = sys.argv[1] if len(sys.argv) > 1 else str(data / "cube_video.mp4")
capture = cv2.VideoCapture(int(source) if source.isdigit() else source)
camera = vt.Camera.from_json(data / "camera.json")
model = vt.Model(data / "model/cube.obj")
fps = capture.get(cv2.CAP_PROP_FPS) or 30.0
tracker = vt.Tracker(model, camera, start_pose=data / "frame0_pose.json", rate_hz=fps,
                     live=source.isdigit())
edges = model.edges().reshape(-1, 3)
out = cv2.VideoWriter(sys.argv[2] if len(sys.argv) > 2 else "tracked.mp4",
                      cv2.VideoWriter_fourcc(*"mp4v"), fps, (camera.width, camera.height))
ok, frame = capture.read()
while ok:
    tracker.push_frame(capture.get(cv2.CAP_PROP_POS_MSEC) / 1e3, frame)
    for report in tracker.poll():
        if report.pose is not None:
            lines = camera.project(report.pose, edges).reshape(-1, 2, 2)
            lines = lines[~np.isnan(lines).any(axis=(1, 2))]
            colour = (0, 200, 0) if report.tracked else (0, 0, 255)
            cv2.polylines(frame, np.round(lines).astype(np.int32), False, colour, 2, cv2.LINE_AA)
    out.write(frame)
    ok, frame = capture.read()
print(tracker.finish())
