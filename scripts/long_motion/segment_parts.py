"""A timeline segment that says an order, streamed in parts and whole: "a person turns left, then walks" over 4 s.

    python scripts/long_motion/segment_parts.py

Seeds 0-7, the shipped student and teacher, the server's stream (stream_timeline, 2-s chunks): the
facing's turn over the whole segment and over each half (left positive), and the pelvis's travel
over each half, with the segment planned in parts (the default) and whole (plan=False).
docs/long_motion.md, "Segments in parts".
"""

import numpy as np, torch
from stablemo.inference.pipeline import Pipeline
from stablemo.inference.bundle import DEMO_BUNDLE, DEMO_STUDENT
from stablemo.motion.heading import facing_yaw
from stablemo.motion.skeleton import get_skeleton
from stablemo.timeline import stream_timeline
sk = get_skeleton("humanml3d")
for name, b in [("student", DEMO_STUDENT), ("teacher", DEMO_BUNDLE)]:
    pipe = Pipeline.from_bundle(b)
    for plan in (True, False):
        rows = []
        for seed in range(8):
            st = stream_timeline(pipe, [(0, 4, "a person turns left, then walks")], seed=seed, plan=plan)
            j = np.concatenate([c.joints for c in st.chunks])
            yaw = np.degrees(np.unwrap(facing_yaw(torch.from_numpy(j), sk).numpy()))
            half = len(j) // 2
            turn_first = yaw[half] - yaw[0]; turn_second = yaw[-1] - yaw[half]
            travel_first = np.linalg.norm(j[half, 0, [0, 2]] - j[0, 0, [0, 2]]); travel_second = np.linalg.norm(j[-1, 0, [0, 2]] - j[half, 0, [0, 2]])
            rows.append((yaw[-1] - yaw[0], turn_first, turn_second, travel_first, travel_second))
        r = np.array(rows)
        print(name, "plan" if plan else "whole", "turn total %.0f, first half %.0f, second half %.0f; travel first %.2f m, second %.2f m" % tuple(r.mean(0)))
