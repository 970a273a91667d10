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

Prints each render's PSNR per group and each group's share of its squared error. Pure Python.
"""
import json
import math
import struct
import sys
import zlib


def read_png(path):
    data = open(path, 'rb').read()
    assert data[:8] == b'\x89PNG\r\n\x1a\n', path
    i, idat = 8, b''
    while i < len(data):
        n, kind = struct.unpack('>I4s', data[i:i + 8])
        chunk = data[i + 8:i + 8 + n]
        i += 12 + n
        if kind == b'IHDR':
            w, h, depth, colour = struct.unpack('>IIBB', chunk[:10])
        elif kind == b'IDAT':
            idat += chunk
    assert depth == 8 and colour in (2, 6), (path, depth, colour)
    ch = 3 if colour == 2 else 4
    raw, stride = zlib.decompress(idat), w * ch
    rows, prev, o = [], bytearray(stride), 0
    for _ in range(h):
        f, line = raw[o], bytearray(raw[o + 1:o + 1 + stride])
        o += 1 + stride
        for x in range(stride):
            a = line[x - ch] if x >= ch else 0
            b = prev[x]
            c = prev[x - ch] if x >= ch else 0
            if f == 1:
                line[x] = (line[x] + a) & 255
            elif f == 2:
                line[x] = (line[x] + b) & 255
            elif f == 3:
                line[x] = (line[x] + (a + b) // 2) & 255
            elif f == 4:
                pa, pb, pc = abs(b - c), abs(a - c), abs(a + b - 2 * c)
                line[x] = (line[x] + (a if pa <= pb and pa <= pc else b if pb <= pc else c)) & 255
        # RGBA over white, as the scorers composite the generator's images.
        rows.append([tuple(line[x * ch:x * ch + 3]) if ch == 3 else
                     tuple(int(line[x * ch + k] * line[x * ch + 3] / 255 + 255 * (1 - line[x * ch + 3] / 255) + 0.5)
                           for k in range(3)) for x in range(w)])
        prev = line
    return rows


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
        overlay = read_png('%s/%s_0.35_%03d.png' % (masks, name, k))
        masked = [[px in ((0, 200, 0), (230, 0, 0)) for px in row] for row in overlay]
        frames.append((f, read_npy('%s/gt/train/%s_depth.npy' % (scene, f['file_path'].split('/')[-1])), masked))
    groups = ['seen in 0-2 frames', 'mostly masked', 'mostly unmasked', 'background at an edge', 'open background']
    sse = {(r, g): 0.0 for r in runs for g in groups}
    count = dict.fromkeys(groups, 0)
    for v, f in enumerate(test[:4]):
        m, fl, cx, cy = f['transform_matrix'], f['fl_x'], f['cx'], f['cy']
        depth = read_npy('%s/gt/test/%s_depth.npy' % (scene, f['file_path'].split('/')[-1]))
        truth = read_png('%s/%s.png' % (scene, f['file_path']))
        images = {r: read_png('%s/%04d.png' % (d, v)) for r, d in runs.items()}
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
