"""The pyramidal Lucas-Kanade baseline of the flow tests (tests/tests/flow_opencv.rs): OpenCV's
`goodFeaturesToTrack` and `calcOpticalFlowPyrLK` with OpenCV's default tracking settings (a 21x21 window, three
pyramid levels above the image, at most 30 iterations or a 0.01 px step), on the same grey PNG pairs as ours.

Usage: python opencv_lk.py PAIRS.json

PAIRS.json is a list of objects {"a": PATH, "b": PATH, "points": [[x, y], ...]}. For each pair the script prints
(as one JSON list, in order) the tracks of OpenCV's own features ("own": up to 200 corners of quality 0.01 of
the best, 10 px apart, as OpenCV's samples use them) and of the given points ("given": the features our flow
selected, so both trackers are also compared on the same windows). A track is [x, y, dx, dy] of a point OpenCV
reports found (status 1); lost points are counted ("own_lost", "given_lost"), never dropped silently.
"""

import json
import sys

import cv2
import numpy as np


def track(a, b, pts):
    if len(pts) == 0:
        return [], 0
    p0 = np.asarray(pts, dtype=np.float32).reshape(-1, 1, 2)
    # OpenCV's defaults, spelled out: winSize (21, 21), maxLevel 3, criteria (COUNT | EPS, 30, 0.01).
    p1, status, _err = cv2.calcOpticalFlowPyrLK(
        a,
        b,
        p0,
        None,
        winSize=(21, 21),
        maxLevel=3,
        criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 30, 0.01),
    )
    out, lost = [], 0
    for q0, q1, ok in zip(p0.reshape(-1, 2), p1.reshape(-1, 2), status.reshape(-1)):
        if ok:
            out.append([float(q0[0]), float(q0[1]), float(q1[0] - q0[0]), float(q1[1] - q0[1])])
        else:
            lost += 1
    return out, lost


def main(path):
    with open(path) as f:
        pairs = json.load(f)
    results = []
    for pair in pairs:
        a = cv2.imread(pair["a"], cv2.IMREAD_GRAYSCALE)
        b = cv2.imread(pair["b"], cv2.IMREAD_GRAYSCALE)
        if a is None or b is None:
            raise SystemExit(f"cannot read {pair['a']} or {pair['b']}")
        corners = cv2.goodFeaturesToTrack(a, maxCorners=200, qualityLevel=0.01, minDistance=10)
        own_pts = [] if corners is None else corners.reshape(-1, 2).tolist()
        own, own_lost = track(a, b, own_pts)
        given, given_lost = track(a, b, pair["points"])
        results.append({"own": own, "own_lost": own_lost, "given": given, "given_lost": given_lost})
    json.dump({"opencv": cv2.__version__, "pairs": results}, sys.stdout)


if __name__ == "__main__":
    main(sys.argv[1])
