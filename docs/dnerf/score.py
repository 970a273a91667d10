#!/usr/bin/env python3
"""Independent PSNR of `nsff render RUN --cameras DATA/transforms_test.json --out DIR`.

Reads the ground-truth PNGs named in the transforms file and the renders DIR/0000.png, ... in
file order, with nothing from the project: PNG decoding (zlib and the five row filters), alpha
compositing on white and the 2x2 downscale are written out here, in plain Python (no numpy).

Ground truth two ways:
  ours:   composite the straight-alpha RGBA on white at 800x800, then average 2x2 blocks
          (what our loader does);
  d-nerf: average the straight RGBA 2x2 blocks (cv2.INTER_AREA at exactly half size), then
          composite (what D-NeRF's load_blender.py does with half_res and white_bkgd).

Usage: python3 score.py DATA_DIR RENDER_DIR [--downscale 2]
Prints per-view PSNR (ours, d-nerf) and the means; the last line is "mean_psnr X" (ours).
"""

import json
import math
import os
import struct
import sys
import zlib

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def png_width(path):
    """A PNG's width from its IHDR chunk (always first), without decoding the image."""
    with open(path, "rb") as f:
        head = f.read(24)
    if head[:8] != PNG_SIGNATURE or head[12:16] != b"IHDR":
        raise ValueError(f"{path}: not a PNG")
    return struct.unpack(">I", head[16:20])[0]


def read_png(path):
    """Returns (width, height, channels, bytes) of an 8-bit RGB or RGBA PNG, not interlaced."""
    with open(path, "rb") as f:
        data = f.read()
    if data[:8] != PNG_SIGNATURE:
        raise ValueError(f"{path}: not a PNG")
    pos, idat, header = 8, [], None
    while pos < len(data):
        (length,) = struct.unpack(">I", data[pos : pos + 4])
        kind = data[pos + 4 : pos + 8]
        body = data[pos + 8 : pos + 8 + length]
        pos += 12 + length
        if kind == b"IHDR":
            header = struct.unpack(">IIBBBBB", body)
        elif kind == b"IDAT":
            idat.append(body)
        elif kind == b"IEND":
            break
    if header is None:
        raise ValueError(f"{path}: a PNG without its IHDR header chunk")
    width, height, depth, color, _, _, interlace = header
    if depth != 8 or color not in (2, 6) or interlace != 0:
        raise ValueError(f"{path}: only 8-bit RGB/RGBA, non-interlaced (got depth {depth}, colour {color})")
    channels = 3 if color == 2 else 4
    raw = zlib.decompress(b"".join(idat))
    stride = width * channels
    out = bytearray(height * stride)
    prev = bytearray(stride)
    for y in range(height):
        kind = raw[y * (stride + 1)]
        line = bytearray(raw[y * (stride + 1) + 1 : (y + 1) * (stride + 1)])
        if kind == 1:
            for i in range(channels, stride):
                line[i] = (line[i] + line[i - channels]) & 255
        elif kind == 2:
            for i in range(stride):
                line[i] = (line[i] + prev[i]) & 255
        elif kind == 3:
            for i in range(stride):
                left = line[i - channels] if i >= channels else 0
                line[i] = (line[i] + ((left + prev[i]) >> 1)) & 255
        elif kind == 4:
            for i in range(stride):
                a = line[i - channels] if i >= channels else 0
                b = prev[i]
                c = prev[i - channels] if i >= channels else 0
                p = a + b - c
                pa, pb, pc = abs(p - a), abs(p - b), abs(p - c)
                pred = a if (pa <= pb and pa <= pc) else (b if pb <= pc else c)
                line[i] = (line[i] + pred) & 255
        elif kind != 0:
            raise ValueError(f"{path}: bad filter {kind} in row {y}")
        out[y * stride : (y + 1) * stride] = line
        prev = line
    return width, height, channels, out


def ground_truth(path, factor):
    """Both ground truths as flat lists of floats in [0, 1], RGB, at 1/factor size."""
    w, h, c, px = read_png(path)
    ow, oh = w // factor, h // factor
    ours, dnerf = [], []
    inv = 1.0 / (factor * factor)
    for y in range(oh):
        for x in range(ow):
            comp = [0.0, 0.0, 0.0]
            straight = [0.0, 0.0, 0.0, 0.0]
            for dy in range(factor):
                base = ((y * factor + dy) * w + x * factor) * c
                for dx in range(factor):
                    i = base + dx * c
                    a = px[i + 3] / 255.0 if c == 4 else 1.0
                    for k in range(3):
                        v = px[i + k] / 255.0
                        comp[k] += v * a + (1.0 - a)
                        straight[k] += v
                    straight[3] += a
            a = straight[3] * inv
            for k in range(3):
                ours.append(comp[k] * inv)
                dnerf.append(straight[k] * inv * a + (1.0 - a))
    return ow, oh, ours, dnerf


def psnr(render, truth):
    mse = sum((r - t) ** 2 for r, t in zip(render, truth)) / len(truth)
    return -10.0 * math.log10(max(mse, 1e-20))


USAGE = "usage: python3 score.py DATA_DIR RENDER_DIR [--downscale 2]"


def main():
    args = sys.argv[1:]
    factor = 2
    if "--downscale" in args:
        i = args.index("--downscale")
        if i + 1 >= len(args) or not args[i + 1].isdigit() or int(args[i + 1]) < 1:
            sys.exit(f"--downscale needs a whole number of at least 1\n{USAGE}")
        factor = int(args[i + 1])
        del args[i : i + 2]
    if len(args) != 2:
        sys.exit(USAGE)
    data, renders = args
    frames = json.load(open(os.path.join(data, "transforms_test.json")))["frames"]
    ours_all, dnerf_all = [], []
    for k, frame in enumerate(frames):
        gt_path = os.path.normpath(os.path.join(data, frame["file_path"] + ".png"))
        gw, gh, ours, dnerf = ground_truth(gt_path, factor)
        rw, rh, rc, px = read_png(os.path.join(renders, f"{k:04d}.png"))
        if (rw, rh) != (gw, gh):
            raise ValueError(f"render {k} is {rw}x{rh}, ground truth {gw}x{gh}")
        render = [px[i * rc + j] / 255.0 for i in range(rw * rh) for j in range(3)]
        p, q = psnr(render, ours), psnr(render, dnerf)
        ours_all.append(p)
        dnerf_all.append(q)
        print(f"{k:3d} {frame['file_path']:<20} psnr {p:7.3f}  (d-nerf ground truth {q:7.3f})")
    n = len(ours_all)
    print(f"mean over {n} views: ours {sum(ours_all) / n:.4f}, d-nerf ground truth {sum(dnerf_all) / n:.4f}")
    print(f"mean_psnr {sum(ours_all) / n:.4f}")


if __name__ == "__main__":
    main()
