#!/usr/bin/env python3
"""Side-by-side figure of one test view per scene: ground truth | render A | render B | ...

Usage: python3 montage.py OUT.png VIEW DATA_DIR:RENDER_A.png:RENDER_B.png [DATA_DIR:... ...]

One row per DATA_DIR (a D-NeRF scene); its ground truth is test frame VIEW of
transforms_test.json, composited on white and averaged 2x2 as score.py does (not averaged when
the renders are the ground truth's size, as for generated videos). The renders must
be RGB(A) PNGs of the same size (e.g. `nsff render RUN --cameras ... --out DIR`, DIR/000V.png).
"""

import json
import os
import struct
import sys
import zlib

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from score import PNG_SIGNATURE, ground_truth, png_width, read_png  # noqa: E402


def main():
    out, view, specs = sys.argv[1], int(sys.argv[2]), sys.argv[3:]
    rows, width = [], None
    for spec in specs:
        data, *renders = spec.split(":")
        frames = json.load(open(os.path.join(data, "transforms_test.json")))["frames"]
        gt_path = os.path.normpath(os.path.join(data, frames[view]["file_path"] + ".png"))
        decoded = [(path, *read_png(path)) for path in renders]
        # D-NeRF renders are at half the ground truth's size, generated videos' at full size.
        factor = max(1, png_width(gt_path) // decoded[0][1]) if decoded else 2
        w, h, ours, _ = ground_truth(gt_path, factor)
        tiles = [bytes(min(255, max(0, round(v * 255))) for v in ours)]
        for path, tw, th, c, px in decoded:
            if (tw, th) != (w, h):
                raise ValueError(f"{path} is {tw}x{th}, ground truth {w}x{h}")
            tiles.append(bytes(px[i * c + k] for i in range(w * h) for k in range(3)))
        width = width or w * len(tiles)
        if w * len(tiles) != width:
            raise ValueError("every row needs the same tile size and count")
        rows += [b"".join(t[y * w * 3 : (y + 1) * w * 3] for t in tiles) for y in range(h)]

    def chunk(kind, body):
        return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))

    header = struct.pack(">IIBBBBB", width, len(rows), 8, 2, 0, 0, 0)
    raw = b"".join(b"\x00" + r for r in rows)
    png = PNG_SIGNATURE + chunk(b"IHDR", header) + chunk(b"IDAT", zlib.compress(raw, 9)) + chunk(b"IEND", b"")
    tmp = out + ".tmp"
    with open(tmp, "wb") as f:
        f.write(png)
    os.replace(tmp, out)
    print(f"wrote {out} ({width}x{len(rows)})")


if __name__ == "__main__":
    main()
