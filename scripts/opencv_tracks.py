#!/usr/bin/env python3
"""Runs ../shared/peers/opencv_klt.py unchanged and records the tracks it makes.

Usage: opencv_tracks.py OUT.csv DATASET [peer options...]

The peer's main() runs as is; cv2.calcOpticalFlowPyrLK and cv2.goodFeaturesToTrack are wrapped to
log their inputs and outputs, and the peer's load_frames to learn the stamps. From the log the
tracks are rebuilt: the points entering the LK call of frame k+1 are frame k's features (survivors
of frame k's LK call, then the new GFTT corners); survivors keep their id. Writes the features0
layout (#timestamp [ns],feature_id,u [px],v [px]).
"""
import importlib.util, sys
import numpy as np
import cv2

out_csv, argv = sys.argv[1], sys.argv[2:]
spec = importlib.util.spec_from_file_location('peer', '/work/shared/peers/opencv_klt.py')
peer = importlib.util.module_from_spec(spec)
spec.loader.exec_module(peer)

log = {'stamps': None, 'imgs': None, 'lk': [], 'gftt': [], 'main_done': False}
orig_load, orig_lk, orig_gftt = peer.load_frames, cv2.calcOpticalFlowPyrLK, cv2.goodFeaturesToTrack


def load_frames(*a, **k):
    stamps, imgs = orig_load(*a, **k)
    log['stamps'], log['imgs'] = stamps, imgs
    return stamps, imgs


def index_of(img):
    for i, im in enumerate(log['imgs']):
        if im is img:
            return i
    return None


def lk(prev, nxt, pts, *a, **k):
    r = orig_lk(prev, nxt, pts, *a, **k)
    if not log['main_done']:
        log['lk'].append((index_of(prev), index_of(nxt), pts.reshape(-1, 2).copy(),
                          r[0].reshape(-1, 2).copy(), r[1].reshape(-1).copy()))
    return r


def gftt(img, *a, **k):
    r = orig_gftt(img, *a, **k)
    if 'mask' not in k:
        log['main_done'] = True  # the standalone timing section begins
    elif not log['main_done']:
        log['gftt'].append((index_of(img), None if r is None else r.reshape(-1, 2).astype(np.float32)))
    return r


peer.load_frames = load_frames
cv2.calcOpticalFlowPyrLK = lk
cv2.goodFeaturesToTrack = gftt
sys.argv = ['opencv_klt.py'] + argv
peer.main()

# Rebuild: forward LK calls are (k-1 -> k); with --fb a backward call (k -> k-1) follows each.
fwd = [c for c in log['lk'] if c[1] == c[0] + 1]
bwd = {c[0]: c for c in log['lk'] if c[1] == c[0] - 1}
new_at = {}
for i, c in log['gftt']:
    new_at[i] = c if c is not None else np.empty((0, 2), np.float32)
fb = '--fb' in argv
h, w = log['imgs'][0].shape
ids, pts = np.empty(0, np.int64), np.empty((0, 2), np.float32)
next_id = 0
rows = []
nfr = len(log['imgs'])
fwd_by_next = {c[1]: c for c in fwd}
for k in range(nfr):
    if k > 0 and k in fwd_by_next:
        _, _, p_in, nxt, st = fwd_by_next[k]
        assert p_in.shape == pts.shape and np.array_equal(p_in, pts), f'frame {k}: LK input is not the previous features'
        ok = st == 1
        if fb:
            back = bwd[k]
            ok &= (back[4] == 1) & (np.linalg.norm(back[3] - p_in, axis=1) < 1.0)
        ok &= (nxt[:, 0] >= 0) & (nxt[:, 0] <= w - 1) & (nxt[:, 1] >= 0) & (nxt[:, 1] <= h - 1)
        ids, pts = ids[ok], nxt[ok]
    if k in new_at and len(new_at[k]):
        n = len(new_at[k])
        ids = np.concatenate([ids, np.arange(next_id, next_id + n)])
        next_id += n
        pts = np.concatenate([pts, new_at[k]])
    for i, p in zip(ids, pts):
        rows.append((log['stamps'][k], int(i), float(p[0]), float(p[1])))
with open(out_csv, 'w') as f:
    f.write('#timestamp [ns],feature_id,u [px],v [px]\n')
    for r in rows:
        f.write(f'{r[0]},{r[1]},{r[2]!r},{r[3]!r}\n')
print(f'wrote {out_csv}: {len(rows)} observations, {next_id} tracks', file=sys.stderr)
