#!/usr/bin/env python3
"""Long-range registration of a fitted project's background against a rendered clip's geometry.

For a pixel p of frame t on the background (the clip's alpha < 1/2, 8 px from the edges), the
clip's depth and cameras give where frame s sees the same 3D point, q (kept where s sees it:
its depth there agrees within 2 %). A mapping that registers the clip sends p and q to the same
atlas point: the error is |uv_t(p) − uv_s(q)| in frame-s px (uv_s's own scale). Printed per
reference frame s (first, middle, last) for every third frame t, then the median over near
pairs (|t − s| ≤ 3) and far pairs (|t − s| ≥ T/2), beside the same for the preparation's chained
homographies and for the best single homography of each frame (least squares to the true
correspondences: what any plane leaves to the parallax field).

    tools/bench_registration.py CLIP PROJECT [--refocus build/refocus]

CLIP is a folder of `tools/corpus/make_corpus.py` (clip.json with "camera_world" and "lens",
depth_%04d.exr, alpha_%04d.png); PROJECT a project fitted on it (its uv maps are exported to a
temporary folder). Needs python3 with numpy and OpenCV.
"""
import argparse
import json
import os
import subprocess
import sys
import tempfile

os.environ.setdefault("OPENCV_IO_ENABLE_OPENEXR", "1")
import cv2  # noqa: E402
import numpy as np  # noqa: E402


def load_clip(d):
    j = json.load(open(os.path.join(d, "clip.json")))
    if "camera_world" not in j or "lens" not in j:
        sys.exit(f"{d}/clip.json: no cameras (a rendered corpus clip is needed)")
    return j


def read1(path):
    x = cv2.imread(path, cv2.IMREAD_UNCHANGED)
    if x is None:
        sys.exit(f"{path}: cannot read")
    return x if x.ndim == 2 else x[..., 0]


class Geometry:
    def __init__(self, d, j):
        self.d, self.W, self.H, self.T = d, j["width"], j["height"], j["frames"]
        self.f = j["lens"]["focal_px"]
        self.c = ((self.W - 1) / 2, (self.H - 1) / 2)  # Blender's principal point, pixel centres
        self.M = [np.array(m, np.float64).reshape(4, 4) for m in j["camera_world"]]
        self.yy, self.xx = np.mgrid[0:self.H, 0:self.W].astype(np.float64)
        self.z = [read1(os.path.join(d, f"depth_{t:04d}.exr")).astype(np.float64) for t in range(self.T)]

    def project(self, t, s):
        """Frame t's pixels seen in frame s (Blender camera: looks down −Z, y up)."""
        cx, cy = self.c
        z = self.z[t]
        X = (self.xx - cx) * z / self.f
        Y = -(self.yy - cy) * z / self.f
        P = np.stack([X, Y, -z, np.ones_like(z)], -1) @ self.M[t].T @ np.linalg.inv(self.M[s]).T
        zs = -P[..., 2]
        return cx + self.f * P[..., 0] / zs, cy - self.f * P[..., 1] / zs, zs

    def mask(self, t, s, qx, qy, zs):
        a = cv2.imread(os.path.join(self.d, f"alpha_{t:04d}.png"), 0)
        ok = (zs > 0) & (qx > 8) & (qx < self.W - 9) & (qy > 8) & (qy < self.H - 9)
        if a is not None:
            ok &= a < 128
        ok[:8], ok[-8:], ok[:, :8], ok[:, -8:] = False, False, False, False
        zq = cv2.remap(self.z[s].astype(np.float32), qx.astype(np.float32), qy.astype(np.float32),
                       cv2.INTER_NEAREST)
        return ok & (np.abs(zq - zs) < 0.02 * zq)


def apply_h(h, x, y):
    w = h[2, 0] * x + h[2, 1] * y + h[2, 2]
    return (h[0, 0] * x + h[0, 1] * y + h[0, 2]) / w, (h[1, 0] * x + h[1, 1] * y + h[1, 2]) / w


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("clip")
    ap.add_argument("project")
    here = os.path.dirname(os.path.abspath(__file__))
    ap.add_argument("--refocus", default=os.path.join(here, "..", "build", "refocus"))
    a = ap.parse_args()
    j = load_clip(a.clip)
    g = Geometry(a.clip, j)
    prep = os.path.join(a.project, "prep", "prepare.json")
    hs = [np.array(h, np.float64).reshape(3, 3) for h in json.load(open(prep))["homographies"]]
    with tempfile.TemporaryDirectory() as tmp:
        r = subprocess.run([a.refocus, "export", a.project, "--what", "uv", "--out", tmp],
                           capture_output=True, text=True)
        if r.returncode != 0:
            sys.exit(f"{a.project}: export --what uv failed: {r.stderr.strip()}")
        uv = []
        for t in range(g.T):
            x = cv2.imread(os.path.join(tmp, f"uv_{t:04d}.exr"), cv2.IMREAD_UNCHANGED)
            uv.append(np.stack([x[..., 2], x[..., 1]], -1).astype(np.float32))  # BGR = (0, v, u)
    near = {"model": [], "chained": [], "plane": []}
    far = {k: [] for k in near}
    print(f"{os.path.basename(os.path.normpath(a.clip))}: background registration, median px "
          "(model / chained homographies / best homography)")
    for s in sorted({0, g.T // 2, g.T - 1}):
        # px per uv unit of frame s's map, per axis (its median gradient)
        sx = 1 / np.median(np.abs(np.diff(uv[s][..., 0], axis=1)))
        sy = 1 / np.median(np.abs(np.diff(uv[s][..., 1], axis=0)))
        cells = []
        for t in range(g.T):
            if t == s:
                continue
            qx, qy, zs = g.project(t, s)
            ok = g.mask(t, s, qx, qy, zs)
            if ok.sum() < 100:
                continue
            uq = cv2.remap(uv[s], qx.astype(np.float32), qy.astype(np.float32), cv2.INTER_LINEAR)
            du = uv[t] - uq
            e_model = np.hypot(du[..., 0] * sx, du[..., 1] * sy)[ok]
            h_ts = np.linalg.inv(hs[s]) @ hs[t]  # frame t → frame 0 → frame s
            hx, hy = apply_h(h_ts, g.xx[ok], g.yy[ok])
            e_chain = np.hypot(hx - qx[ok], hy - qy[ok])
            src = np.stack([g.xx[ok], g.yy[ok]], 1).astype(np.float32)
            dst = np.stack([qx[ok], qy[ok]], 1).astype(np.float32)
            hb, _ = cv2.findHomography(src, dst, 0)
            bx, by = apply_h(hb, g.xx[ok], g.yy[ok])
            e_plane = np.hypot(bx - qx[ok], by - qy[ok])
            med = [float(np.median(e)) for e in (e_model, e_chain, e_plane)]
            for k, m in zip(near, med):
                if abs(t - s) <= 3:
                    near[k].append(m)
                if abs(t - s) >= g.T / 2:
                    far[k].append(m)
            if t % 3 == 0:
                cells.append(f"{t}:" + "/".join(f"{m:.1f}" for m in med))
        print(f"  against frame {s:2d}: " + "  ".join(cells))
    for name, d in (("near pairs (|t-s| <= 3)", near), ("far pairs (|t-s| >= T/2)", far)):
        if d["model"]:
            print(f"  {name}: model {np.median(d['model']):.2f} px, chained homographies "
                  f"{np.median(d['chained']):.2f}, best homography {np.median(d['plane']):.2f}")


if __name__ == "__main__":
    main()
