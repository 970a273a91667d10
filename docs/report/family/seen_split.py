#!/usr/bin/env python3
"""Where do renders of a generated video's off-path views lose? Pixels split by how the training
video saw them.

usage: seen_split.py SCENE MASKS NAME=RENDER_DIR [NAME=RENDER_DIR ...]

SCENE is a `nerf synth --preset family` folder; MASKS the folder of its per-frame motion-mask
overlays from `MASK_PNG_DIR=MASKS MASK_PNG_ALL=1 cargo run --release -p nsff --example
mask_recall -- SCENE` (default threshold); each RENDER_DIR holds `0000.png` ... of the scene's
test cameras in file order (`nsff render RUN --cameras SCENE/transforms_test.json --out DIR`,
`nerf render` likewise). The first four test views are the off-path ones.

Each pixel of those views is put in one group:
- *background*: no surface (depth 0), split into *at an edge* (within 2 px of a surface pixel)
  and *open*;
- a surface point (the generator's camera depth, taken along −z) is projected into every
  training frame. It counts as seen there when that frame's own depth agrees within 2 %. Then it
  is *seen in 0-2 frames*, *mostly masked* (inside the motion mask in at least half the frames
  that saw it), or *mostly unmasked*.

Prints each render's PSNR per group and each group's share of its squared error. Pure Python;
PNG decoding and the ground truth's compositing are `docs/dnerf/score.py`'s.
"""
import json
import math
import os
import struct
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), '..', '..', 'dnerf'))
from score import ground_truth, read_png  # noqa: E402


def rgb_rows(path):
    """An 8-bit RGB PNG (a render or a mask overlay) as rows of (r, g, b) in 0-255."""
    w, h, c, px = read_png(path)
    return [[tuple(px[(y * w + x) * c:(y * w + x) * c + 3]) for x in range(w)] for y in range(h)]


def truth_rows(path):
    """A generator image composited on white, as the scorer does, rows of (r, g, b) in 0-255."""
    w, h, flat, _ = ground_truth(path, 1)
    return [[tuple(255.0 * flat[3 * (y * w + x) + k] for k in range(3)) for x in range(w)] for y in range(h)]


def read_npy(path):
    data = open(path, 'rb').read()
    n = struct.unpack('<H', data[8:10])[0]
    header = data[10:10 + n].decode()
    assert "'<f4'" in header and "False" in header, (path, header)
    h, w = (int(v) for v in header.split('(')[1].split(')')[0].split(',')[:2])
    values = struct.unpack('<%df' % (h * w), data[10 + n:10 + n + 4 * h * w])
    return [values[y * w:(y + 1) * w] for y in range(h)]


def main():
    scene, masks, runs = sys.argv[1], sys.argv[2], dict(a.split('=', 1) for a in sys.argv[3:])
    name = scene.rstrip('/').split('/')[-1]
    train = json.load(open(scene + '/transforms_train.json'))['frames']
    test = json.load(open(scene + '/transforms_test.json'))['frames']
    frames = []
    for k, f in enumerate(train):
        overlay = rgb_rows('%s/%s_0.35_%03d.png' % (masks, name, k))
        masked = [[px in ((0, 200, 0), (230, 0, 0)) for px in row] for row in overlay]
        frames.append((f, read_npy('%s/gt/train/%s_depth.npy' % (scene, f['file_path'].split('/')[-1])), masked))
    groups = ['seen in 0-2 frames', 'mostly masked', 'mostly unmasked', 'background at an edge', 'open background']
    sse = {(r, g): 0.0 for r in runs for g in groups}
    count = dict.fromkeys(groups, 0)
    for v, f in enumerate(test[:4]):
        m, fl, cx, cy = f['transform_matrix'], f['fl_x'], f['cx'], f['cy']
        depth = read_npy('%s/gt/test/%s_depth.npy' % (scene, f['file_path'].split('/')[-1]))
        truth = truth_rows('%s/%s.png' % (scene, f['file_path']))
        images = {r: rgb_rows('%s/%04d.png' % (d, v)) for r, d in runs.items()}
        h, w = len(depth), len(depth[0])
        for y in range(h):
            for x in range(w):
                d = depth[y][x]
                if d <= 0:
                    edge = any(0 <= y + j < h and 0 <= x + i < w and depth[y + j][x + i] > 0
                               for j in range(-2, 3) for i in range(-2, 3))
                    group = 'background at an edge' if edge else 'open background'
                else:
                    ray = ((x + 0.5 - cx) / fl, -(y + 0.5 - cy) / fl, -1.0)
                    p = [m[i][3] + d * sum(m[i][j] * ray[j] for j in range(3)) for i in range(3)]
                    seen = inside = 0
                    for g, gd, gm in frames:
                        n = g['transform_matrix']
                        q = [sum(n[j][i] * (p[j] - n[j][3]) for j in range(3)) for i in range(3)]
                        if q[2] >= -1e-6:
                            continue
                        z = -q[2]
                        u = int(math.floor(g['fl_x'] * q[0] / z + g['cx']))
                        t = int(math.floor(-g['fl_y'] * q[1] / z + g['cy']))
                        if 0 <= u < w and 0 <= t < h and abs(gd[t][u] - z) <= 0.02 * z:
                            seen += 1
                            inside += gm[t][u]
                    group = ('seen in 0-2 frames' if seen <= 2 else
                             'mostly masked' if 2 * inside >= seen else 'mostly unmasked')
                count[group] += 1
                for r, img in images.items():
                    sse[(r, group)] += sum((img[y][x][k] - truth[y][x][k]) ** 2 for k in range(3)) / (3 * 255.0 ** 2)
    total = sum(count.values())
    print('%s, off-path views, PSNR per group (pixels):' % name)
    print('| render | ' + ' | '.join('%s (%d)' % (g, count[g]) for g in groups) + ' | all |')
    print('| --- |' + ' ---: |' * (len(groups) + 1))
    for r in runs:
        cells = ['%.2f' % (-10 * math.log10(sse[(r, g)] / count[g])) if count[g] and sse[(r, g)] > 0 else '-' for g in groups]
        print('| %s | %s | %.2f |' % (r, ' | '.join(cells), -10 * math.log10(sum(sse[(r, g)] for g in groups) / total)))
    print('share of the squared error:')
    for r in runs:
        e = sum(sse[(r, g)] for g in groups)
        print('| %s | %s |' % (r, ' | '.join('%.0f %%' % (100 * sse[(r, g)] / e) for g in groups)))


if __name__ == '__main__':
    main()
