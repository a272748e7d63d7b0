"""OpenCV's ORB on the invariance protocol of tests/invariance.rs.

Usage: python opencv_orb_invariance.py IMAGE ANGLE_DEG SCALE
Prints "<correct> <matches>": matches after mutual nearest neighbour, ratio
0.9 and Hamming <= 64, correct when the warped query keypoint lies within
3 px of the train keypoint.
"""
import math
import sys

import cv2
import numpy as np

cv2.setNumThreads(1)
path, angle, scale = sys.argv[1], float(sys.argv[2]), float(sys.argv[3])
img = cv2.imread(path, cv2.IMREAD_GRAYSCALE)
h, w = img.shape
a = math.radians(angle)
c, s = math.cos(a), math.sin(a)
ow = round(scale * (w * abs(c) + h * abs(s)))
oh = round(scale * (w * abs(s) + h * abs(c)))
M = np.array([[scale * c, -scale * s, 0.0], [scale * s, scale * c, 0.0]])
M[:, 2] = np.array([(ow - 1) / 2, (oh - 1) / 2]) - M[:, :2] @ np.array([(w - 1) / 2, (h - 1) / 2])
warped = cv2.warpAffine(img, M, (ow, oh), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
orb = cv2.ORB_create(nfeatures=1000)
ka, da = orb.detectAndCompute(img, None)
kb, db = orb.detectAndCompute(warped, None)
bf = cv2.BFMatcher(cv2.NORM_HAMMING)
rev = {m[0].queryIdx: m[0].trainIdx for m in bf.knnMatch(db, da, k=1)}
good = []
for m in bf.knnMatch(da, db, k=2):
    if len(m) < 2 or m[0].distance > 64 or not m[0].distance < 0.9 * m[1].distance:
        continue
    if rev.get(m[0].trainIdx) == m[0].queryIdx:
        good.append(m[0])
ok = 0
for m in good:
    p = M[:, :2] @ np.array(ka[m.queryIdx].pt) + M[:, 2]
    ok += int(np.linalg.norm(p - np.array(kb[m.trainIdx].pt)) <= 3.0)
print(ok, len(good))
